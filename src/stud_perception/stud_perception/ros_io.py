"""The edge between ROS messages and our numpy core, and the boilerplate every node shares.

One place for: sensor_msgs/Image <-> numpy (no cv_bridge here), CameraInfo -> intrinsics,
Pose <-> rotation/translation, the QoS profiles of our topics, declared-and-validated
parameters, /diagnostics, and a small stamp synchroniser (message_filters does not exist
in the PyPI wheels). Units are converted here: depth 16UC1 millimetres become float
metres with NaN for "no depth" (REP 118) before the core sees them.
"""
from __future__ import annotations

import gc
import math
import sys
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, Quaternion
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from stud_perception.camera_model import CameraModel
from stud_perception.rectify import Rectifier, rectifier_for
from stud_perception.rotations import matrix_to_quaternion, quaternion_to_matrix

# -- QoS ------------------------------------------------------------------------------------------
#: Image/depth/camera-info subscriptions: best effort accepts both best-effort camera drivers
#: and reliable publishers (bag play, our sim camera).
SENSOR_QOS = qos_profile_sensor_data
#: Our own camera publishers: reliable, so a reliable subscriber (an HMI, `ros2 bag record`)
#: gets frames too; a sensor-data subscriber is compatible with it.
CAMERA_PUB_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
#: Layouts and registrations: a late subscriber (the HMI, the matcher started later) gets the last one.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL, history=HistoryPolicy.KEEP_LAST)
#: Results (weld targets, arm state): reliable, a short queue.
RESULT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)


class MessageError(ValueError):
    """A message the core cannot use (wrong encoding, size, ...): the text names field and value."""


# -- Images ---------------------------------------------------------------------------------------
_ENCODINGS = {  # encoding -> (dtype, channels)
    "rgb8": (np.uint8, 3), "bgr8": (np.uint8, 3), "rgba8": (np.uint8, 4), "bgra8": (np.uint8, 4),
    "mono8": (np.uint8, 1), "8UC1": (np.uint8, 1), "8UC3": (np.uint8, 3),
    "mono16": (np.uint16, 1), "16UC1": (np.uint16, 1), "32FC1": (np.float32, 1),
}


def image_to_numpy(msg: Image) -> np.ndarray:
    """sensor_msgs/Image -> array (H, W) or (H, W, C), honouring step and endianness (a copy)."""
    if msg.encoding not in _ENCODINGS:
        raise MessageError(f"image encoding '{msg.encoding}' is not supported; expected one of {sorted(_ENCODINGS)}")
    dtype, channels = _ENCODINGS[msg.encoding]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    row_bytes = msg.width * channels * dt.itemsize
    if msg.step < row_bytes or len(msg.data) < msg.step * msg.height:
        raise MessageError(f"image {msg.width}x{msg.height} {msg.encoding}: step {msg.step} / data "
                           f"{len(msg.data)} bytes too small (need step >= {row_bytes})")
    buf = np.frombuffer(memoryview(msg.data), dtype=np.uint8, count=msg.step * msg.height)
    rows = buf.reshape(msg.height, msg.step)[:, :row_bytes]
    arr = np.ascontiguousarray(rows).view(dt).reshape(msg.height, msg.width, channels)
    arr = arr.astype(dt.newbyteorder("="), copy=False)
    return arr[:, :, 0] if channels == 1 else arr


def numpy_to_image(arr: np.ndarray, encoding: str, stamp: Time | None = None, frame_id: str = "") -> Image:
    """Array -> sensor_msgs/Image (little endian, packed rows)."""
    if encoding not in _ENCODINGS:
        raise MessageError(f"image encoding '{encoding}' is not supported")
    dtype, channels = _ENCODINGS[encoding]
    arr = np.ascontiguousarray(arr, dtype=dtype)
    if (arr.ndim == 2 and channels != 1) or (arr.ndim == 3 and arr.shape[2] != channels):
        raise MessageError(f"array of shape {arr.shape} does not fit encoding {encoding}")
    msg = Image()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.height, msg.width = int(arr.shape[0]), int(arr.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = int(arr.shape[1] * channels * arr.dtype.itemsize)
    msg.data = arr.tobytes()
    return msg


def bgr_to_compressed(bgr: np.ndarray, stamp: Time | None = None, frame_id: str = "",
                      jpeg_quality: int = 80) -> CompressedImage:
    """BGR uint8 (H, W, 3) -> sensor_msgs/CompressedImage, JPEG (what image_transport's ``compressed``
    plugin sends; Foxglove and RViz show it). ``jpeg_quality`` 1..100."""
    import cv2

    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(bgr, dtype=np.uint8),
                           [int(cv2.IMWRITE_JPEG_QUALITY), int(jpeg_quality)])
    if not ok:
        raise MessageError(f"JPEG encoding of a {bgr.shape} image failed")
    msg = CompressedImage(format="jpeg", data=buf.tobytes())
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    return msg


