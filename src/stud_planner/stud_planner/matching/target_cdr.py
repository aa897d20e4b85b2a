"""A view's weld targets as the CDR bytes of a ``stud_welding_msgs/WeldTargetArray`` (no rclpy).

The matcher node's hot path. Building 100 WeldTarget message objects and letting rclpy convert
them costs about 5 ms a view, more than the matching; the same message written here from the
arrays costs a tenth of that, and ``Publisher.publish`` sends bytes as they are. Subscribers
see an ordinary WeldTargetArray: tests deserialise these bytes with rclpy and compare each field,
and compare them with rclpy's own serialisation.

The encoding is the one every ROS 2 Jazzy RMW uses on the wire: plain CDR (XCDR1), little-endian,
a 4-byte encapsulation header, each primitive aligned to its size counted from the end of that
header, strings as a uint32 length that includes the terminating NUL. If the message definitions
change, ``tests/ros/test_target_cdr.py`` fails until this module follows.
"""
from __future__ import annotations

import struct

import numpy as np

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little-endian
#: WeldTarget from drawing_x to gun_clearance: 14 float64 (drawing_x/y, pose position + orientation,
#: normal, pixel_u/v), uint32 view_index and iterations, 7 float64 (xy_error, inclination,
#: normal_rms, normal_sigma, lean_bound, fill_ratio, gun_clearance). It starts 8-aligned and holds
#: no padding, so one numpy row is the wire bytes.
_BLOCK = np.dtype([("f", "<f8", 14), ("u", "<u4", 2), ("g", "<f8", 7)])


def _align(buf: bytearray, size: int) -> None:
    buf += bytes(-(len(buf) - len(_ENCAPSULATION)) % size)


def _string(buf: bytearray, text: str) -> None:
    data = text.encode("utf-8")
    _align(buf, 4)
    buf += struct.pack("<I", len(data) + 1)
    buf += data
    buf.append(0)


def weld_target_array_cdr(targets, view_index: int, stamp_sec: int, stamp_nanosec: int,
                          frame_id: str = "world") -> bytes:
    """The WeldTargetArray of a view_planning.ViewTargets: every stud in drawing order, NaN
    positions (no match) sent as NaN so nobody mistakes them for 0, a NaN orientation as the
    identity; ``algorithm``, ``match_time`` and ``total_iterations`` from the targets."""
    n = len(targets.ids)
    block = np.zeros(n, _BLOCK)
    block["f"] = np.hstack([targets.drawing_xy_m, targets.position_w, targets.message_quat_xyzw, targets.normal_w,
                            targets.matches.pixel_uv])
    block["u"][:, 0] = view_index
    block["u"][:, 1] = targets.matches.iterations
    block["g"] = np.column_stack([targets.matches.xy_residual_m, targets.inclination_deg, targets.normal_rms_m,
                                  targets.normal_sigma_deg, targets.lean_bound_deg, targets.poses.fill_ratio,
                                  targets.gun_clearance_m])
    rows = block.tobytes()

    buf = bytearray(_ENCAPSULATION)
    buf += struct.pack("<iI", stamp_sec, stamp_nanosec)
    _string(buf, frame_id)
    _align(buf, 4)
    buf += struct.pack("<I", n)
    size = _BLOCK.itemsize
    for i, (sid, status, text) in enumerate(zip(targets.ids, targets.status.tolist(), targets.status_text)):
        _string(buf, sid)
        _align(buf, 8)
        buf += rows[i * size:(i + 1) * size]
        buf.append(status)
        _string(buf, text)
        _string(buf, targets.reason(i) if status else "")
    _string(buf, targets.algorithm)
    _align(buf, 8)
    buf += struct.pack("<dQ", float(targets.match_time_s), int(targets.matches.total_iterations))
    buf += struct.pack("<I", view_index)
    return bytes(buf)
