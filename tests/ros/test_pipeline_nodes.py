"""Drawing + sim camera + registration + matcher as four processes; a fifth (this test) checks
the weld targets against the scene's ground truth."""
from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import PoseArray, PoseStamped
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import Registration, WeldTargetArray
from visualization_msgs.msg import MarkerArray

from rosproc import REPO, ros2_run, wait_for
from stud_common import ros_io
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render

DEMO_DXF = REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf"
DEMO_SCENE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"


# Clean depth (32FC1, exact): positions and normals to the bounds. A real camera: 16UC1
# with a structured-light camera's noise (0.5 mm; mm quantisation costs the normal a little more),
# tilted, and raw images of a lens with barrel distortion that registration and matcher rectify.
@pytest.mark.parametrize("algorithm, yaw_deg, tilt_deg, height_m, encoding, noise_m, distortion, normal_tol_deg", [
    ("batch", 90.0, 0.0, 0.70, "32FC1", 0.0, [0.0] * 5, 1.0),
    ("fpm", 90.0, 0.0, 0.70, "32FC1", 0.0, [0.0] * 5, 1.0),
    ("batch", 137.0, 10.0, 0.75, "16UC1", 0.0005, [-0.2, 0.08, 0.001, -0.0008, 0.0], 2.0),
])
def test_targets_from_the_node_graph_match_the_scene_truth(ros_node, procs, tmp_path, algorithm, yaw_deg, tilt_deg,
                                                           height_m, encoding, noise_m, distortion, normal_tol_deg):
    cam = {"scene_file": str(DEMO_SCENE), "depth_encoding": encoding, "depth_noise_m": noise_m,
           "camera_xyz_m": [0.22, -0.15, height_m], "distortion_d": distortion,  # board and dome in one view
           "camera_yaw_deg": yaw_deg, "camera_tilt_deg": tilt_deg, "camera_tilt_azimuth_deg": 40.0}
    procs.append(ros2_run("stud_planner", "drawing", tmp_path / "drawing.log", {"drawing_file": str(DEMO_DXF)}))
    procs.append(ros2_run("stud_perception", "camera", tmp_path / "camera.log", cam))
    procs.append(ros2_run("stud_perception", "registration", tmp_path / "registration.log"))
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log", {"algorithm": algorithm}))
    logs = lambda: "\n".join(f"--- {p.cmd[2:4]}\n{p.output()[-1500:]}" for p in procs)  # noqa: E731

    regs, targets, poses, markers, overlays, cam_poses = [], [], [], [], [], []
    ros_node.create_subscription(Registration, "/registration/result", regs.append, ros_io.LATCHED_QOS)
    ros_node.create_subscription(WeldTargetArray, "/weld_targets", targets.append, ros_io.RESULT_QOS)
    ros_node.create_subscription(PoseArray, "/weld_targets/poses", poses.append, ros_io.RESULT_QOS)
    ros_node.create_subscription(MarkerArray, "/weld_targets/markers", markers.append, ros_io.RESULT_QOS)
    ros_node.create_subscription(Image, "/weld_targets/overlay", overlays.append, ros_io.RESULT_QOS)
    ros_node.create_subscription(PoseStamped, "/camera/pose", cam_poses.append, ros_io.SENSOR_QOS)
    trigger = ros_node.create_client(Trigger, "/camera/trigger")
    wait_for(trigger.service_is_ready, 30, spin=ros_node.spin, what="camera")
    # Shoot once registration and matcher listen to the camera (else the first shots are lost).
    wait_for(lambda: ros_node.count_subscribers("/camera/depth/image_raw") >= 2
             and ros_node.count_publishers("/weld_targets") >= 1, 30, spin=ros_node.spin, what="graph discovery")

    def shoot_until(cond, what):
        for _ in range(6):  # the first shots may reach nodes that are still discovering each other
            trigger.call_async(Trigger.Request())
            try:
                wait_for(cond, 10, spin=ros_node.spin, what=what)
                return
            except AssertionError:
                continue
        raise AssertionError(f"no {what}\n{logs()}")

    shoot_until(lambda: any(r.valid for r in regs), "valid registration")
    shoot_until(lambda: targets, "/weld_targets")
    # Visualisation is lazy (built, and colour taken, only for subscribers the matcher has discovered):
    # a further shot may be needed once it has seen ours.
    shoot_until(lambda: poses and markers and overlays, "poses, markers, overlay")
    assert all(any(o.header.stamp == t.header.stamp for t in targets) for o in overlays)  # each overlay is of a view

    arr = targets[-1]
    assert arr.algorithm == algorithm and arr.total_iterations > 0
    scene = load_scene(DEMO_SCENE)
    pose_msg = next(p for p in cam_poses if p.header.stamp == arr.header.stamp)
    camera_pose = ros_io.pose_to_rt(pose_msg.pose)
    from stud_perception.scene_cameras import view_camera
    camera = view_camera((0, 0, 0)).with_pose(*camera_pose)
    truth = render(scene, camera)
    by_id = dict(zip(scene.stud_ids, range(len(scene.stud_ids))))
    assert [t.stud_id for t in arr.targets] == sorted(scene.stud_ids)  # drawing order
    # In view: visible, with the normal's 20 mm patch inside the image (a stud right at the border
    # cannot have its normal fitted, and says so: no_normal / out_of_view).
    margin_px = 0.5 * 0.02 * camera.fx / 0.65 + 2
    uv = truth.stud_pixels_uv
    inside = ((uv[:, 0] >= margin_px) & (uv[:, 0] <= camera.width - 1 - margin_px)
              & (uv[:, 1] >= margin_px) & (uv[:, 1] <= camera.height - 1 - margin_px))
    in_view = [t for t in arr.targets if truth.stud_visible[by_id[t.stud_id]] and inside[by_id[t.stud_id]]]
    assert len(in_view) >= 4  # of the 9 studs: both the board and the dome are in this view
    bad = [(t.stud_id, t.status_text, uv[by_id[t.stud_id]].round(1).tolist()) for t in in_view if t.status_text != "ok"]
    assert not bad, bad
    for t in arr.targets:  # every "ok" target is right (no silent wrong pose), in view or not
        if t.status_text != "ok":
            assert not truth.stud_visible[by_id[t.stud_id]]
            continue
        i = by_id[t.stud_id]
        p = np.array([t.pose.position.x, t.pose.position.y, t.pose.position.z])
        assert np.linalg.norm(p[:2] - truth.studs_world_m[i, :2]) <= 0.001, t.stud_id
        assert abs(p[2] - truth.studs_world_m[i, 2]) <= 0.001 + 2 * noise_m, t.stud_id
        n = np.array([t.normal.x, t.normal.y, t.normal.z])
        assert np.degrees(np.arccos(np.clip(n @ truth.stud_normals_w[i], -1, 1))) <= normal_tol_deg, t.stud_id
    # the PoseArray of a view is its OK targets' poses, in the same order; nothing NaN (RViz cannot draw it)
    pa = poses[-1]
    same_view = next(t for t in targets if t.header.stamp == pa.header.stamp)
    got = [(q.position.x, q.position.y, q.position.z, q.orientation.x, q.orientation.y, q.orientation.z,
            q.orientation.w) for q in pa.poses]
    ok_targets = [t for t in same_view.targets if t.status == t.STATUS_OK]
    np.testing.assert_array_equal(got, [(t.pose.position.x, t.pose.position.y, t.pose.position.z,
                                         t.pose.orientation.x, t.pose.orientation.y, t.pose.orientation.z,
                                         t.pose.orientation.w) for t in ok_targets])
    assert len(pa.poses) >= 4 and np.all(np.isfinite(got))
    n_ok = sum(t.status_text == "ok" for t in arr.targets)
    assert len([m for m in markers[-1].markers if m.action == m.ADD]) >= n_ok
