"""What the arm driver's parts share: :class:`DriverState` holds the state that
:class:`~rm65_driver.driver.driver_node.DriverNode` sets up and hands to its status publisher
(:class:`~rm65_driver.driver.status.DriverStatus`) and its services
(:class:`~rm65_driver.driver.services.DriverServices`), so each part is an object of its own."""
from __future__ import annotations

import threading
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.impl.rcutils_logger import RcutilsLogger

from rm65_driver.journal.records import JournalError
from rm65_driver.journal.scan import JournalCorrupt
from rm65_driver.journal.writer import Journal
from rm65_driver.kinematics.rm65 import RM65Kinematics
from rm65_driver.protocol.arm_client import ArmClient
from rm65_driver.protocol.messages import ArmStateReading
from rm65_driver.rail.control import RailControl
from rm65_driver.weld.reach import Reach
from rm65_driver.weld.safety import SafetyChecker
from rm65_driver.weld.weld_sequence import WeldSequence
from stud_common.hand_eye_in_use import HandEyeInUse


class DriverState:
    """The driver node's state, made once by the node and read by its parts (on their own threads)."""

    def __init__(self, p: dict[str, Any], logger: RcutilsLogger, client: ArmClient, kin: RM65Kinematics,
                 hand_eye: HandEyeInUse, journal_path: Path, rail: RailControl | None = None) -> None:
        self.p = p                        # the validated parameters (driver.params.PARAMS)
        self.log = logger                 # the node's logger
        self.client = client
        self.kin = kin
        self.rail = rail if rail is not None else RailControl(client, None)  # the carriage (no axis: no rail)
        self.hand_eye = hand_eye
        self.journal_path = journal_path
        self.journal: Journal | None = None               # None while the journal is in FAULT
        self.open_fault: JournalError | None = None       # damage found when opening (the FAULT)
        self.sequence: WeldSequence | None = None         # the running or last weld job
        self.job_lock = threading.Lock()
        self.estop = False
        self.message = ""
        self.last_state: ArmStateReading | None = None    # the last arm state read

    # -- the weld journal ------------------------------------------------------------------------
    def open_journal(self) -> None:
        """Open the journal; damage puts the driver in FAULT instead (OSError: cannot read it at all)."""
        try:
            self.journal = Journal(self.journal_path)
        except JournalCorrupt as exc:
            self.journal, self.open_fault = None, exc
            self.log.error(f"FAULT: {exc}")
            return
        self.open_fault = None
        for w in self.journal.warnings:
            self.log.warn(f"weld journal: {w}")
        self.log.info(f"weld journal {self.journal_path}: {len(self.journal.welded_ids)} welded, "
                      f"{len(self.journal.uncertain_ids)} uncertain stud(s)")

    @property
    def journal_fault(self) -> JournalError | None:
        """Why the journal cannot be trusted or written now (None: it can)."""
        if self.open_fault is not None:
            return self.open_fault
        j = self.journal
        return j.fault if j is not None else None

    def fault_text(self, fault: JournalError) -> str:
        return f"weld journal FAULT: {fault} (weld jobs refused until /arm/resolve_journal)"

    # -- the tool and the camera on it ------------------------------------------------------------
    @property
    def tool_T(self) -> np.ndarray:
        T = np.eye(4)
        T[2, 3] = self.p["tool_offset_m"]
        return T

    def hand_eye_T(self) -> np.ndarray:
        return self.hand_eye.T_tool_cam

    # -- the checks -------------------------------------------------------------------------------
    def safety_checker(self, world_T_base: np.ndarray | None = None) -> SafetyChecker:
        """The checks of a weld job and of /arm/move_to with the parameters as they are now (the base at
        ``world_T_base`` in world; identity: no rail)."""
        from rm65_driver.driver.params import safety_checker  # (params imports the weld modules, not this one)

        return safety_checker(self.p, self.hand_eye_T(), self.kin, world_T_base)

    def reach(self) -> Reach:
        """The reach test as the planner gets it (``/arm/reach_config``): the verdicts' configuration."""
        from rm65_driver.driver.params import job_config

        params, _limits = job_config(self.p)
        return self.safety_checker().reach_for(params.standoff_m, params.plunge_m)
