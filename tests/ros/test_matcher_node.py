"""The matcher node on its own (`ros2 run stud_planner matcher`), fed by this test as the camera:
/weld_targets never waits for colour, and colour is taken only while the overlay is watched."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from geometry_msgs.msg import Point, PoseStamped
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, Image
from stud_welding_msgs.msg import Registration, Stud, StudLayout, WeldTargetArray

from rosproc import REPO, ros2_run, wait_for
from stud_common import ros_io
from stud_perception.camera_node import shot_messages
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render

DEMO_SCENE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"
COLOR = "/camera/color/image_raw"


def _layout() -> StudLayout:
    scene = load_scene(DEMO_SCENE)
    return StudLayout(studs=[Stud(id=sid, x=float(x), y=float(y), diameter=0.016, layer="STUDS")
                             for sid, (x, y) in zip(scene.stud_ids, scene.studs_drawing_m)],
                      mark_a=Point(x=0.13), mark_b=Point(y=0.1), mark_diameter=0.02, source_file="test")


def _camera_inputs(node, publish_layout: bool = True):
    """Latched layout + true registration of the demo scene, publishers for one posed RGB-D shot."""
    scene = load_scene(DEMO_SCENE)
    reg = Registration(valid=True, message="truth", m_local2world=[float(v) for v in scene.M_local2world.ravel()])
    if publish_layout:
        node.create_publisher(StudLayout, "/drawing/layout", ros_io.LATCHED_QOS).publish(_layout())
    node.create_publisher(Registration, "/registration/result", ros_io.LATCHED_QOS).publish(reg)
    pubs = {k: node.create_publisher(t, topic, ros_io.CAMERA_PUB_QOS) for k, t, topic in (
        ("color", Image, COLOR), ("depth", Image, "/camera/depth/image_raw"),
        ("info", CameraInfo, "/camera/color/camera_info"), ("pose", PoseStamped, "/camera/pose"))}
    cam = view_camera((0, 0, 0), 1.0)
    cam = cam.with_pose(cam.R_wc, np.array([0.28, 0.10, 0.5]))
    return pubs, shot_messages(render(scene, cam, seed=1), "16UC1", ros_io.ns_to_stamp(0))


def _shoot(pubs, shot, sec: int, keys=("color", "depth", "info", "pose")):
    stamp = ros_io.ns_to_stamp(sec * 1_000_000_000)
    for key in keys:
        shot[key].header.stamp = stamp
        pubs[key].publish(shot[key])
    return stamp


def _shoot_until(node, pubs, shot, seconds, keys, received: list):
    """Shoot views stamped ``seconds`` until a message with the view's stamp lands in ``received``."""
    for sec in seconds:
        stamp = _shoot(pubs, shot, sec, keys)
        try:
            wait_for(lambda: any(m.header.stamp == stamp for m in received), 5, spin=node.spin, what=str(keys))
            return stamp
        except AssertionError:
            continue
    raise AssertionError(f"nothing received for views of {keys}")


def test_targets_without_colour_and_colour_only_while_the_overlay_is_watched(ros_node, procs, tmp_path: Path):
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log"))
    pubs, shot = _camera_inputs(ros_node)
    targets, overlays = [], []
    ros_node.create_subscription(WeldTargetArray, "/weld_targets", targets.append, ros_io.RESULT_QOS)
    wait_for(lambda: ros_node.count_subscribers("/camera/depth/image_raw") >= 1, 30, spin=ros_node.spin,
             what="the matcher's depth subscription")
    wait_for(lambda: all(pubs[k].get_subscription_count() >= 1 for k in ("depth", "info", "pose")), 20,
             spin=ros_node.spin, what="depth, camera info and pose matched by the matcher")
    assert ros_node.count_subscribers(COLOR) == 0  # nobody watches the overlay: no colour traffic

    # a view without any colour image is matched (the first shots may precede the matcher's side of
    # the discovery: best-effort samples to an unmatched reader are lost, so shoot until one lands)
    stamp = _shoot_until(ros_node, pubs, shot, range(1, 7), ("depth", "info", "pose"), targets)
    arr = next(t for t in targets if t.header.stamp == stamp)
    assert sum(t.status_text == "ok" for t in arr.targets) >= 5

    # an overlay subscriber makes the matcher take colour; the overlay carries the view's stamp
    sub = ros_node.create_subscription(Image, "/weld_targets/overlay", overlays.append, ros_io.RESULT_QOS)
    wait_for(lambda: pubs["color"].get_subscription_count() >= 1, 20, spin=ros_node.spin,
             what="the matcher subscribing to colour")
    # colour published after the depth: the overlay follows the targets
    stamp = _shoot_until(ros_node, pubs, shot, range(10, 16), ("depth", "info", "pose", "color"), overlays)
    ov = next(o for o in overlays if o.header.stamp == stamp)
    assert (ov.width, ov.height, ov.encoding) == (shot["color"].width, shot["color"].height, "bgr8")

    # the last overlay subscriber gone: colour is dropped again
    ros_node.destroy_subscription(sub)
    wait_for(lambda: ros_node.count_subscribers(COLOR) == 0, 20, spin=ros_node.spin,
             what="the matcher unsubscribing from colour")


