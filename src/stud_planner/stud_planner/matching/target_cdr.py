"""A view's weld targets as the CDR bytes of a ``stud_welding_msgs/WeldTargetArray`` (no rclpy).

The matcher node's hot path: the message written here from the table's columns costs a tenth of
building WeldTarget objects and letting rclpy convert them, and ``Publisher.publish`` sends bytes
as they are. Subscribers see an ordinary WeldTargetArray.

The encoding is the one every ROS 2 Jazzy RMW uses on the wire: plain CDR (XCDR1), little-endian,
a 4-byte encapsulation header, each primitive aligned to its size counted from the end of that
header, strings as a uint32 length that includes the terminating NUL. The fields, in message order,
are :data:`WELD_TARGET_FIELDS` and :data:`WELD_TARGET_ARRAY_FIELDS`; ``tests/ros/test_target_cdr.py``
derives the same lists from the ``.msg`` files, so the two cannot drift apart.
"""
from __future__ import annotations

import struct

import numpy as np

from stud_planner.matching.target_table import TargetTable

_ENCAPSULATION = b"\x00\x01\x00\x00"  # CDR, little-endian

#: WeldTarget's fields from drawing_x to gun_clearance, in message order: (field, CDR type, the
#: table's column, component; a NaN orientation goes as the identity). They start 8-aligned and need
#: no padding, so one numpy row of :data:`_BLOCK` is their wire bytes.
WELD_TARGET_BLOCK = (
    ("drawing_x", "float64", "drawing_xy_m", 0), ("drawing_y", "float64", "drawing_xy_m", 1),
    ("pose.position.x", "float64", "position_w", 0), ("pose.position.y", "float64", "position_w", 1),
    ("pose.position.z", "float64", "position_w", 2),
    ("pose.orientation.x", "float64", "quat_xyzw", 0), ("pose.orientation.y", "float64", "quat_xyzw", 1),
    ("pose.orientation.z", "float64", "quat_xyzw", 2), ("pose.orientation.w", "float64", "quat_xyzw", 3),
    ("normal.x", "float64", "normal_w", 0), ("normal.y", "float64", "normal_w", 1),
    ("normal.z", "float64", "normal_w", 2),
    ("pixel_u", "float64", "pixel_uv", 0), ("pixel_v", "float64", "pixel_uv", 1),
    ("view_index", "uint32", "view_index", None), ("iterations", "uint32", "iterations", None),
    ("xy_error", "float64", "xy_error_m", None), ("inclination", "float64", "inclination_deg", None),
    ("normal_rms", "float64", "normal_rms_m", None), ("normal_sigma", "float64", "normal_sigma_deg", None),
    ("lean_bound", "float64", "lean_bound_deg", None), ("fill_ratio", "float64", "fill_ratio", None),
    ("gun_clearance", "float64", "gun_clearance_m", None),
)
#: Every WeldTarget field, in message order, as (field, CDR type).
WELD_TARGET_FIELDS = (("stud_id", "string"), *((f, t) for f, t, _c, _k in WELD_TARGET_BLOCK),
                      ("status", "uint8"), ("status_text", "string"), ("reason", "string"))
#: Every WeldTargetArray field, in message order (what :func:`weld_target_array_cdr` writes).
WELD_TARGET_ARRAY_FIELDS = (("header.stamp.sec", "int32"), ("header.stamp.nanosec", "uint32"),
                            ("header.frame_id", "string"), ("targets", "WeldTarget[]"), ("algorithm", "string"),
                            ("match_time", "float64"), ("total_iterations", "uint64"), ("view_index", "uint32"))

_NUMPY_TYPE = {"float64": "<f8", "uint32": "<u4"}
_BLOCK = np.dtype([(f, _NUMPY_TYPE[t]) for f, t, _c, _k in WELD_TARGET_BLOCK])
_OFFSETS = np.cumsum([0] + [np.dtype(_NUMPY_TYPE[t]).itemsize for _f, t, _c, _k in WELD_TARGET_BLOCK])
assert all(offset % np.dtype(_NUMPY_TYPE[t]).itemsize == 0
           for offset, (_f, t, _c, _k) in zip(_OFFSETS, WELD_TARGET_BLOCK)), "the block would need padding"


def _align(buf: bytearray, size: int) -> None:
    buf += bytes(-(len(buf) - len(_ENCAPSULATION)) % size)


def _string(buf: bytearray, text: str) -> None:
    data = text.encode("utf-8")
    _align(buf, 4)
    buf += struct.pack("<I", len(data) + 1)
    buf += data
    buf.append(0)


def weld_target_block(targets: TargetTable, view_index: int | None = None) -> np.ndarray:
    """(N,) rows of :data:`_BLOCK`: the targets' fields from drawing_x to gun_clearance;
    ``view_index``, if given, replaces the table's in every row."""
    block = np.zeros(len(targets.ids), _BLOCK)
    columns = {"quat_xyzw": targets.message_quat_xyzw}
    for field, _type, column, k in WELD_TARGET_BLOCK:
        values = columns.get(column)
        if values is None:
            values = columns[column] = getattr(targets, column)
        block[field] = values if k is None else values[:, k]
    if view_index is not None:
        block["view_index"] = view_index
    return block


def weld_target_array_cdr(targets, view_index: int, stamp_sec: int, stamp_nanosec: int,
                          frame_id: str = "world") -> bytes:
    """The WeldTargetArray of one view's targets (a view_targets.ViewTargets): every stud in drawing
    order, each as matched on ``view_index`` (the array is one view), NaN positions (no match) sent
    as NaN so nobody mistakes them for 0, a NaN orientation as the identity; ``algorithm``,
    ``match_time`` and ``total_iterations`` from the targets."""
    rows = weld_target_block(targets, view_index).tobytes()
    size = _BLOCK.itemsize
    buf = bytearray(_ENCAPSULATION)
    buf += struct.pack("<iI", stamp_sec, stamp_nanosec)
    _string(buf, frame_id)
    _align(buf, 4)
    buf += struct.pack("<I", len(targets.ids))
    for i, (sid, status, text, reason) in enumerate(zip(targets.ids, targets.status.tolist(), targets.status_text,
                                                        targets.reasons.tolist())):
        _string(buf, sid)
        _align(buf, 8)
        buf += rows[i * size:(i + 1) * size]
        buf.append(status)
        _string(buf, text)
        _string(buf, reason)
    _string(buf, targets.algorithm)
    _align(buf, 8)
    buf += struct.pack("<dQ", float(targets.match_time_s), int(targets.matches.total_iterations))
    buf += struct.pack("<I", view_index)
    return bytes(buf)
