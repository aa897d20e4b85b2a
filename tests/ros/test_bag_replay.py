"""`ros2 bag play bags/dome_demo` through the real registration and matcher nodes: the targets
match the bag's ground truth. The layout itself comes from the bag (latched /drawing/layout)."""
from __future__ import annotations

import json

import numpy as np
from stud_welding_msgs.msg import Registration, WeldTargetArray

from rosproc import REPO, Proc, ros2_run, wait_for
from stud_common import ros_io

BAG = REPO / "bags" / "dome_demo"


def test_replayed_bag_gives_the_ground_truth_targets(ros_node, procs, tmp_path):
    truth = json.loads((BAG / "ground_truth.json").read_text())
    procs.append(ros2_run("stud_perception", "registration", tmp_path / "registration.log"))
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log"))
    regs, arrays = [], []
    ros_node.create_subscription(Registration, "/registration/result", regs.append, ros_io.LATCHED_QOS)
    ros_node.create_subscription(WeldTargetArray, "/weld_targets", arrays.append, ros_io.RESULT_QOS)
    wait_for(lambda: ros_node.count_subscribers("/camera/depth/image_raw") >= 2
             and ros_node.count_publishers("/weld_targets") >= 1, 30, spin=ros_node.spin, what="nodes up")
    # both nodes subscribe to depth, camera info and pose; colour only the registration (the matcher
    # while an overlay is wanted): wait until each topic has its subscribers matched
    play = Proc(["ros2", "bag", "play", str(BAG), "--wait-for-subscribers", "2", "/camera/color/image_raw=1"],
                tmp_path / "play.log")
    procs.append(play)
    logs = lambda: "\n".join(p.output()[-2000:] for p in procs)  # noqa: E731
    wait_for(lambda: len(arrays) >= 2, 60, spin=ros_node.spin, what=f"targets of the station views\n{logs()}")
    wait_for(lambda: play.popen.poll() is not None, 30, spin=ros_node.spin, what="play to finish")
    assert play.popen.returncode == 0, play.output()

    assert regs and regs[-1].valid, logs()
    M = np.asarray(regs[-1].m_local2world).reshape(3, 3)
    assert np.abs(M - np.asarray(truth["M_local2world"])).max() < 5e-4
    by_id = {s["stud_id"]: s for s in truth["studs"]}
    seen_ok = set()
    for arr in arrays:
        for t in arr.targets:
            if t.status_text != "ok":
                continue
            seen_ok.add(t.stud_id)
            q = np.asarray(by_id[t.stud_id]["position_m"])
            p = np.array([t.pose.position.x, t.pose.position.y, t.pose.position.z])
            assert np.linalg.norm(p[:2] - q[:2]) <= 0.001 and abs(p[2] - q[2]) <= 0.002, t.stud_id
            n = np.array([t.normal.x, t.normal.y, t.normal.z])
            assert np.degrees(np.arccos(np.clip(n @ by_id[t.stud_id]["normal"], -1, 1))) <= 2.5, t.stud_id
    assert seen_ok == set(by_id)  # every stud of the drawing got a correct target from some view
