"""RealMan RM-65 JSON-over-TCP protocol: framing, command builders, reply parsing, units, error text.

Everything here follows docs/RM65_PROTOCOL.md (RealMan JSON protocol v3.7.4, the official SDK
robotic-arm 1.1.6 as observed on the wire, the official ROS1 driver); ``§`` cites its sections. No I/O and
no ROS: the client, the simulator and the tests all use this one module.

Framing (§1.1): every message, in both directions, is one JSON object followed by ``\\r\\n``.
Messages are delimited on ``\\r\\n`` only: the official ROS1 driver sends pretty-printed JSON
with bare ``\\n``/``\\t`` inside the object, so a bare ``\\n`` is never a delimiter.

Units (§1.3) are converted here, at the edge, and nowhere else:

=============  =====================  ==========================
quantity       wire                   core (this project)
=============  =====================  ==========================
joint angle    int, 0.001 deg         float, rad
position       int, 0.001 mm (1 µm)   float, m
Euler angle    int, 0.001 rad         float, rad (ZYX, R = Rz·Ry·Rx)
payload        int, g                 float, kg
=============  =====================  ==========================
"""
from __future__ import annotations

import json
import logging
import math
from dataclasses import dataclass, field
from typing import Any, Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

_log = logging.getLogger(__name__)

TERMINATOR = b"\r\n"
#: Largest message we buffer without seeing a terminator (a stream of garbage must not eat memory).
MAX_FRAME_BYTES = 1 << 20

DEFAULT_PORT = 8080
#: The real controller's factory address (§1.1). This project defaults to loopback for safety.
FACTORY_ARM_IP = "192.168.1.18"


class ProtocolError(ValueError):
    """A message that is not valid protocol (not JSON, not an object, missing fields)."""


# -- Framing ---------------------------------------------------------------------------------------


def encode(message: dict[str, Any], pretty: bool = False) -> bytes:
    """One message on the wire: compact JSON (as the official SDK sends it) + ``\\r\\n``.

    ``pretty=True`` mimics cJSON_Print (tabs and bare newlines inside the object), as the
    official ROS1 driver sends it; used by tests and the simulator's pretty-reply option.
    """
    if pretty:
        text = json.dumps(message, indent="\t", separators=(",", ":\t"))
    else:
        text = json.dumps(message, separators=(",", ":"))
    return text.encode("utf-8") + TERMINATOR


