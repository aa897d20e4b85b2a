"""The matcher node's own default ``tolerance_m`` decides a match 1-10 mm off: studs a few millimetres
beyond the image border are refused (out_of_view), the dome's studs in view matched. A real process
with its default parameters, fed over DDS by this test as the camera (tests/planner/test_match_tolerance.py
has the scene)."""
from __future__ import annotations

import sys
from pathlib import Path

from geometry_msgs.msg import Point, PoseStamped
from sensor_msgs.msg import CameraInfo, Image
from stud_welding_msgs.msg import Registration, Stud, StudLayout, WeldTargetArray

from rosproc import REPO, ros2_run, wait_for
from stud_common import ros_io
from stud_perception.camera_node import shot_messages
from stud_perception.scene_render import render

sys.path.insert(0, str(REPO / "tests" / "planner"))
from test_match_tolerance import SCENE, edge_view  # noqa: E402
from test_matcher_node import _shoot_until  # noqa: E402


def test_the_matcher_node_refuses_studs_1_to_10_mm_off_at_its_default_tolerance(ros_node, procs, tmp_path: Path):
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log"))  # its defaults
    camera, _, edge_studs = edge_view()
    studs = [Stud(id=sid, x=float(x), y=float(y), diameter=0.016, layer="STUDS")
             for sid, (x, y) in zip(SCENE.stud_ids, SCENE.studs_drawing_m)]
    studs += [Stud(id=f"EDGE{i}", x=float(x), y=float(y), diameter=0.016, layer="STUDS")
              for i, (x, y) in enumerate(edge_studs)]
    layout = StudLayout(studs=studs, mark_a=Point(x=0.13), mark_b=Point(y=0.1), mark_diameter=0.02, source_file="test")
    ros_node.create_publisher(StudLayout, "/drawing/layout", ros_io.LATCHED_QOS).publish(layout)
    reg = Registration(valid=True, message="truth", m_local2world=[float(v) for v in SCENE.M_local2world.ravel()])
    ros_node.create_publisher(Registration, "/registration/result", ros_io.LATCHED_QOS).publish(reg)
    pubs = {k: ros_node.create_publisher(t, topic, ros_io.CAMERA_PUB_QOS) for k, t, topic in (
        ("color", Image, "/camera/color/image_raw"), ("depth", Image, "/camera/depth/image_raw"),
        ("info", CameraInfo, "/camera/color/camera_info"), ("pose", PoseStamped, "/camera/pose"))}
    shot = shot_messages(render(SCENE, camera, seed=1), "16UC1", ros_io.ns_to_stamp(0))
    targets: list[WeldTargetArray] = []
    ros_node.create_subscription(WeldTargetArray, "/weld_targets", targets.append, ros_io.RESULT_QOS)
    wait_for(lambda: all(pubs[k].get_subscription_count() >= 1 for k in ("depth", "info", "pose")), 30,
             spin=ros_node.spin, what="the matcher's subscriptions")
    stamp = _shoot_until(ros_node, pubs, shot, range(1, 7), ("depth", "info", "pose"), targets)
    arr = next(t for t in targets if t.header.stamp == stamp)
    status = {t.stud_id: t.status_text for t in arr.targets}
    edge = {sid: s for sid, s in status.items() if sid.startswith("EDGE")}
    assert edge == {f"EDGE{i}": "out_of_view" for i in range(len(edge_studs))}, (edge, procs[0].output()[-2000:])
    assert sum(s == "ok" for s in status.values()) >= 5  # the view itself is matched
