"""What the arm driver's parts share: :class:`DriverBase` declares the state that
:class:`~rm65_driver.driver_node.DriverNode` sets up and its status (``driver_status``) and service
(``driver_services``) parts use, so each part reads as a class of its own and is type checked."""
from __future__ import annotations

import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rclpy.node import Node

from .arm_client import ArmClient
from .journal import Journal
from .journal_records import JournalError
from .kinematics import RM65Kinematics
from .reach import Reach
from .weld_sequence import WeldSequence


class DriverBase(Node):
    """The driver node's state (set in DriverNode.__init__), declared once for its parts."""

    p: dict[str, Any]                 # the validated parameters (driver_params.PARAMS)
    client: ArmClient
    kin: RM65Kinematics
    journal: Journal | None           # None while the journal is in FAULT
    journal_path: Path
    sequence: WeldSequence | None     # the running or last weld job
    _job_lock: threading.Lock
    _journal_fault: JournalError | None
    _estop: bool
    _message: str
    _last_state: Any

    if TYPE_CHECKING:  # defined by DriverNode and DriverStatus
        @property
        def tool_T(self) -> np.ndarray: ...
        @property
        def journal_fault(self) -> JournalError | None: ...
        def _fault_text(self, fault: JournalError) -> str: ...
        def _open_journal(self) -> None: ...
        def _hand_eye(self) -> np.ndarray: ...
        def reach(self) -> Reach: ...
