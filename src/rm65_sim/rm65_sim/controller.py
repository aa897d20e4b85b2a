"""The simulated controller's state and its non-motion commands: arm state, the SDK's connect-time
queries, tool and work frames (§1.7), controller and tool-flange IO (§1.8); ``§`` cites docs/RM65_PROTOCOL.md.

:class:`ControllerCommands` is a part of :class:`~rm65_sim.simulator.ArmSimulator` (the state
lives there, under its lock): one ``_cmd_<command>(msg)`` per command, returning the reply.
Units on the wire as in :mod:`~rm65_driver.protocol.messages` (0.001°, µm, mrad); inside, rad and m. Every change of a
digital output is recorded as a :class:`DOEvent` with the tool pose at that instant.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from rm65_driver.kinematics.rm65 import (
    JOINT_MAX_ACC_DEG_S2,
    JOINT_MAX_SPEED_DEG_S,
    RM65Kinematics,
    invert_transform,
    matrix_to_pose6,
    pose6_to_matrix,
)
from rm65_driver.protocol import messages as P
from rm65_sim.config import SimulatorConfig

#: Controller IO (Gen-3: four multiplexed DI/DO) and tool-flange IO (two), §1.8.
N_IO = 4
N_TOOL_IO = 2


@dataclass(frozen=True)
class DOEvent:
    """A digital-output level change. ``tcp_pose`` (4x4, m) is the tool in the work frame, then;
    ``base_in_world`` (4x4) where the arm's base truly was (the rail's true pose; identity without one)."""

    t: float
    io: int
    tool: bool
    value: int
    joints_rad: np.ndarray
    tcp_pose: np.ndarray
    base_in_world: np.ndarray = field(default_factory=lambda: np.eye(4))

    @property
    def position(self) -> np.ndarray:
        return self.tcp_pose[:3, 3]

    @property
    def true_world_position(self) -> np.ndarray:
        """Where the tool truly was in ``world`` (m): on the rail's true pose (the work frame being the base)."""
        return (self.base_in_world @ self.tcp_pose)[:3, 3]



