"""The post-weld inspection shot is not a view to match: the sim camera publishes it on topics of its own
(``/camera/inspection/...``), which the inspector reads and the matcher does not, and a shot to match
never appears there. Through the real camera node over DDS."""
from __future__ import annotations

from geometry_msgs.msg import PoseStamped
from sensor_msgs.msg import CameraInfo, Image
from std_srvs.srv import Trigger

from rosproc import REPO, ros2_run, wait_for
from stud_common import names, ros_io

DEMO_SCENE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"
TYPES = {"color": Image, "depth": Image, "info": CameraInfo, "pose": PoseStamped}


def _call(node, client, request, timeout=30):
    wait_for(lambda: client.service_is_ready(), timeout, spin=node.spin, what=f"service {client.srv_name}")
    future = client.call_async(request)
    wait_for(future.done, timeout, spin=node.spin, what=f"reply of {client.srv_name}")
    return future.result()


def test_an_inspection_shot_goes_out_on_its_own_topics_and_a_view_on_the_matchers(ros_node, procs, tmp_path):
    procs.append(ros2_run("stud_perception", "camera", tmp_path / "camera.log",
                          {"scene_file": str(DEMO_SCENE), "camera_xyz_m": [0.215, 0.0, 0.55]}))
    got = {kind: {k: [] for k in TYPES} for kind in (False, True)}
    for inspection in (False, True):
        for key, topic in names.shot_topics(inspection).items():
            ros_node.create_subscription(TYPES[key], topic, got[inspection][key].append, ros_io.SENSOR_QOS)
    assert set(names.shot_topics(True).values()).isdisjoint(names.shot_topics(False).values())
    view, inspection_shot = (ros_node.create_client(Trigger, n)
                             for n in (names.CAMERA_TRIGGER, names.CAMERA_TRIGGER_INSPECTION))
    wait_for(lambda: ros_node.count_publishers(names.INSPECTION_DEPTH_IMAGE) >= 1
             and ros_node.count_publishers(names.DEPTH_IMAGE) >= 1, 30, spin=ros_node.spin, what="the camera")

    reply = _call(ros_node, inspection_shot, Trigger.Request())
    assert reply.success and reply.message.startswith("inspection shot"), reply.message
    wait_for(lambda: all(got[True].values()), 30, spin=ros_node.spin, what=f"the inspection shot\n{procs[0].output()}")
    stamps = {ros_io.stamp_to_ns(v[0].header.stamp) for v in got[True].values()}
    assert len(stamps) == 1  # one shot, one stamp, as a view's

    reply = _call(ros_node, view, Trigger.Request())
    assert reply.success, reply.message
    wait_for(lambda: all(got[False].values()), 30, spin=ros_node.spin, what="the view")
    for _ in range(20):  # anything late would have come by now (the view came after it)
        ros_node.spin()
    # each shot on its own topics only: the matcher (subscribed to the view's) never saw the inspection shot
    assert all(len(v) == 1 for v in got[True].values()) and all(len(v) == 1 for v in got[False].values())
    assert ros_io.stamp_to_ns(got[False]["depth"][0].header.stamp) not in stamps