def test_a_view_that_comes_before_the_layout_is_matched_once_the_layout_arrives(ros_node, procs, tmp_path: Path):
    """A slow start: the station's shot reaches the matcher before the drawing's layout does (seen in
    the cell under load). The view waits, and is matched when the layout comes -- no second shot.
    With sensor_qos reliable, as in the cell, the one shot is not lost on the way either."""
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log", params={"sensor_qos": "reliable"}))
    pubs, shot = _camera_inputs(ros_node, publish_layout=False)
    targets = []
    ros_node.create_subscription(WeldTargetArray, "/weld_targets", targets.append, ros_io.RESULT_QOS)
    wait_for(lambda: all(pubs[k].get_subscription_count() >= 1 for k in ("depth", "info", "pose")), 30,
             spin=ros_node.spin, what="depth, camera info and pose matched by the matcher")
    stamp = _shoot(pubs, shot, 1, ("depth", "info", "pose"))  # one shot: it arrives, and waits

    def held() -> bool:  # the view's own reason, not the start-up line that names the layout too
        return any(line.endswith("]: waiting for /drawing/layout") for line in procs[-1].output().splitlines())
    wait_for(held, 10, spin=ros_node.spin, what="the matcher holding the view")
    assert not targets
    ros_node.create_publisher(StudLayout, "/drawing/layout", ros_io.LATCHED_QOS).publish(_layout())
    wait_for(lambda: any(t.header.stamp == stamp for t in targets), 10, spin=ros_node.spin,
             what="targets of the view shot before the layout")
    assert sum(t.status_text == "ok" for t in targets[-1].targets) >= 5


def test_poses_hold_only_the_usable_targets_in_target_order_and_no_nan():
    """/weld_targets/poses: the k-th pose is the k-th OK target (RViz and Foxglove cannot draw NaN)."""
    from std_msgs.msg import Header

    from stud_planner.matching.matcher_node import MatcherNode
    from stud_planner.matching.view_targets import plan_view

    scene = load_scene(DEMO_SCENE)
    cam = view_camera((0, 0, 0), 1.0)
    cam = cam.with_pose(cam.R_wc, np.array([0.28, 0.10, 0.5]))
    view = render(scene, cam, seed=1)
    ids = list(scene.stud_ids) + ["FAR"]
    xy = np.vstack([scene.studs_drawing_m, [[5.0, 5.0]]])  # 5 m away: out of view, no pose
    targets = plan_view(ids, xy, scene.M_local2world, view.depth_m, cam)
    assert targets.ok.sum() >= 5 and not targets.ok.all()
    pa = MatcherNode._poses(targets, Header(frame_id="world"))
    got = np.array([(p.position.x, p.position.y, p.position.z, p.orientation.x, p.orientation.y, p.orientation.z,
                     p.orientation.w) for p in pa.poses])
    assert np.all(np.isfinite(got)) and pa.header.frame_id == "world"
    np.testing.assert_array_equal(got, np.hstack([targets.position_w, targets.message_quat_xyzw])[targets.ok])


def test_a_steady_camera_reuses_its_noise_measurement_and_a_moved_one_measures_again(ros_node, procs, tmp_path: Path):
    """The noise correlation is measured on a frame and reused for the same camera's next frames at
    that pose (measured again after their targets are out); a shot from another pose, and every
    frame with noise_correlation_reuse_s 0, is measured on itself. The view log says which."""
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log", params={"sensor_qos": "reliable"}))
    pubs, shot = _camera_inputs(ros_node)
    targets = []
    ros_node.create_subscription(WeldTargetArray, "/weld_targets", targets.append, ros_io.RESULT_QOS)
    wait_for(lambda: all(pubs[k].get_subscription_count() >= 1 for k in ("depth", "info", "pose")), 30,
             spin=ros_node.spin, what="depth, camera info and pose matched by the matcher")

    def view_line(stamp) -> str:
        wait_for(lambda: any(t.header.stamp == stamp for t in targets), 10, spin=ros_node.spin, what="targets")
        index = next(t.view_index for t in targets if t.header.stamp == stamp)
        wait_for(lambda: f"view {index}:" in procs[-1].output(), 5, spin=ros_node.spin, what="its log line")
        return next(line for line in procs[-1].output().splitlines() if f"view {index}:" in line)

    first = view_line(_shoot(pubs, shot, 1, ("depth", "info", "pose")))
    second = view_line(_shoot(pubs, shot, 2, ("depth", "info", "pose")))
    assert "noise correlation of a frame" not in first and "noise correlation of a frame" in second
    def poses(arr) -> np.ndarray:  # NaN where a stud has no pose
        return np.array([(t.status, t.pose.position.x, t.pose.position.y, t.pose.position.z, t.normal.x, t.normal.y,
                          t.normal.z) for t in arr.targets])
    assert [t.stud_id for t in targets[1].targets] == [t.stud_id for t in targets[0].targets]
    np.testing.assert_array_equal(poses(targets[1]), poses(targets[0]))  # the same frame, the same targets
    moved = shot["pose"]
    moved.pose.position.x += 0.01
    assert "noise correlation of a frame" not in view_line(_shoot(pubs, shot, 3, ("depth", "info", "pose")))