#: 8-bit colour and grey encodings: what OpenCV's detectors (HoughCircles, ...) take. A 16-bit or
#: float image on a colour topic is almost always a depth or IR stream on the wrong topic.
COLOR_ENCODINGS = ("rgb8", "bgr8", "rgba8", "bgra8", "mono8", "8UC1", "8UC3")


def color_to_bgr(msg: Image, rectifier: Rectifier | None = None) -> np.ndarray:
    """Colour image (8-bit: one of COLOR_ENCODINGS) -> BGR uint8 (H, W, 3) for OpenCV, rectified by
    ``rectifier`` (see :func:`camera_rectifier`) if given."""
    bgr = _color_to_bgr(msg)
    return bgr if rectifier is None else rectifier.color(bgr)


def _color_to_bgr(msg: Image) -> np.ndarray:
    if msg.encoding not in COLOR_ENCODINGS:
        raise MessageError(f"colour image encoding '{msg.encoding}' is not supported; expected an 8-bit "
                           f"colour or mono encoding, one of {list(COLOR_ENCODINGS)}")
    arr = image_to_numpy(msg)
    if msg.encoding in ("rgb8",):
        return arr[:, :, ::-1].copy()
    if msg.encoding in ("rgba8",):
        return arr[:, :, 2::-1].copy()
    if msg.encoding in ("bgra8",):
        return arr[:, :, :3].copy()
    if arr.ndim == 2:
        return np.repeat(arr[:, :, None], 3, axis=2)
    return arr


def depth_to_metres(msg: Image, rectifier: Rectifier | None = None) -> np.ndarray:
    """Depth image -> float32 metres (H, W), NaN where there is no depth (REP 118: 0 in 16UC1, NaN in
    32FC1), rectified by ``rectifier`` (see :func:`camera_rectifier`) if given."""
    depth = _depth_to_metres(msg)
    return depth if rectifier is None else rectifier.depth(depth)


def _depth_to_metres(msg: Image) -> np.ndarray:
    arr = image_to_numpy(msg)
    if msg.encoding in ("16UC1", "mono16"):
        out = arr.astype(np.float32) * np.float32(0.001)
        out[arr == 0] = np.nan
        return out
    if msg.encoding == "32FC1":
        out = arr.astype(np.float32, copy=True)
        out[~np.isfinite(out) | (out <= 0)] = np.nan
        return out
    raise MessageError(f"depth encoding '{msg.encoding}' is not supported; expected 16UC1 (mm) or 32FC1 (m)")


# -- Camera info and poses -----------------------------------------------------------------------
def camera_info_to_K(msg: CameraInfo) -> np.ndarray:
    K = np.asarray(msg.k, dtype=np.float64).reshape(3, 3)
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise MessageError(f"camera_info K has fx={K[0, 0]}, fy={K[1, 1]}: not calibrated?")
    return K


def camera_info_from_model(camera: CameraModel, stamp: Time | None = None,
                           frame_id: str = "camera_color_optical_frame", d=(),
                           distortion_model: str = "plumb_bob") -> CameraInfo:
    """The CameraInfo of raw images from ``camera`` with lens distortion ``d`` (none: five zeros)."""
    msg = CameraInfo()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = frame_id
    msg.width, msg.height = camera.width, camera.height
    msg.distortion_model = distortion_model
    msg.d = [float(x) for x in d] if len(d) else [0.0] * 5
    msg.k = [float(x) for x in camera.K.ravel()]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    P = np.hstack([camera.K, np.zeros((3, 1))])
    msg.p = [float(x) for x in P.ravel()]
    return msg


