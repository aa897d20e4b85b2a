"""The edge between camera messages and our numpy core: sensor_msgs/Image <-> numpy (no cv_bridge
here), CameraInfo -> intrinsics and the pinhole CameraModel of Eq. 1, rectification of raw images,
and :func:`decode_view`: one RGB-D view (camera info, pose, depth, colour) decoded and checked once,
for every node and ``plan`` (:func:`decode_depth_view` without the colour). Units are converted
here: depth 16UC1 millimetres become float metres with NaN for "no depth" (REP 118) before the core
sees them. (QoS, parameters, poses and stamps: stud_common.ros_io.)
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Pose
from sensor_msgs.msg import CameraInfo, CompressedImage, Image

from stud_common import names
from stud_common.ros_io import MessageError, Param, pose_to_rt
from stud_perception.camera_model import CameraModel, CameraModelError
from stud_perception.depth_image import DepthImageError, depth_image_to_m
from stud_perception.rectify import Rectifier, rectifier_for

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
    try:  # the one mm -> m conversion (depth_image), at the message edge
        return depth_image_to_m(image_to_numpy(msg), msg.encoding)
    except DepthImageError:
        raise MessageError(f"depth encoding '{msg.encoding}' is not supported; "
                           "expected 16UC1 (mm) or 32FC1 (m)") from None


def camera_info_to_K(msg: CameraInfo) -> np.ndarray:
    """The intrinsic matrix K (3, 3) [px] of a CameraInfo; MessageError when fx or fy is not positive."""
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


def camera_model_from_msgs(info: CameraInfo, pose: Pose, images_rectified: bool = False) -> CameraModel:
    """CameraInfo + the optical frame's pose in `world` -> the pinhole CameraModel of Eq. 1.

    Raw images (``images_rectified`` false, the default: ``image_raw`` topics) are modelled with K;
    if D is non-zero they must go through :func:`camera_rectifier` onto that pinhole camera first.
    Rectified images (a driver's ``image_rect`` topics, whose CameraInfo still carries the raw
    images' K and D) are modelled with the left 3x3 of P, as image_geometry does."""
    R, t = pose_to_rt(pose)
    return CameraModel(K=camera_matrix(info, images_rectified), width=info.width, height=info.height, R_wc=R, t_wc=t)


def camera_matrix(info: CameraInfo, images_rectified: bool = False) -> np.ndarray:
    """The 3x3 intrinsics the images follow: K for raw images, the left 3x3 of P for rectified ones
    (see :func:`camera_model_from_msgs`)."""
    if not images_rectified:
        return camera_info_to_K(info)
    K = np.asarray(info.p, dtype=np.float64).reshape(3, 4)[:, :3]
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise MessageError(f"camera_info P has fx={K[0, 0]}, fy={K[1, 1]}: rectified images need the "
                           "rectified projection P (or set images_rectified false for raw images)")
    return K


#: A view's topics by role, as nodes name them in their view dicts: the default names.
VIEW_TOPICS = {"color": names.COLOR_IMAGE, "depth": names.DEPTH_IMAGE, "info": names.CAMERA_INFO,
               "pose": names.CAMERA_POSE}


def view_topics(node) -> dict[str, str]:
    """:data:`VIEW_TOPICS` as an rclpy ``node`` resolves them (its remappings applied): the names its
    view's errors give."""
    return {role: node.resolve_topic_name(topic) for role, topic in VIEW_TOPICS.items()}


@dataclass(frozen=True, eq=False)
class DepthView:
    """One view's camera and depth, decoded and checked (:func:`decode_depth_view`): the pinhole
    camera of Eq. 1 and ``depth_m`` (H, W) float32 metres, NaN = no depth, on that camera's image
    (rectified by ``rectifier``; None: nothing to do). ``topics``: role -> topic, for the errors."""

    camera: CameraModel
    depth_m: np.ndarray
    rectifier: Rectifier | None
    topics: Mapping[str, str]

    def color(self, msg: Image) -> np.ndarray:
        """A colour image of this view as BGR uint8 (H, W, 3) on the view's camera (rectified), its
        size and encoding checked. Raises MessageError naming the topic and the sizes."""
        _check_size(msg, "colour", self.topics["color"], self.camera.width, self.camera.height, self.topics["info"])
        return _decoded(color_to_bgr, msg, self.rectifier, self.topics["color"])


@dataclass(frozen=True, eq=False)
class RgbdView(DepthView):
    """A :class:`DepthView` with its colour image ``color_bgr`` (H, W, 3) uint8 (:func:`decode_view`)."""

    color_bgr: np.ndarray


def decode_view(info: CameraInfo, pose: Pose, depth: Image, color: Image, images_rectified: bool = False,
                topics: Mapping[str, str] = VIEW_TOPICS) -> RgbdView:
    """A view's camera info, camera pose, depth and colour image -> :class:`RgbdView`, checked as
    :func:`decode_depth_view` checks, the colour image as :meth:`DepthView.color`."""
    view = decode_depth_view(info, pose, depth, images_rectified, topics)
    return RgbdView(view.camera, view.depth_m, view.rectifier, view.topics, view.color(color))


def decode_depth_view(info: CameraInfo, pose: Pose, depth: Image, images_rectified: bool = False,
                      topics: Mapping[str, str] = VIEW_TOPICS) -> DepthView:
    """A view's camera info, camera pose (the optical frame in `world`) and depth image ->
    :class:`DepthView`. Checked once, here: the camera (K, or P for ``images_rectified``; the pose),
    that the depth image has camera_info's size (registered to colour), its encoding. Raises
    MessageError (a ValueError) naming the topic (``topics``: role -> name) and the values."""
    try:
        R, t = pose_to_rt(pose)
    except MessageError as exc:
        raise MessageError(f"{exc} (on {topics['pose']})") from None
    try:
        camera = CameraModel(K=camera_matrix(info, images_rectified), width=info.width, height=info.height,
                             R_wc=R, t_wc=t)
        rectifier = camera_rectifier(info, images_rectified)
    except (MessageError, CameraModelError, ValueError) as exc:
        raise MessageError(f"{exc} (on {topics['info']})") from None
    _check_size(depth, "depth", topics["depth"], info.width, info.height, topics["info"])
    return DepthView(camera, _decoded(depth_to_metres, depth, rectifier, topics["depth"]), rectifier, dict(topics))


def _check_size(msg: Image, what: str, topic: str, width: int, height: int, info_topic: str) -> None:
    if (msg.width, msg.height) != (width, height):
        raise MessageError(f"{what} image {topic} is {msg.width}x{msg.height}, camera_info {info_topic} "
                           f"{width}x{height}: they must agree (depth registered to colour)")


def _decoded(decode, msg: Image, rectifier: Rectifier | None, topic: str) -> np.ndarray:
    try:
        return decode(msg, rectifier)
    except (MessageError, ValueError) as exc:
        raise MessageError(f"{exc} (on {topic})") from None


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


#: The matcher's and the registration's: which camera model the images follow.
IMAGES_RECTIFIED_PARAM = Param(
    "images_rectified", False, "the images are rectified already (a driver's image_rect topics): model them with "
    "camera_info P and ignore D; false: raw images (image_raw), rectified here when D is non-zero")