def test_per_view_registration_matches_each_view_with_the_registration_of_its_own_stamp(ros_node, procs, tmp_path):
    """A long part's replay: the registration of a later view may arrive first, and a view may come before its
    own; each is matched with its own (a layout with reference marks), and a view whose registration failed is
    not matched."""
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log", params={"per_view_registration": True}))
    scene = load_scene(DEMO_SCENE)
    layout = _layout()
    layout.reference_mark_labels, layout.reference_marks = ["M1"], [Point(x=0.3, y=0.2)]
    ros_node.create_publisher(StudLayout, "/drawing/layout", ros_io.LATCHED_QOS).publish(layout)
    # latched, and deep enough that a registration is never replaced before the matcher took it
    reg_pub = ros_node.create_publisher(Registration, "/registration/result", QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
    shifted = scene.M_local2world.copy()
    shifted[0, 2] += 0.005  # a neighbour's registration, 5 mm off here
    pubs = {k: ros_node.create_publisher(t, topic, ros_io.CAMERA_PUB_QOS) for k, t, topic in (
        ("depth", Image, "/camera/depth/image_raw"), ("info", CameraInfo, "/camera/color/camera_info"),
        ("pose", PoseStamped, "/camera/pose"))}
    cam = view_camera((0, 0, 0), 1.0)
    shot = shot_messages(render(scene, cam.with_pose(cam.R_wc, np.array([0.28, 0.10, 0.5])), seed=1), "16UC1",
                         ros_io.ns_to_stamp(0))
    targets = []
    ros_node.create_subscription(WeldTargetArray, "/weld_targets", targets.append, ros_io.RESULT_QOS)
    wait_for(lambda: all(p.get_subscription_count() >= 1 for p in pubs.values())
             and reg_pub.get_subscription_count() >= 1, 30, spin=ros_node.spin, what="the matcher's subscriptions")

    def registration(sec: int, M: np.ndarray, valid: bool = True) -> None:
        msg = Registration(valid=valid, message="test", m_local2world=[float(v) for v in M.ravel()])
        msg.header.stamp = ros_io.ns_to_stamp(sec * 1_000_000_000)
        reg_pub.publish(msg)

    def shot_at(sec: int) -> None:
        stamp = ros_io.ns_to_stamp(sec * 1_000_000_000)
        for key in pubs:
            shot[key].header.stamp = stamp
            pubs[key].publish(shot[key])

    def targets_at(sec: int):
        return [a for a in targets if ros_io.stamp_to_ns(a.header.stamp) == sec * 1_000_000_000]

    def max_error_mm(arr) -> float:
        truth = dict(zip(scene.stud_ids, scene.studs_world_xy_m))
        return max(1e3 * np.hypot(t.pose.position.x - truth[t.stud_id][0], t.pose.position.y - truth[t.stud_id][1])
                   for t in arr.targets if t.status_text == "ok")

    def shoot_until_matched(sec: int):
        """Shoot the view stamped ``sec`` until its targets come (the first shots may precede the matcher's side
        of the discovery, and best-effort samples to an unmatched reader are lost)."""
        for _ in range(10):
            shot_at(sec)
            try:
                wait_for(lambda: targets_at(sec), 3, spin=ros_node.spin, what=f"targets of the view at {sec} s")
                return targets_at(sec)[0]
            except AssertionError:
                continue
        raise AssertionError(f"the view at {sec} s was never matched")

    registration(12, shifted)          # the next view's registration comes first
    for _ in range(3):                 # this view waits for its own (the latest would be matched at once)
        shot_at(11)
        for _ in range(30):            # pacing (not a condition): time for the view to reach the matcher
            ros_node.spin()
    assert not targets_at(11)
    registration(11, scene.M_local2world)
    assert max_error_mm(shoot_until_matched(11)) < 1.0
    assert 4.0 < max_error_mm(shoot_until_matched(12)) < 6.0  # its own registration, not the latest one
    registration(13, scene.M_local2world, valid=False)
    for _ in range(3):
        shot_at(13)
    registration(14, scene.M_local2world)
    shoot_until_matched(14)
    assert not targets_at(13)          # its registration failed: not matched
