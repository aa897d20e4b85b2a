"""A long part's bag through `ros2 run stud_planner cell --mode replay` (issue 35): views of the girder shot
from the arm on its rail, with the rail's simulated error, replayed through the registration and matcher
nodes give the targets `ros2 run stud_planner plan` gives from the same bag, within 0.1 mm: every view
registered on its own marks and matched with that registration, whichever arrives first."""
from __future__ import annotations

import importlib.util
import sys

import numpy as np

from rosproc import REPO
from stud_common import ros_io
from stud_planner.offline_plan import plan

DXF = REPO / "src" / "stud_planner" / "data" / "girder_demo.dxf"


def record_girder(out, stations):
    spec = importlib.util.spec_from_file_location("record_demo_bag", REPO / "tools" / "record_demo_bag.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["record_demo_bag"] = module
    spec.loader.exec_module(module)
    return module.record_girder(out, list(stations))


def test_a_girder_bag_replays_to_the_targets_plan_gives(ros_node, cell_run, tmp_path):
    probe = ros_node
    from stud_welding_msgs.msg import Registration, WeldTargetArray

    bag = tmp_path / "girder_bag"
    truth = record_girder(bag, (0, 1, 18))  # the board, the girder's start and its far end
    report = plan(DXF, bag)
    arrays, regs = [], []
    probe.create_subscription(WeldTargetArray, "/weld_targets", arrays.append, ros_io.RESULT_QOS)
    probe.create_subscription(Registration, "/registration/result", regs.append, ros_io.LATCHED_QOS)
    cell = cell_run("--mode", "replay", "--no-hmi", "--bag", str(bag), "--drawing", str(DXF))
    cell.wait(lambda: "bag_play exited (exit code 0" in cell.output(), 120, "the end of the bag", spin=probe.spin)
    stamps = lambda: {ros_io.stamp_to_ns(a.header.stamp) for a in arrays}  # noqa: E731
    cell.wait(lambda: stamps() >= set(report["view_stamps_ns"]), 60, "/weld_targets of every view", spin=probe.spin)
    assert cell.running()
    by_stamp = {ros_io.stamp_to_ns(a.header.stamp): {t.stud_id: t for t in a.targets} for a in arrays}
    ok = [t for t in report["targets"] if t["status"] == "ok"]
    assert len(ok) >= 12
    worst = 0.0
    for t in ok:
        replayed = by_stamp[report["view_stamps_ns"][t["view"]]][t["stud_id"]]
        assert replayed.status_text == "ok", (t["stud_id"], replayed.status_text)
        p = np.array([replayed.pose.position.x, replayed.pose.position.y, replayed.pose.position.z])
        worst = max(worst, float(np.linalg.norm(p - np.asarray(t["position_m"]))))
    assert worst <= 1e-4, f"replay and plan differ by {worst * 1e3:.3f} mm"
    # the nodes registered every view on its own marks, as plan did
    valid = [r for r in regs if r.valid]
    assert sorted(ros_io.stamp_to_ns(r.header.stamp) for r in valid) == report["view_stamps_ns"]
    assert [list(r.labels_used) for r in sorted(valid, key=lambda r: ros_io.stamp_to_ns(r.header.stamp))] == \
        [r["marks"] for r in report["registrations"]]
    assert len(truth["views"]) == 4
    cell.record_pids()
    cell.ctrl_c_stops_everything()