@dataclass
class FrameDecoder:
    """Incremental decoder of a byte stream into JSON objects.

    ``feed(data)`` returns every complete message found so far (zero, one or several per call,
    whatever the read boundaries). A frame that is not a JSON object is skipped: it is counted,
    kept (truncated) in ``bad_frames`` and logged, so a garbage line never poisons the stream.
    A frame longer than ``max_frame_bytes`` without a terminator is dropped the same way.
    """

    max_frame_bytes: int = MAX_FRAME_BYTES
    bad_frames: list[str] = field(default_factory=list)
    bad_count: int = 0
    _buf: bytearray = field(default_factory=bytearray, repr=False)

    def feed(self, data: bytes) -> list[dict[str, Any]]:
        self._buf.extend(data)
        out: list[dict[str, Any]] = []
        start = 0
        while True:
            end = self._buf.find(TERMINATOR, start)
            if end < 0:
                break
            frame = bytes(self._buf[start:end])
            start = end + len(TERMINATOR)
            msg = self._parse(frame)
            if msg is not None:
                out.append(msg)
        del self._buf[:start]
        if len(self._buf) > self.max_frame_bytes:
            self._reject(bytes(self._buf[:80]), f"no terminator within {self.max_frame_bytes} bytes")
            self._buf.clear()
        return out

    @property
    def pending_bytes(self) -> int:
        """Bytes received after the last terminator (a message split across reads)."""
        return len(self._buf)

    def _parse(self, frame: bytes) -> dict[str, Any] | None:
        if not frame.strip():
            return None  # keep-alive / blank line
        try:
            msg = json.loads(frame.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            self._reject(frame, f"not JSON ({exc})")
            return None
        if not isinstance(msg, dict):
            self._reject(frame, f"JSON {type(msg).__name__}, expected an object")
            return None
        return msg

    def _reject(self, frame: bytes, why: str) -> None:
        self.bad_count += 1
        text = frame[:200].decode("utf-8", "replace")
        self.bad_frames.append(text)
        del self.bad_frames[:-20]
        _log.warning("skipped a bad protocol frame: %s: %r", why, text)


def decode_frame(frame: bytes | str) -> dict[str, Any]:
    """Parse one frame (without its terminator); raises :class:`ProtocolError` if not a JSON object."""
    if isinstance(frame, str):
        frame = frame.encode("utf-8")
    try:
        msg = json.loads(frame.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ProtocolError(f"not JSON: {frame[:80]!r} ({exc})") from exc
    if not isinstance(msg, dict):
        raise ProtocolError(f"expected a JSON object, got {type(msg).__name__}: {frame[:80]!r}")
    return msg


# -- Units (§1.3) ----------------------------------------------------------------------------------


def _to_int_list(values: Iterable[float], scale: float) -> list[int]:
    vals = [float(v) for v in values]
    if not all(math.isfinite(v) for v in vals):
        raise ValueError(f"non-finite value in {vals} (refusing to send it to the controller)")
    return [int(round(v * scale)) for v in vals]


def joints_to_wire(q_rad: ArrayLike) -> list[int]:
    """Joint angles rad -> int 0.001 deg."""
    return _to_int_list(np.degrees(np.asarray(q_rad, dtype=np.float64)), 1000.0)


def joints_from_wire(mdeg: ArrayLike) -> np.ndarray:
    """Joint angles int 0.001 deg -> rad, shape (n,)."""
    return np.radians(np.asarray(mdeg, dtype=np.float64) / 1000.0)


def pose_to_wire(pose6: ArrayLike) -> list[int]:
    """``[x, y, z (m), rx, ry, rz (rad)]`` -> ``[µm, µm, µm, mrad, mrad, mrad]``."""
    p = np.asarray(pose6, dtype=np.float64).reshape(6)
    return _to_int_list(p[:3], 1e6) + _to_int_list(p[3:], 1e3)


def pose_from_wire(wire: ArrayLike) -> np.ndarray:
    """``[µm, µm, µm, mrad, mrad, mrad]`` -> ``[x, y, z (m), rx, ry, rz (rad)]``."""
    w = np.asarray(wire, dtype=np.float64).reshape(6)
    return np.concatenate([w[:3] / 1e6, w[3:] / 1e3])


def position_to_wire(xyz_m: Sequence[float]) -> list[int]:
    """Position m -> int µm."""
    return _to_int_list(xyz_m, 1e6)


# -- Command builders (§1.4 – §1.11) ---------------------------------------------------------------
# Each returns the dict to send; units are SI on the way in.

MOTION_COMMANDS = frozenset({"movej", "movej_p", "movel"})


def _check_speed(v: int) -> int:
    v = int(v)
    if not 1 <= v <= 100:
        raise ValueError(f"speed v={v} % outside 1..100")
    return v


def movej(q_rad: ArrayLike, v: int, r: int = 0, trajectory_connect: int = 0) -> dict[str, Any]:
    """Joint move to ``q_rad`` (6,) at ``v`` % of max joint speed."""
    return {"command": "movej", "joint": joints_to_wire(q_rad), "v": _check_speed(v), "r": int(r),
            "trajectory_connect": int(trajectory_connect)}


def movej_p(pose6: ArrayLike, v: int, r: int = 0, trajectory_connect: int = 0) -> dict[str, Any]:
    """Joint-space move to a Cartesian pose ``[m, m, m, rad, rad, rad]`` (current tool in current work frame)."""
    return {"command": "movej_p", "pose": pose_to_wire(pose6), "v": _check_speed(v), "r": int(r),
            "trajectory_connect": int(trajectory_connect)}


def movel(pose6: ArrayLike, v: int, r: int = 0, trajectory_connect: int = 0) -> dict[str, Any]:
    """Straight-line move of the current tool to a pose ``[m, m, m, rad, rad, rad]``."""
    return {"command": "movel", "pose": pose_to_wire(pose6), "v": _check_speed(v), "r": int(r),
            "trajectory_connect": int(trajectory_connect)}


def simple(command: str, **fields: Any) -> dict[str, Any]:
    """A command with no unit conversion: ``{"command": command, **fields}``."""
    return {"command": command, **fields}


def get_current_arm_state() -> dict[str, Any]:
    """Query the joints, the tool pose and the errors (answered in one of three formats, §1.6)."""
    return {"command": "get_current_arm_state"}


def get_joint_degree() -> dict[str, Any]:
    """Query the joint angles (0.001 deg on the wire), §1.6."""
    return {"command": "get_joint_degree"}


def set_arm_stop() -> dict[str, Any]:
    """Trajectory emergency stop (fastest deceleration, not resumable), §1.5."""
    return {"command": "set_arm_stop"}


def set_arm_slow_stop() -> dict[str, Any]:
    """Slow stop on the path, §1.5."""
    return {"command": "set_arm_slow_stop"}


def set_arm_pause() -> dict[str, Any]:
    """Pause on the path (:func:`set_arm_continue` resumes), §1.5."""
    return {"command": "set_arm_pause"}


def set_arm_continue() -> dict[str, Any]:
    """Resume a paused trajectory, §1.5."""
    return {"command": "set_arm_continue"}


def clear_system_err() -> dict[str, Any]:
    """Clear the controller's system error, §1.6."""
    return {"command": "clear_system_err"}


def get_arm_current_trajectory() -> dict[str, Any]:
    """Query the motion running (``type`` movej / movel / none and its data), §1.5."""
    return {"command": "get_arm_current_trajectory"}


def set_manual_tool_frame(name: str, tool_pose6: Sequence[float], payload_kg: float = 0.0,
                          com_m: Sequence[float] = (0.0, 0.0, 0.0)) -> dict[str, Any]:
    """Define a tool frame (flange -> tool pose, payload, centre of mass), §1.7. Name <= 10 chars."""
    _check_frame_name(name)
    return {"command": "set_manual_tool_frame", "tool_name": name, "tool_pose": pose_to_wire(tool_pose6),
            "payload": int(round(payload_kg * 1000.0)), "position": position_to_wire(com_m)}


def set_change_tool_frame(name: str) -> dict[str, Any]:
    """Make tool frame ``name`` (1..10 chars) the current one, §1.7."""
    _check_frame_name(name)
    return {"command": "set_change_tool_frame", "tool_name": name}


def get_current_tool_frame() -> dict[str, Any]:
    """Query the current tool frame (name, pose, payload, centre of mass), §1.7."""
    return {"command": "get_current_tool_frame"}


def set_manual_work_frame(name: str, frame_pose6: Sequence[float]) -> dict[str, Any]:
    """Define work frame ``name`` (1..10 chars) at base-frame pose ``frame_pose6`` [m, m, m, rad, rad, rad], §1.7."""
    _check_frame_name(name)
    return {"command": "set_manual_work_frame", "frame_name": name, "frame_pose": pose_to_wire(frame_pose6)}


def set_change_work_frame(name: str) -> dict[str, Any]:
    """Make work frame ``name`` (1..10 chars) the current one, §1.7."""
    _check_frame_name(name)
    return {"command": "set_change_work_frame", "frame_name": name}


def get_current_work_frame() -> dict[str, Any]:
    """Query the current work frame (name and pose), §1.7."""
    return {"command": "get_current_work_frame"}


def _check_frame_name(name: str) -> None:
    if not 0 < len(name) <= 10:
        raise ValueError(f"frame name {name!r} must be 1..10 characters (controller limit)")


def set_IO_mode(io_num: int, mode: int) -> dict[str, Any]:
    """Controller IO mode (Gen-3 multiplexed IO1..4): 0 input, 1 output, §1.8."""
    return {"command": "set_IO_mode", "IO_Num": int(io_num), "IO_mode": int(mode)}


def set_DO_state(io_num: int, state: bool | int) -> dict[str, Any]:
    """Controller digital output IO_Num (1..4) high/low. Max 2 mA: drive a relay module, §1.8."""
    return {"command": "set_DO_state", "IO_Num": int(io_num), "state": 1 if state else 0}


def get_IO_state(io_num: int) -> dict[str, Any]:
    """Query controller IO ``IO_Num`` (1..4), §1.8."""
    return {"command": "get_IO_state", "IO_Num": int(io_num)}


def get_IO_output() -> dict[str, Any]:
    """Query the levels of the controller's digital outputs, §1.8."""
    return {"command": "get_IO_output"}


def get_IO_input() -> dict[str, Any]:
    """Query the levels of the controller's digital inputs, §1.8."""
    return {"command": "get_IO_input"}


def set_tool_IO_mode(io_num: int, mode: int) -> dict[str, Any]:
    """Tool-flange IO mode (the wire field is ``state``), §1.8."""
    return {"command": "set_tool_IO_mode", "IO_Num": int(io_num), "state": int(mode)}


def set_tool_DO_state(io_num: int, state: bool | int) -> dict[str, Any]:
    """Tool-flange digital output IO_Num (1..2); level = tool supply voltage."""
    return {"command": "set_tool_DO_state", "IO_Num": int(io_num), "state": 1 if state else 0}


def get_tool_IO_state() -> dict[str, Any]:
    """Query the tool-flange IO's modes and levels (two of each), §1.8."""
    return {"command": "get_tool_IO_state"}


def set_tool_voltage(voltage_type: int) -> dict[str, Any]:
    """Tool supply: 0 = 0 V, 2 = 12 V, 3 = 24 V (1 = 5 V, with which tool IO does not work)."""
    return {"command": "set_tool_voltage", "voltage_type": int(voltage_type)}


#: The official SDK's connect-time queries, in its order (§1.11).
HANDSHAKE_COMMANDS: tuple[str, ...] = (
    "get_arm_software_info",
    "get_arm_current_trajectory",
    "get_realtime_push",
    "get_current_work_frame",
    "get_current_tool_frame",
    "get_install_pose",
    "get_joint_min_pos",
    "get_joint_max_pos",
    "get_joint_max_acc",
    "get_joint_max_speed",
    "get_DH_data",
)

# -- Reply matching --------------------------------------------------------------------------------

#: Query -> the ``state`` (or ``command``) tag of its reply, where that differs from the command name.
REPLY_TAG: dict[str, str] = {
    "get_current_arm_state": "current_arm_state",
    "get_joint_degree": "joint_degree",
    "get_arm_all_state": "arm_all_state",
    "get_controller_state": "controller_state",
    "get_arm_power_state": "arm_power_state",
    "get_arm_software_info": "arm_software_info",
    "get_arm_software_version": "arm_software_version",
    "get_arm_current_trajectory": "arm_current_trajectory",
    "get_current_work_frame": "current_work_frame",
    "get_current_tool_frame": "current_tool_frame",
    "get_total_tool_frame": "total_tool_frame",
    "get_total_work_frame": "total_work_frame",
    "get_install_pose": "install_pose",
    "get_joint_min_pos": "joint_min_pos",
    "get_joint_max_pos": "joint_max_pos",
    "get_joint_max_speed": "joint_max_speed",
    "get_joint_max_acc": "joint_max_acc",
    "get_IO_state": "IO_state",
    "get_IO_output": "IO_output_state",
    "get_IO_input": "IO_input_state",
    "get_tool_IO_state": "tool_IO_state",
    "get_arm_max_line_speed": "arm_max_line_speed",
    "expand_get_state": "expand_state",  # the rail (expansion joint, device 4): rail/axis.py
}

#: Set/action command -> the boolean result key of its acknowledgement (§1.4 – §1.8).
RESULT_KEY: dict[str, str] = {
    "movej": "receive_state",
    "movej_p": "receive_state",
    "movel": "receive_state",
    "movec": "receive_state",
    "set_arm_stop": "arm_stop",
    "set_arm_slow_stop": "arm_slow_stop",
    "set_arm_pause": "arm_pause",
    "set_arm_continue": "arm_continue",
    "set_delete_current_trajectory": "delete_current_trajectory",
    "set_arm_delete_trajectory": "arm_delete_trajectory",
    "clear_system_err": "clear_state",
    "set_manual_tool_frame": "manual_tool_frame",
    "set_change_tool_frame": "change_tool_frame",
    "set_delete_tool_frame": "delete_tool_frame",
    "update_tool_frame": "update_state",
    "set_manual_work_frame": "manual_work_frame",
    "set_change_work_frame": "change_work_frame",
    "set_delete_work_frame": "delete_work_frame",
    "update_work_frame": "update_state",
    "set_IO_mode": "set_state",
    "set_DO_state": "set_state",
    "set_tool_IO_mode": "set_state",
    "set_tool_DO_state": "set_state",
    "set_tool_voltage": "state",
    "set_arm_power": "arm_power",
    "set_realtime_push": "state",
    "expand_set_pos": "set_pos_state",  # the rail (expansion joint, device 4): rail/axis.py
    "expand_set_speed": "set_speed_state",
}

TRAJECTORY_STATE = "current_trajectory_state"


def reply_tag(msg: dict[str, Any]) -> str | None:
    """The tag a message is identified by: its ``command`` field, else its ``state`` field."""
    tag = msg.get("command")
    if not isinstance(tag, str):
        tag = msg.get("state")
    return tag if isinstance(tag, str) else None


def expected_reply_tags(command: str) -> frozenset[str]:
    """Tags that a reply to ``command`` may carry (some queries answer with ``command``, some with ``state``)."""
    tags = {command}
    if command in REPLY_TAG:
        tags.add(REPLY_TAG[command])
    return frozenset(tags)


def is_trajectory_event(msg: dict[str, Any]) -> bool:
    """True for the unsolicited arrival message ``current_trajectory_state`` (§1.2)."""
    return msg.get("state") == TRAJECTORY_STATE


def reply_ok(command: str, msg: dict[str, Any]) -> bool:
    """Result of a set/action command's acknowledgement (True when the command has no result key)."""
    key = RESULT_KEY.get(command)
    if key is None or key not in msg:
        return True
    return bool(msg[key])


# -- Reply parsing ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrajectoryEvent:
    """``current_trajectory_state``: a planned motion ended (``success``) or failed."""

    success: bool
    device: int = 0  # 0 arm, 1 gripper, 2 hand, 3 lift, 4 expansion joint
    trajectory_connect: int = 0  # 0: all queued trajectories done


def parse_trajectory_event(msg: dict[str, Any]) -> TrajectoryEvent:
    """The arrival message ``current_trajectory_state`` as a :class:`TrajectoryEvent`; ProtocolError for any other."""
    if not is_trajectory_event(msg):
        raise ProtocolError(f"not a {TRAJECTORY_STATE} message: {msg!r}")
    return TrajectoryEvent(
        success=bool(msg.get("trajectory_state", False)),
        device=int(msg.get("device", 0)),
        trajectory_connect=int(msg.get("trajectory_connect", 0)),
    )


@dataclass(frozen=True)
class ArmStateReading:
    """Reply to ``get_current_arm_state`` in core units.

    ``joints_rad`` (6,); ``pose`` (6,) ``[x, y, z (m), rx, ry, rz (rad)]`` of the *current tool
    frame in the current work frame*; ``error_codes`` the non-zero controller codes, whatever the
    firmware's format (``err_format``: ``"list"`` current, ``"scalar"`` English doc,
    ``"arm_sys"`` Chinese doc v3.7.4).
    """

    joints_rad: np.ndarray
    pose: np.ndarray
    error_codes: tuple[int, ...]
    err_format: str

    @property
    def errors_text(self) -> list[str]:
        return [describe_error(c) for c in self.error_codes]


def parse_arm_state(msg: dict[str, Any]) -> ArmStateReading:
    """Parse ``{"state":"current_arm_state","arm_state":{...}}`` in any of the three formats (§1.6)."""
    if msg.get("state") != "current_arm_state" or not isinstance(msg.get("arm_state"), dict):
        raise ProtocolError(f"not a current_arm_state reply: {str(msg)[:120]}")
    st = msg["arm_state"]
    try:
        joints = joints_from_wire(st["joint"])
        pose = pose_from_wire(st["pose"])
    except (KeyError, TypeError, ValueError) as exc:
        raise ProtocolError(f"current_arm_state without a valid joint/pose: {str(st)[:120]}") from exc
    if joints.shape != (6,):
        raise ProtocolError(f"current_arm_state has {joints.size} joints, expected 6")
    if "err" in st and isinstance(st["err"], list):
        codes, fmt = [int(c) for c in st["err"]], "list"
    elif "err" in st:
        codes, fmt = [int(st["err"])], "scalar"
    elif "arm_err" in st or "sys_err" in st:
        codes, fmt = [int(st.get("arm_err", 0)), int(st.get("sys_err", 0))], "arm_sys"
    else:
        raise ProtocolError(f"current_arm_state without err / arm_err / sys_err: {str(st)[:120]}")
    return ArmStateReading(joints, pose, tuple(c for c in codes if c != 0), fmt)


def arm_state_message(joints_rad, pose6, error_codes: Sequence[int] = (), err_format: str = "list") -> dict[str, Any]:
    """Build a ``current_arm_state`` reply (simulator side); inverse of :func:`parse_arm_state`."""
    st: dict[str, Any] = {"joint": joints_to_wire(joints_rad), "pose": pose_to_wire(pose6)}
    codes = [int(c) for c in error_codes]
    if err_format == "list":
        st["err"] = codes or [0]
    elif err_format == "scalar":
        st["err"] = codes[0] if codes else 0
    elif err_format == "arm_sys":
        arm = [c for c in codes if c < 0x5000]
        sys_ = [c for c in codes if c >= 0x5000]
        st["arm_err"] = arm[0] if arm else 0
        st["sys_err"] = sys_[0] if sys_ else 0
    else:
        raise ValueError(f"unknown err_format {err_format!r} (list, scalar, arm_sys)")
    return {"state": "current_arm_state", "arm_state": st}


# -- Error codes (§1.12, DOCS json/errorList.md) ---------------------------------------------------

ERROR_CODES: dict[int, str] = {
    0x0000: "normal",
    0x1001: "joint communication error",
    0x1002: "target angle exceeds the joint limit",
    0x1003: "target unreachable (singularity)",
    0x1004: "real-time kernel communication error",
    0x1005: "joint bus error",
    0x1006: "planning kernel error",
    0x1007: "joint overspeed",
    0x1008: "end interface board not connected",
    0x1009: "speed limit exceeded",
    0x100A: "acceleration limit exceeded",
    0x100B: "joint brake not released",
    0x100C: "overspeed during drag teaching",
    0x100D: "collision detected",
    0x100E: "no such work frame",
    0x100F: "no such tool frame",
    0x1010: "joint disabled",
    0x1011: "arc planning error",
    0x1012: "self-collision",
    0x1013: "electronic fence collision",
    0x1014: "joint soft limit exceeded",
    0x2001: "gripper error",
    0x2002: "dexterous hand error",
    0x2003: "six-axis force sensor error",
    0x2004: "one-axis force sensor error",
    0x2005: "output current abnormal",
    0x5003: "controller over-temperature",
    0x5005: "controller over-current",
    0x5006: "controller under-current",
    0x5007: "controller over-voltage",
    0x5008: "controller under-voltage",
    0x5009: "real-time kernel communication error",
}

#: Joint error bit flags (``err_flag`` / ``joint_err_code``), §1.12.
JOINT_ERROR_FLAGS: dict[int, str] = {
    0x0001: "FOC error",
    0x0002: "over-voltage",
    0x0004: "under-voltage",
    0x0008: "over-temperature",
    0x0010: "start failed",
    0x0020: "encoder error",
    0x0040: "over-current",
    0x0080: "software error",
    0x0100: "temperature sensor error",
    0x0200: "position limit error",
    0x0400: "illegal joint ID",
    0x0800: "position tracking error",
    0x1000: "current detection error",
    0x2000: "brake open failed",
    0x4000: "position step warning",
    0x8000: "multi-turn count lost",
}


def describe_error(code: int) -> str:
    """``0x1003: target unreachable (singularity)``; unknown codes are named as such."""
    code = int(code)
    return f"0x{code:04X}: {ERROR_CODES.get(code, 'unknown controller error')}"


def describe_joint_flags(flags: int) -> list[str]:
    """Decode a joint error bit field into its set flags' names."""
    flags = int(flags)
    return [text for bit, text in JOINT_ERROR_FLAGS.items() if flags & bit]

