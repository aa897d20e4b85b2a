"""One view decode (image_io.decode_view) for every node and `plan`: a shot's four messages become
the camera of Eq. 1 and the images on it, and whatever does not fit -- sizes that disagree, an
encoding, a pose, the intrinsics -- is one error naming the topic and the values."""
from __future__ import annotations

import copy

import numpy as np
import pytest

pytest.importorskip("rclpy")
from stud_common import ros_io  # noqa: E402
from stud_perception import image_io  # noqa: E402
from stud_perception.camera_node import shot_messages  # noqa: E402
from stud_perception.scene import demo_dome_scene  # noqa: E402
from stud_perception.scene_cameras import distort_view, view_camera  # noqa: E402
from stud_perception.scene_render import render  # noqa: E402

TOPICS = {"color": "/cam/rgb", "depth": "/cam/depth", "info": "/cam/info", "pose": "/cam/pose"}


@pytest.fixture(scope="module")
def shot():
    cam = view_camera((0.1, -0.2, 0.0), 0.5, width=320, height=240)
    view = render(demo_dome_scene(), cam, seed=3)
    return view, shot_messages(view, "16UC1", ros_io.ns_to_stamp(1_000_000_000))


def _decode(msgs, **kwargs):
    return image_io.decode_view(msgs["info"], msgs["pose"].pose, msgs["depth"], msgs["color"], topics=TOPICS,
                                **kwargs)


def test_a_shot_decodes_to_its_camera_and_images(shot):
    view, msgs = shot
    got = _decode(msgs)
    np.testing.assert_allclose(got.camera.K, view.camera.K)
    np.testing.assert_allclose(got.camera.R_wc, view.camera.R_wc, atol=1e-12)
    np.testing.assert_allclose(got.camera.t_wc, view.camera.t_wc, atol=1e-12)
    np.testing.assert_array_equal(got.color_bgr, view.color_bgr)
    np.testing.assert_array_equal(np.isnan(got.depth_m), view.depth_mm == 0)
    np.testing.assert_allclose(got.depth_m[view.depth_mm > 0], view.depth_mm[view.depth_mm > 0] * 1e-3, rtol=1e-6)
    assert got.rectifier is None
    depth_only = image_io.decode_depth_view(msgs["info"], msgs["pose"].pose, msgs["depth"], topics=TOPICS)
    np.testing.assert_array_equal(depth_only.color(msgs["color"]), view.color_bgr)  # a colour image that came later


def test_raw_images_with_distortion_are_rectified_onto_the_pinhole_camera(shot):
    view, _msgs = shot
    raw = distort_view(view, (0.05, -0.02, 0.0, 0.0, 0.0))
    msgs = shot_messages(raw, "16UC1", ros_io.ns_to_stamp(1))
    got = _decode(msgs)
    assert got.rectifier is not None
    inside = (slice(40, -40), slice(40, -40))  # the border loses pixels to the distortion
    assert np.abs(got.color_bgr[inside].astype(int) - view.color_bgr[inside]).mean() < 8


@pytest.mark.parametrize(("role", "width", "height"), [("depth", 640, 480), ("color", 320, 200)])
def test_images_whose_size_is_not_camera_infos_are_named_with_the_sizes(shot, role, width, height):
    _view, msgs = shot
    msgs = dict(msgs)
    arr = image_io.image_to_numpy(msgs[role])
    big = np.zeros((height, width) + arr.shape[2:], arr.dtype)
    msgs[role] = image_io.numpy_to_image(big, msgs[role].encoding)
    what = {"depth": "depth", "color": "colour"}[role]
    with pytest.raises(ros_io.MessageError, match=rf"{what} image {TOPICS[role]} is {width}x{height}, camera_info "
                                                  rf"/cam/info 320x240: they must agree"):
        _decode(msgs)
    if role == "color":
        late = image_io.decode_depth_view(msgs["info"], msgs["pose"].pose, msgs["depth"], topics=TOPICS)
        with pytest.raises(ros_io.MessageError, match=r"colour image /cam/rgb is 320x200"):
            late.color(msgs["color"])


def test_an_unusable_encoding_pose_or_camera_info_names_its_topic(shot):
    _view, msgs = shot
    bad = dict(msgs, color=copy.deepcopy(msgs["color"]))
    bad["color"].encoding, bad["color"].step = "16UC1", bad["color"].width * 2
    with pytest.raises(ros_io.MessageError, match=r"colour image encoding '16UC1' is not supported.* \(on /cam/rgb\)"):
        _decode(bad)
    bad = dict(msgs, depth=copy.deepcopy(msgs["depth"]))
    bad["depth"].encoding = "8UC1"
    with pytest.raises(ros_io.MessageError, match=r"depth encoding '8UC1' is not supported.* \(on /cam/depth\)"):
        _decode(bad)
    bad = dict(msgs, pose=copy.deepcopy(msgs["pose"]))
    bad["pose"].pose.orientation.w = float("nan")
    with pytest.raises(ros_io.MessageError, match=r"orientation.w=nan.* \(on /cam/pose\)"):
        _decode(bad)
    bad = dict(msgs, info=copy.deepcopy(msgs["info"]))
    bad["info"].k = [0.0] * 9
    with pytest.raises(ros_io.MessageError, match=r"camera_info K has fx=0.0.* \(on /cam/info\)"):
        _decode(bad)
    with pytest.raises(ros_io.MessageError, match=r"camera_info P has fx=0.0.* \(on /cam/info\)"):
        _decode(dict(msgs, info=_without_p(msgs["info"])), images_rectified=True)


def _without_p(info):
    info = copy.deepcopy(info)
    info.p = [0.0] * 12
    return info
