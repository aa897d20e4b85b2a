"""The drawing and camera nodes as separate processes, received by this test process over DDS."""
from __future__ import annotations

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger
from stud_welding_msgs.msg import StudLayout
from stud_welding_msgs.srv import LoadDrawing

from rosproc import REPO, ros2_run, wait_for
from stud_common import ros_io
from stud_perception import image_io
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render
from stud_planner.drawing import read_layout

DEMO_DXF = REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf"
DEMO_SCENE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"


def _call(node, client, request, timeout=30):
    wait_for(lambda: client.service_is_ready(), timeout, spin=node.spin, what=f"service {client.srv_name}")
    future = client.call_async(request)
    wait_for(future.done, timeout, spin=node.spin, what=f"reply of {client.srv_name}")
    return future.result()


def test_drawing_node_latches_the_layout_and_survives_a_bad_reload(ros_node, procs, tmp_path):
    procs.append(ros2_run("stud_planner", "drawing", tmp_path / "drawing.log", {"drawing_file": str(DEMO_DXF)}))
    got: list[StudLayout] = []
    ros_node.create_subscription(StudLayout, "/drawing/layout", got.append, ros_io.LATCHED_QOS)
    wait_for(lambda: got, 30, spin=ros_node.spin, what=f"/drawing/layout\n{procs[0].output()}")
    expected = read_layout(DEMO_DXF)
    msg = got[-1]
    assert [s.id for s in msg.studs] == [s.id for s in expected.studs]
    assert np.allclose([(s.x, s.y) for s in msg.studs], expected.studs_xy_m())
    assert (msg.mark_a.x, msg.mark_b.y) == pytest.approx((0.13, 0.10))
    assert msg.header.frame_id == "drawing" and msg.source_units == "mm"

    bad = tmp_path / "not_a_drawing.dxf"
    bad.write_text("this is not a DXF file\n")
    client = ros_node.create_client(LoadDrawing, "/drawing/load")
    reply = _call(ros_node, client, LoadDrawing.Request(drawing_file=str(bad)))
    assert not reply.success and str(bad) in reply.message
    reply = _call(ros_node, client, LoadDrawing.Request(drawing_file=""))  # reload the good one
    assert reply.success and reply.stud_count == len(expected.studs)
    assert procs[0].popen.poll() is None


def test_camera_node_publishes_one_synchronised_shot_per_trigger(ros_node, procs, tmp_path):
    params = {"scene_file": str(DEMO_SCENE), "depth_noise_m": 0.0, "camera_xyz_m": [0.28, 0.10, 0.55],
              "camera_yaw_deg": 30.0}
    procs.append(ros2_run("stud_perception", "camera", tmp_path / "camera.log", params))
    got: dict[str, list] = {"color": [], "depth": [], "info": [], "pose": []}
    for key, topic, typ in (("color", "/camera/color/image_raw", Image), ("depth", "/camera/depth/image_raw", Image),
                            ("info", "/camera/color/camera_info", CameraInfo), ("pose", "/camera/pose", PoseStamped)):
        ros_node.create_subscription(typ, topic, got[key].append, ros_io.SENSOR_QOS)
    client = ros_node.create_client(Trigger, "/camera/trigger")
    reply = _call(ros_node, client, Trigger.Request())
    assert reply.success, reply.message
    wait_for(lambda: all(got.values()), 30, spin=ros_node.spin, what=f"a full shot\n{procs[0].output()}")
    stamps = {k: ros_io.stamp_to_ns(v[0].header.stamp) for k, v in got.items()}
    assert len(set(stamps.values())) == 1, stamps
    assert got["depth"][0].encoding == "16UC1" and got["color"][0].encoding == "bgr8"
    camera = image_io.camera_model_from_msgs(got["info"][0], got["pose"][0].pose)
    depth_m = image_io.depth_to_metres(got["depth"][0])
    # The published shot is the scene rendered from the published pose: depth at every stud's
    # pixel lifts (Eq. 1) to the true surface point within the mm quantisation.
    truth = render(load_scene(DEMO_SCENE), camera, depth_noise_m=0.0)
    assert truth.stud_visible.all()
    u, v = np.round(truth.stud_pixels_uv).astype(int).T
    lifted = camera.pixel_to_world(u, v, depth_m[v, u])
    exact = camera.pixel_to_world(u, v, truth.depth_exact_m[v, u])
    assert np.abs(lifted - exact).max() < 0.001
    assert np.degrees(np.arccos(camera.R_wc[:, 0] @ [np.cos(np.radians(30)), np.sin(np.radians(30)), 0])) < 0.01
