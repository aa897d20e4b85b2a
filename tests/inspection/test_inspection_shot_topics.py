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


def test_the_shot_node_takes_an_inspection_shot_of_a_streaming_driver_onto_the_inspection_topics(ros_node, procs,
                                                                                                  tmp_path):
    """A real camera: the shot node (a vendor driver streaming) does the same on /camera/trigger_inspection."""
    import threading
    import time

    import numpy as np
    from stud_welding_msgs.msg import ArmState

    from stud_perception.camera_model import nadir_rotation
    from stud_perception.camera_node import shot_messages
    from stud_perception.scene_cameras import view_camera
    from stud_perception.scene_file import load_scene
    from stud_perception.scene_render import render

    procs.append(ros2_run("stud_perception", "shot", tmp_path / "shot.log",
                          {"hand_eye_xyz_m": [0.05, 0.0, -0.10], "hand_eye_rpy_deg": [0.0, 0.0, 0.0]}))
    cam = view_camera((0, 0, 0), 1.0, width=160, height=120)
    view = render(load_scene(DEMO_SCENE), cam.with_pose(cam.R_wc, np.array([0.3, 0.0, 0.5])))
    drv = {k: ros_node.create_publisher(TYPES[k], f"/camera_driver/{topic}", ros_io.SENSOR_QOS) for k, topic in (
        ("color", "color/image_raw"), ("depth", "aligned_depth_to_color/image_raw"), ("info", "color/camera_info"))}
    arm = ros_node.create_publisher(ArmState, names.ARM_STATE, ros_io.RESULT_QOS)
    got = {kind: {k: [] for k in TYPES} for kind in (False, True)}
    for inspection in (False, True):
        for key, topic in names.shot_topics(inspection).items():
            ros_node.create_subscription(TYPES[key], topic, got[inspection][key].append, ros_io.SENSOR_QOS)
    stop = threading.Event()

    def stream():
        while not stop.is_set():
            now = ros_node.get_clock().now().nanoseconds
            shot = shot_messages(view, "16UC1", ros_io.ns_to_stamp(now))
            for key in ("color", "depth", "info"):
                drv[key].publish(shot[key])
            state = ArmState(mode=ArmState.MODE_IDLE, connected=True)
            state.header.stamp = ros_io.ns_to_stamp(now)
            state.tool_pose = ros_io.rt_to_pose(nadir_rotation(0.0), np.array([0.25, 0.05, 0.40]))
            arm.publish(state)
            time.sleep(1 / 15)

    thread = threading.Thread(target=stream, daemon=True)
    thread.start()
    try:
        reply = _call(ros_node, ros_node.create_client(Trigger, names.CAMERA_TRIGGER_INSPECTION), Trigger.Request())
        assert reply.success, reply.message
        wait_for(lambda: all(got[True].values()), 15, spin=ros_node.spin, what=f"the shot\n{procs[0].output()}")
        for _ in range(20):
            ros_node.spin()
    finally:
        stop.set()
        thread.join()
    assert all(len(v) == 1 for v in got[True].values()) and not any(got[False].values())