def pose_to_rt(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    q = pose.orientation
    values = {"position.x": pose.position.x, "position.y": pose.position.y, "position.z": pose.position.z,
              "orientation.x": q.x, "orientation.y": q.y, "orientation.z": q.z, "orientation.w": q.w}
    bad = [f"{k}={v}" for k, v in values.items() if not math.isfinite(v)]
    if bad:
        raise MessageError(f"pose has non-finite values ({', '.join(bad)}); expected finite metres and quaternion")
    try:
        R = quaternion_to_matrix(q.x, q.y, q.z, q.w)
    except ValueError:
        raise MessageError("pose orientation is a zero quaternion") from None
    t = np.array([pose.position.x, pose.position.y, pose.position.z])
    return R, t


def rt_to_pose(R: np.ndarray, t: np.ndarray) -> Pose:
    x, y, z, w = matrix_to_quaternion(R)
    return Pose(position=Point(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                orientation=Quaternion(x=x, y=y, z=z, w=w))


def camera_model_from_msgs(info: CameraInfo, pose: Pose, images_rectified: bool = False) -> CameraModel:
    """CameraInfo + the optical frame's pose in `world` -> the pinhole CameraModel of Eq. 1.

    Raw images (``images_rectified`` false, the default: ``image_raw`` topics) are modelled with K;
    if D is non-zero they must go through :func:`camera_rectifier` onto that pinhole camera first.
    Rectified images (a driver's ``image_rect`` topics, whose CameraInfo still carries the raw
    images' K and D) are modelled with the left 3x3 of P, as image_geometry does."""
    R, t = pose_to_rt(pose)
    if not images_rectified:
        K = camera_info_to_K(info)
    else:
        K = np.asarray(info.p, dtype=np.float64).reshape(3, 4)[:, :3]
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise MessageError(f"camera_info P has fx={K[0, 0]}, fy={K[1, 1]}: rectified images need the "
                               "rectified projection P (or set images_rectified false for raw images)")
    return CameraModel(K=K, width=info.width, height=info.height, R_wc=R, t_wc=t)


def camera_rectifier(info: CameraInfo, images_rectified: bool = False) -> Rectifier | None:
    """What maps this camera's raw images onto the pinhole camera of :func:`camera_model_from_msgs`:
    None if there is nothing to do (no distortion, or the images are already rectified).
    Raises RectifyError (a ValueError) for an unsupported model or coefficient count."""
    if images_rectified:
        return None
    return rectifier_for(camera_info_to_K(info), info.d, info.distortion_model, info.width, info.height)


def rectification_note(info: CameraInfo) -> str:
    """One line for the log: which distortion the raw images are rectified from."""
    d = np.asarray(info.d, dtype=np.float64)
    k = int(np.argmax(np.abs(d))) if d.size else 0
    return (f"camera_info has lens distortion (model '{info.distortion_model}', largest d[{k}] = "
            f"{d[k] if d.size else 0.0:g}): rectifying the raw images onto the pinhole camera with its K")


def stamp_to_ns(stamp: Time) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


# -- Parameters -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Param:
    """A node parameter: name, default, description, and an optional range or validator.

    ``validate(value) -> str | None`` returns a reason to reject the value. Numbers (and lists of
    numbers) must be finite whatever the range: NaN compares false with every bound -- unless
    ``nan_means`` says what a NaN stands for (a documented "not set" value, e.g. "the believed
    hand-eye"), in which case NaN is accepted and inf still is not.
    """

    name: str
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple | None = None
    read_only: bool = False
    validate: Callable[[Any], str | None] | None = None
    nan_means: str | None = None

    def expected(self) -> str:
        """What a valid value looks like, for error messages ("a number in [0.005, 0.3]")."""
        if self.choices is not None:
            return f"one of {list(self.choices)}"
        d = self.default
        kind = ("true or false" if isinstance(d, bool) else "an integer" if isinstance(d, int)
                else "a number" if isinstance(d, float) else "a string" if isinstance(d, str)
                else "a list of numbers" if isinstance(d, (list, tuple)) else type(d).__name__)
        if self.min is not None and self.max is not None:
            return f"{kind} in [{self.min}, {self.max}]"
        if self.min is not None:
            return f"{kind} >= {self.min}"
        if self.max is not None:
            return f"{kind} <= {self.max}"
        return kind

    def check(self, value: Any) -> str | None:
        if self.choices is not None and value not in self.choices:
            return f"{self.name}={value!r}: expected one of {list(self.choices)}"
        numbers = value if isinstance(value, (list, tuple)) else [value]
        allowed = (lambda v: math.isfinite(v) or math.isnan(v)) if self.nan_means else math.isfinite
        if any(isinstance(v, float) and not allowed(v) for v in numbers):
            extra = f" (or NaN: {self.nan_means})" if self.nan_means else ""
            return f"{self.name}={_show(value)}: expected {self.expected()}, finite{extra}"
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if (self.min is not None and value < self.min) or (self.max is not None and value > self.max):
                return f"{self.name}={value!r}: expected {self.expected()}"
        if self.validate is not None:
            return self.validate(value)
        return None


def _show(value: Any) -> str:
    return repr(list(value)) if isinstance(value, (list, tuple)) else repr(value)


#: The matcher's and the registration's: which camera model the images follow.
IMAGES_RECTIFIED_PARAM = Param(
    "images_rectified", False, "the images are rectified already (a driver's image_rect topics): model them with "
    "camera_info P and ignore D; false: raw images (image_raw), rectified here when D is non-zero")


def declare_params(node: Node, params: list[Param], on_change: Callable[[dict], None] | None = None,
                   check: Callable[[dict], str | None] | None = None) -> dict:
    """Declare ``params`` with descriptions and ranges, reject bad values, return the current values.

    At start-up a bad value (out of range, wrong type, non-finite, refused by a validator, or a
    combination ``check(values)`` refuses, e.g. a box whose min is above its max) is logged as one
    line naming the parameter, the value and what is expected, and ends the node with
    ``SystemExit(2)`` -- never a traceback, never a node that starts and fails later. At run time
    the same checks refuse the change through the parameter callback.
    """
    from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException

    by_name = {p.name: p for p in params}
    problems = []
    for p in params:
        desc = ParameterDescriptor(description=p.description, read_only=p.read_only)
        if p.min is not None and p.max is not None and isinstance(p.default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(p.min), to_value=float(p.max))]
        elif p.min is not None and p.max is not None and isinstance(p.default, int) and not isinstance(p.default, bool):
            desc.integer_range = [IntegerRange(from_value=int(p.min), to_value=int(p.max), step=1)]
        try:
            node.declare_parameter(p.name, p.default, desc)
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            # rclpy refused the override against the range/type: read it back untyped to say what it was
            value = node.declare_parameter(p.name, p.default, ParameterDescriptor(dynamic_typing=True)).value
            wrong_type = isinstance(exc, InvalidParameterTypeException)
            problems.append(f"{p.name}={_show(value)}"
                            + (f" ({type(value).__name__})" if wrong_type else "") + f": expected {p.expected()}")
    values = {p.name: node.get_parameter(p.name).value for p in params}
    problems += [r for p in params if not any(x.startswith(p.name + "=") for x in problems)
                 and (r := p.check(values[p.name]))]
    if not problems and check is not None:
        problems += [r for r in [check(values)] if r]
    if problems:
        for r in problems:
            node.get_logger().fatal(f"bad parameter {r}")
        raise SystemExit(2)

    def _callback(changes) -> SetParametersResult:
        update = {}
        for change in changes:
            spec = by_name.get(change.name)
            if spec is None:
                continue
            reason = spec.check(change.value)
            if reason:
                node.get_logger().warn(f"rejected parameter {reason}")
                return SetParametersResult(successful=False, reason=reason)
            update[change.name] = change.value
        if update and check is not None:
            reason = check({**values, **update})
            if reason:
                node.get_logger().warn(f"rejected parameters {reason}")
                return SetParametersResult(successful=False, reason=reason)
        values.update(update)
        if update and on_change is not None:
            on_change(update)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(_callback)
    return values


# -- Diagnostics ------------------------------------------------------------------------------------
class Diagnostics:
    """Publishes one DiagnosticStatus for this node on /diagnostics (call :meth:`publish` from a timer)."""

    OK, WARN, ERROR, STALE = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR, DiagnosticStatus.STALE

    def __init__(self, node: Node, name: str | None = None, hardware_id: str = ""):
        self._node = node
        self._pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.name = name or f"{node.get_name()}"
        self.hardware_id = hardware_id
        self.level = DiagnosticStatus.OK
        self.message = "starting"
        self.values: dict[str, str] = {}

    def set(self, level: int, message: str, **values: Any) -> None:
        self.level, self.message = level, message
        self.values.update({k: str(v) for k, v in values.items()})

    def publish(self) -> None:
        status = DiagnosticStatus(level=self.level, name=self.name, message=self.message,
                                  hardware_id=self.hardware_id,
                                  values=[KeyValue(key=k, value=v) for k, v in self.values.items()])
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(arr)


# -- Stamp synchroniser ----------------------------------------------------------------------------
class StampSync:
    """Pairs messages of several streams that carry the same header stamp (within ``slop_ns``).

    Our camera publishes colour, depth, camera info and pose with one shared stamp (one
    triggered shot); a real driver's streams may differ by a little, hence the slop. Calls
    ``callback(dict name -> msg)`` once per complete set; incomplete sets older than
    ``max_sets`` newer ones are dropped.
    """

    def __init__(self, names: list[str], callback: Callable[[dict], None], slop_ns: int = 0, max_sets: int = 10):
        self.names = list(names)
        self.callback = callback
        self.slop_ns = slop_ns
        self.max_sets = max_sets
        self._sets: OrderedDict[int, dict] = OrderedDict()

    def add(self, name: str, msg: Any) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        key = next((k for k in self._sets if abs(k - stamp) <= self.slop_ns), stamp)
        entry = self._sets.setdefault(key, {})
        entry[name] = msg
        if len(entry) == len(self.names):
            del self._sets[key]
            for older in [k for k in self._sets if k < key]:  # a newer complete set supersedes them
                del self._sets[older]
            self.callback(entry)
        while len(self._sets) > self.max_sets:
            self._sets.popitem(last=False)


def keep_freed_memory(max_block_bytes: int = 32 << 20) -> bool:
    """Tell glibc's allocator to serve blocks up to ``max_block_bytes`` from the heap and keep freed
    memory instead of returning it to the kernel.

    Every frame allocates and frees image-sized arrays (depth in metres, window point clouds: 1-10
    MB). By default glibc maps each with mmap and unmaps it on free, so every frame touches fresh
    pages: thousands of page faults per frame, which on a virtual machine cost as much as the
    matching itself (bench/bench_latency.py, A/B here: matcher p50 24-27 -> 18-21 ms, p99 33-38 ->
    25-29 ms). The price is that the process keeps its peak heap. Returns False where there is no
    glibc or it refuses a setting.
    """
    import ctypes

    M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, int(max_block_bytes)) and mallopt(M_TRIM_THRESHOLD, 1 << 30)
                and mallopt(M_TOP_PAD, 64 << 20))


def spin_node(node_factory: Callable[[], Node], args: list[str] | None = None, multithreaded: bool = False) -> int:
    """`main()` body shared by our nodes: init, spin (``multithreaded`` for nodes whose service
    callbacks wait on their own subscriptions), clean shutdown on Ctrl-C (no traceback)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor

    keep_freed_memory()
    rclpy.init(args=args if args is not None else sys.argv)
    node = None
    code = 0
    try:
        node = node_factory()
        # Everything built so far (modules, the node) lives as long as the process: move it out of
        # the collector's sight, so a full collection -- triggered at random while a callback
        # allocates messages -- does not walk a few hundred thousand objects (tens of ms).
        gc.freeze()
        rclpy.spin(node, executor=MultiThreadedExecutor(num_threads=4) if multithreaded else None)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SystemExit as exc:
        code = int(exc.code or 0)
    except RuntimeError:
        # Ctrl-C shuts the context down under a take in progress (a large image arriving):
        # rclpy then raises from the middle of it. That is a shutdown, not a failure.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.try_shutdown()
    return code