class ControllerCommands:
    """State queries, frames and IO of :class:`~rm65_sim.simulator.ArmSimulator` (state lives there)."""

    kin: RM65Kinematics
    config: SimulatorConfig
    do_events: list[DOEvent]
    _lock: threading.RLock
    _changed: threading.Condition
    _joints: np.ndarray
    _queue: Any  # deque of motion.Motion
    _errors: list[int]
    _tool_frames: dict[str, tuple[np.ndarray, int, list[int]]]
    _work_frames: dict[str, np.ndarray]
    _tool_name: str
    _work_name: str
    _io_mode: list[int]
    _do: list[int]
    _tool_io_mode: list[int]
    _tool_do: list[int]
    _tool_voltage: int
    _realtime_push: dict[str, Any]
    _power: int
    rail: Any  # rm65_sim.rail.SimRail

    # -- state ---------------------------------------------------------------------------
    def _frames_locked(self) -> tuple[np.ndarray, np.ndarray]:
        T_work = pose6_to_matrix(self._work_frames[self._work_name])
        T_tool = pose6_to_matrix(self._tool_frames[self._tool_name][0])
        return T_work, T_tool

    def _tcp_pose_at(self, q: np.ndarray) -> np.ndarray:
        T_work, T_tool = self._frames_locked()
        return invert_transform(T_work) @ self.kin.fk(q, T_tool)

    def _tcp_pose_locked(self) -> np.ndarray:
        return self._tcp_pose_at(self._joints)

    def _cmd_get_current_arm_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            pose = matrix_to_pose6(self._tcp_pose_locked())
            return P.arm_state_message(self._joints, pose, self._errors, self.config.err_format)

    def _cmd_get_joint_degree(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "joint_degree", "joint": P.joints_to_wire(self._joints)}

    def _cmd_get_arm_all_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "arm_all_state", "all_state": {
            "temperature": [35000] * 6, "current": [500000] * 6, "voltage": [24000] * 6,
            "err_flag": [0] * 6, "en_flag": [1] * 6, "sys_err": 0}}

    def _cmd_get_controller_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "controller_state", "voltage": 24000, "current": 1500, "temperature": 42000,
                "err_flag": 0}

    def _cmd_set_arm_power(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            self._power = int(msg["arm_power"])
        return {"command": "set_arm_power", "arm_power": True}

    def _cmd_get_arm_power_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "arm_power_state", "power_state": self._power}

    def _cmd_set_arm_run_mode(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"command": "set_arm_run_mode", "set_state": True}  # reply format [UNCERTAIN]

    # -- connect-time queries of the official SDK (§1.11) --------------------------------
    def _cmd_get_arm_software_info(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {
            "Product_version": self.config.product_version,
            "algorithm_info": {"version": "1.2.3"},
            "command": "arm_software_info",
            "ctrl_info": {"build_time": "2024-10-17 10:00:00", "version": "V1.4.6"},
            "dynamic_info": {"model_version": "1"},
            "plan_info": {"build_time": "2024-10-17 10:00:00", "version": "V1.4.6"},
        }

    def _cmd_get_realtime_push(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            cfg = dict(self._realtime_push)
        return {"command": "get_realtime_push", "custom": {"expand_state": False, "joint_speed": False,
                "lift_state": False}, **cfg}

    def _cmd_set_realtime_push(self, msg: dict[str, Any]) -> dict[str, Any]:
        # Stored and reported back; the UDP push itself is not simulated.
        with self._lock:
            for k in ("cycle", "enable", "port", "ip", "force_coordinate"):
                if k in msg:
                    self._realtime_push[k] = msg[k]
        return {"command": "set_realtime_push", "state": True}

    def _cmd_get_install_pose(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "install_pose", "pose": [0, 0, 0]}

    def _cmd_get_joint_min_pos(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "joint_min_pos", "min_pos": P.joints_to_wire(self.kin.limits_rad[:, 0])}

    def _cmd_get_joint_max_pos(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "joint_max_pos", "max_pos": P.joints_to_wire(self.kin.limits_rad[:, 1])}

    def _cmd_get_joint_max_speed(self, msg: dict[str, Any]) -> dict[str, Any]:
        # 0.001 deg/s ([UNCERTAIN] unit, see §1.6)
        return {"state": "joint_max_speed", "joint_speed": [int(v * 1000) for v in JOINT_MAX_SPEED_DEG_S]}

    def _cmd_get_joint_max_acc(self, msg: dict[str, Any]) -> dict[str, Any]:
        # same unit as the speeds; the motion model accelerates at these (RM65Kinematics.max_acc_rad_s2)
        return {"state": "joint_max_acc", "joint_acc": [int(a * 1000) for a in JOINT_MAX_ACC_DEG_S2]}

    def _cmd_get_DH_data(self, msg: dict[str, Any]) -> dict[str, Any]:
        dh = self.kin.dh
        out: dict[str, Any] = {"command": "get_DH_data"}
        for i in range(6):
            out[f"joint_{i + 1}"] = [
                int(round(np.degrees(dh.alpha[i]) * 1000)), int(round(dh.a[i] * 1e6)),
                int(round(dh.d[i] * 1e6)), int(round(np.degrees(dh.offset[i]) * 1000)),
            ]
        return out

    # -- frames (§1.7) -------------------------------------------------------------------
    def _cmd_set_manual_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        name = str(msg["tool_name"])
        ok = 0 < len(name) <= 10
        with self._lock:
            ok = ok and (name in self._tool_frames or len(self._tool_frames) < 10)
            if ok:
                self._tool_frames[name] = (P.pose_from_wire(msg["tool_pose"]), int(msg.get("payload", 0)),
                                           [int(v) for v in msg.get("position", [0, 0, 0])])
        return {"command": "set_manual_tool_frame", "manual_tool_frame": ok}

    def _cmd_set_change_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["tool_name"] in self._tool_frames and not self._queue
            if ok:
                self._tool_name = msg["tool_name"]
            elif msg["tool_name"] not in self._tool_frames:
                self._errors = [0x100F]
        return {"command": "set_change_tool_frame", "change_tool_frame": ok}

    def _cmd_set_delete_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["tool_name"] in self._tool_frames and msg["tool_name"] not in (self._tool_name, "Arm_Tip")
            if ok:
                del self._tool_frames[msg["tool_name"]]
        return {"command": "set_delete_tool_frame", "delete_tool_frame": ok}

    def _cmd_get_current_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            pose, payload, com = self._tool_frames[self._tool_name]
            return {"state": "current_tool_frame", "tool_name": self._tool_name, "pose": P.pose_to_wire(pose),
                    "payload": payload, "position": list(com)}

    def _cmd_get_total_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "total_tool_frame", "tool_names": list(self._tool_frames)}

    def _cmd_set_manual_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        name = str(msg["frame_name"])
        ok = 0 < len(name) <= 10
        with self._lock:
            ok = ok and (name in self._work_frames or len(self._work_frames) < 10)
            if ok:
                self._work_frames[name] = P.pose_from_wire(msg["frame_pose"])
        return {"command": "set_manual_work_frame", "manual_work_frame": ok}

    def _cmd_set_change_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["frame_name"] in self._work_frames and not self._queue
            if ok:
                self._work_name = msg["frame_name"]
            elif msg["frame_name"] not in self._work_frames:
                self._errors = [0x100E]
        return {"command": "set_change_work_frame", "change_work_frame": ok}

    def _cmd_set_delete_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["frame_name"] in self._work_frames and msg["frame_name"] not in (self._work_name, "Base")
            if ok:
                del self._work_frames[msg["frame_name"]]
        return {"command": "set_delete_work_frame", "delete_work_frame": ok}

    def _cmd_get_current_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "current_work_frame", "frame_name": self._work_name,
                    "pose": P.pose_to_wire(self._work_frames[self._work_name])}

    def _cmd_get_total_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "total_work_frame", "frame_names": list(self._work_frames)}

    # -- IO (§1.8) -----------------------------------------------------------------------
    def _record_do(self, io: int, tool: bool, value: int) -> None:
        self.do_events.append(DOEvent(time.monotonic(), io, tool, value, self._joints.copy(), self._tcp_pose_locked(),
                                      self.rail.true_base_in_world()))

    def _cmd_set_IO_mode(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, mode = int(msg["IO_Num"]), int(msg["IO_mode"])
        ok = 1 <= io <= N_IO and 0 <= mode <= 14
        if ok:
            with self._lock:
                self._io_mode[io - 1] = mode
        return {"command": "set_IO_mode", "set_state": ok}

    def _cmd_set_DO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, value = int(msg["IO_Num"]), 1 if int(msg["state"]) else 0
        with self._lock:
            ok = 1 <= io <= N_IO and (not self.config.strict_io_mode or self._io_mode[io - 1] == 1)
            if ok and self._do[io - 1] != value:
                self._do[io - 1] = value
                self._record_do(io, False, value)
                self._changed.notify_all()
        return {"command": "set_DO_state", "set_state": ok}

    def _cmd_get_IO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        io = int(msg["IO_Num"])
        if not 1 <= io <= N_IO:
            raise ValueError(f"IO_Num {io}")
        with self._lock:
            return {"state": "IO_state", "IO_Num": io, "IO_Mode": self._io_mode[io - 1], "IO_state": self._do[io - 1]}

    def _cmd_get_IO_output(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "IO_output_state", "DO": list(self._do), "AO": [0] * 4}

    def _cmd_get_IO_input(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "IO_input_state", "DI": [0] * N_IO, "AI": [0] * 4}

    def _cmd_set_tool_IO_mode(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, mode = int(msg["IO_Num"]), int(msg["state"])
        ok = 1 <= io <= N_TOOL_IO and mode in (0, 1)
        if ok:
            with self._lock:
                self._tool_io_mode[io - 1] = mode
        return {"command": "set_tool_IO_mode", "set_state": ok}

    def _cmd_set_tool_DO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, value = int(msg["IO_Num"]), 1 if int(msg["state"]) else 0
        with self._lock:
            ok = 1 <= io <= N_TOOL_IO and (not self.config.strict_io_mode or self._tool_io_mode[io - 1] == 1)
            if ok and self._tool_do[io - 1] != value:
                self._tool_do[io - 1] = value
                self._record_do(io, True, value)
                self._changed.notify_all()
        return {"command": "set_tool_DO_state", "set_state": ok}

    def _cmd_get_tool_IO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "tool_IO_state", "IO_Mode": list(self._tool_io_mode), "IO_State": list(self._tool_do)}

    def _cmd_set_tool_voltage(self, msg: dict[str, Any]) -> dict[str, Any]:
        vt = int(msg["voltage_type"])
        ok = vt in (0, 1, 2, 3)
        if ok:
            with self._lock:
                self._tool_voltage = vt
        return {"command": "set_tool_voltage", "state": ok}
