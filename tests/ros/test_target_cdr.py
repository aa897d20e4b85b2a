"""The matcher's hand-written WeldTargetArray bytes are what rclpy itself would send: rclpy reads
every field back as the view's arrays say, and its own serialisation of that message has the same
layout — on a real rendered view (matched, out-of-view and failed studs, NaN positions),
with odd-length and non-ASCII ids, and with no studs at all. The writer's field layout is the
``.msg`` files' (derived from them here), and a message read back into a TargetTable is the table sent."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from stud_welding_msgs.msg import WeldTargetArray

from stud_perception.scene import demo_dome_scene
from stud_perception.scene_cameras import demo_camera
from stud_perception.scene_render import render
from stud_planner.matching.target_cdr import WELD_TARGET_ARRAY_FIELDS, WELD_TARGET_FIELDS, weld_target_array_cdr
from stud_planner.matching.target_table import COLUMNS
from stud_planner.matching.view_targets import STATUS_OUT_OF_VIEW, plan_view
from stud_planner.msg_convert import weld_target_table


@pytest.fixture(scope="module")
def view_targets():
    scene = demo_dome_scene()
    cam = demo_camera()
    # shifted so some studs fall outside the image (NaN positions, identity orientation)
    cam = cam.with_pose(cam.R_wc, cam.t_wc + np.array([0.3, 0.0, 0.0]))
    view = render(scene, cam, seed=2, depth_noise_m=0.0005)
    targets = plan_view(list(scene.stud_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world,
                        view.depth_m, cam)
    # matched and unmatched studs, or the test proves less
    assert targets.ok.any() and (targets.status == STATUS_OUT_OF_VIEW).any()
    return targets


def _check(targets, view_index=7, sec=1_700_000_123, nanosec=456_789_000, frame_id="world"):
    data = weld_target_array_cdr(targets, view_index, sec, nanosec, frame_id)
    msg = deserialize_message(data, WeldTargetArray)
    # the same layout as rclpy's (its padding bytes are whatever was in memory, so compare the size)
    assert len(serialize_message(msg)) == len(data)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id) == (sec, nanosec, frame_id)
    assert (msg.algorithm, msg.view_index) == (targets.algorithm, view_index)
    assert msg.match_time == targets.match_time_s
    assert msg.total_iterations == targets.matches.total_iterations
    assert [t.stud_id for t in msg.targets] == targets.ids
    assert [t.status for t in msg.targets] == targets.status.tolist()
    assert [t.status_text for t in msg.targets] == targets.status_text
    assert [t.reason for t in msg.targets] == [targets.reason(i) for i in range(len(targets.ids))]

    def col(f, width):
        return np.array([f(t) for t in msg.targets], dtype=np.float64).reshape(len(msg.targets), width)

    nan_eq = dict(equal_nan=True, rtol=0, atol=0)
    np.testing.assert_allclose(col(lambda t: (t.drawing_x, t.drawing_y), 2), targets.drawing_xy_m, **nan_eq)
    np.testing.assert_allclose(col(lambda t: (t.pose.position.x, t.pose.position.y, t.pose.position.z), 3),
                               targets.position_w.reshape(-1, 3), **nan_eq)
    np.testing.assert_allclose(col(lambda t: (t.normal.x, t.normal.y, t.normal.z), 3),
                               targets.normal_w.reshape(-1, 3), **nan_eq)
    q = col(lambda t: (t.pose.orientation.x, t.pose.orientation.y, t.pose.orientation.z, t.pose.orientation.w), 4)
    finite = np.all(np.isfinite(targets.quat_xyzw.reshape(-1, 4)), axis=1)
    np.testing.assert_array_equal(q[finite], targets.quat_xyzw.reshape(-1, 4)[finite])
    np.testing.assert_array_equal(q[~finite], np.tile([0.0, 0.0, 0.0, 1.0], (int((~finite).sum()), 1)))
    np.testing.assert_allclose(col(lambda t: (t.pixel_u, t.pixel_v), 2), targets.matches.pixel_uv.reshape(-1, 2),
                               **nan_eq)
    np.testing.assert_allclose(col(lambda t: (t.xy_error, t.inclination, t.normal_rms), 3),
                               np.column_stack([targets.matches.xy_residual_m, targets.inclination_deg,
                                                targets.normal_rms_m]), **nan_eq)
    np.testing.assert_allclose(col(lambda t: (t.normal_sigma, t.lean_bound, t.fill_ratio, t.gun_clearance), 4),
                               np.column_stack([targets.normal_sigma_deg, targets.lean_bound_deg,
                                                targets.poses.fill_ratio, targets.gun_clearance_m]), **nan_eq)
    assert [t.iterations for t in msg.targets] == targets.matches.iterations.tolist()
    assert all(t.view_index == view_index for t in msg.targets)
    return msg


def test_a_rendered_view_reads_back_field_for_field(view_targets):
    msg = _check(view_targets)
    assert any(np.isnan(t.pose.position.x) for t in msg.targets)  # unmatched studs stay NaN, not 0


def test_ids_of_every_length_and_script_keep_the_alignment(view_targets):
    ids = ["", "A", "AB", "ABC", "ABCD", "Ø16-тест", "焊钉 7", "S" * 61] + [f"x{i}" for i in range(9)]
    _check(dataclasses.replace(view_targets, ids=ids[:len(view_targets.ids)]), frame_id="map")


def test_a_view_without_studs(view_targets):
    empty = plan_view([], np.zeros((0, 2)), np.eye(3), np.full((960, 1280), np.nan, np.float32),
                      demo_camera())
    assert _check(empty, view_index=0, sec=0, nanosec=0, frame_id="").targets == []


REPO = Path(__file__).resolve().parents[2]
PRIMITIVES = {"bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64",
              "float32", "float64", "string"}


def msg_fields(package: str, name: str, prefix: str = "") -> list[tuple[str, str]]:
    """The fields of ``package/name``.msg in wire order, nested messages flattened to dotted names
    (arrays of messages stay one ``Type[]`` field), read from the .msg files themselves."""
    ours = REPO / "src" / package / "msg" / f"{name}.msg"
    if ours.exists():
        path = ours
    else:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory(package)) / "msg" / f"{name}.msg"
    out = []
    for line in path.read_text().splitlines():
        words = line.split("#", 1)[0].split()
        if not words or "=" in words[1] or (len(words) > 2 and words[2] == "="):
            continue  # blank, comment or constant
        kind, field = words[0], words[1]
        if kind in PRIMITIVES:
            out.append((prefix + field, kind))
        elif kind.endswith("[]"):
            out.append((prefix + field, kind.split("/")[-1]))
        else:
            pkg, _, sub = kind.rpartition("/")
            pkg = pkg or ("std_msgs" if sub == "Header" else package)
            out.extend(msg_fields(pkg, sub, f"{prefix}{field}."))
    return out


def test_the_writers_field_layout_is_the_one_the_msg_files_define():
    assert list(WELD_TARGET_FIELDS) == msg_fields("stud_welding_msgs", "WeldTarget")
    assert list(WELD_TARGET_ARRAY_FIELDS) == msg_fields("stud_welding_msgs", "WeldTargetArray")


def test_a_received_array_reads_back_into_the_table_that_was_sent(view_targets):
    msg = deserialize_message(weld_target_array_cdr(view_targets, 3, 1, 2), WeldTargetArray)
    got = weld_target_table(msg)
    assert got.ids == view_targets.ids
    for name in COLUMNS:
        want = getattr(view_targets, name)
        if name == "quat_xyzw":
            want = view_targets.message_quat_xyzw  # the identity on the wire where there is no normal
        elif name == "view_index":
            want = np.full(len(want), 3)
        elif name == "centre_offset":
            assert np.isnan(got.centre_offset).all()  # not on the wire: unknown without the camera
            continue
        np.testing.assert_array_equal(getattr(got, name), want, err_msg=name)
    sent = dataclasses.replace(view_targets, view_index=np.full(len(view_targets.ids), 3))
    assert got.report_entries() == sent.report_entries()
