"""The plan of the part through `ros2 run stud_planner hmi` over DDS: this test process is the rest of
the cell (drawing, registration, arm on a rail, sequencer) and a browser (a raw WebSocket client)."""
from __future__ import annotations

import math

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stud_welding_msgs.msg", reason="workspace not built/sourced (source ros2_ws/setup.bash)")

from geometry_msgs.msg import Point  # noqa: E402
from stud_welding_msgs.msg import ArmState, CellStatus, Registration, Stud, StudLayout, WeldTarget  # noqa: E402

from fake_cell import FakeCell, target  # noqa: E402
from hmi_testing import ctrl_c, free_port  # noqa: E402
from rosproc import ros2_run  # noqa: E402
from stud_common import ros_io  # noqa: E402
from test_hmi_node import Inbox  # noqa: E402
from ws_client import WsClient  # noqa: E402

MOUNT = [0.05, -0.45, 0.1]
#: a girder's flange in the drawing: three studs per row every 0.2 m over 5.8 m
DRAWING = [(f"S{k + 1:04d}", 0.1 + 0.2 * i, 0.06 + 0.08 * j) for k, (i, j) in enumerate(
    (i, j) for i in range(30) for j in range(3))]
PART_AT = (1.5, -0.2)  # the registration: the drawing's origin 1.5 m along the rail, turned 90 deg


def layout_msg() -> StudLayout:
    msg = StudLayout(source_file="/parts/girder.dxf", mark_diameter=0.03,
                     studs=[Stud(id=sid, x=x, y=y, diameter=0.019) for sid, x, y in DRAWING])
    msg.mark_a.x, msg.mark_b.y = 0.5, 0.3
    msg.reference_mark_labels = ["M1", "M2"]  # painted along the flange
    msg.reference_marks = [Point(x=3.0, y=0.3), Point(x=5.9, y=0.3)]
    return msg


def registration_msg() -> Registration:
    msg = Registration(valid=True, residual=0.0002, message="3 marks, residual 0.2 mm")
    msg.m_local2world = [0.0, -1.0, PART_AT[0], 1.0, 0.0, PART_AT[1], 0.0, 0.0, 1.0]
    return msg


def state_of(msg: dict, stud_id: str) -> str | None:
    return next((s["state"] for s in msg["studs"] if s["stud_id"] == stud_id), None)


def world(x: float, y: float) -> list[float]:
    return [PART_AT[0] - y, PART_AT[1] + x]


def test_the_page_gets_the_plan_in_world_the_carriage_on_its_rail_and_the_station(ros_node, procs, tmp_path):
    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log",
                   {"port": port, "rail_length_m": 6.0, "rail_mount_xyz_m": MOUNT})
    procs.append(hmi)
    cell = FakeCell(ros_node)
    pub_reg = ros_node.create_publisher(Registration, "/registration/result", ros_io.LATCHED_QOS)
    cell.pub_layout.publish(layout_msg())  # latched, as the drawing node publishes it
    cell.wait_for_hmi(port, hmi)
    inbox = Inbox(WsClient("127.0.0.1", port))

    # before the registration: the drawing's coordinates, the rail as the parameters give it
    msg = inbox.wait(lambda m: m["type"] == "plan" and len(m["studs"]) == 90, ros_node, "the plan of the drawing")
    assert msg["frame"] == "drawing" and msg["studs"][4]["xy_m"] == pytest.approx([0.3, 0.14])
    assert msg["studs"][4]["state"] == "not_seen" and msg["studs"][0]["d_m"] == pytest.approx(0.019)
    assert msg["rail"] == {"length_m": 6.0, "extent_m": [0.0, 6.0], "mount_xyz_m": MOUNT, "reach_m": 0.61}
    assert [(m["label"], m["xy_m"]) for m in msg["marks"]] == [
        ("O", [0.0, 0.0]), ("A", [0.5, 0.0]), ("B", [0.0, 0.3]), ("M1", [3.0, 0.3]), ("M2", [5.9, 0.3])]

    # the registration puts the part in world (Eq. 2)
    pub_reg.publish(registration_msg())
    msg = inbox.wait(lambda m: m["type"] == "plan" and m["frame"] == "world", ros_node, "the plan in world")
    for s, (_sid, x, y) in zip(msg["studs"], DRAWING):
        assert s["xy_m"] == pytest.approx(world(x, y), abs=1e-5)
    assert msg["marks"][3]["xy_m"] == pytest.approx(world(3.0, 0.3), abs=1e-5)
    b = msg["bounds_m"]  # the part: the studs (0.1 .. 5.9 m along the drawing's x) and the marks
    assert b == pytest.approx([PART_AT[0] - 0.3, PART_AT[1], PART_AT[0], PART_AT[1] + 5.9], abs=1e-5)

    # the carriage: /arm/state's rail position reaches the page with the arm's base and reach
    def carriage(pos: float, moving: bool):
        def publish():
            state = ArmState(mode=ArmState.MODE_MOVING, connected=True, rail_position_m=pos, rail_moving=moving)
            state.tool_pose.position.z = math.nan
            cell.pub_arm.publish(state)
        return publish
    arm = inbox.wait(lambda m: m["type"] == "arm" and m["rail_position_m"] == 2.25, ros_node, "the carriage at 2.25 m",
                     publish=carriage(2.25, True))
    assert arm["rail_moving"] is True
    assert arm["carriage"] == {"position_m": 2.25, "moving": True, "base_xy_m": [2.3, -0.45], "reach_m": 0.61}
    arm = inbox.wait(lambda m: m["type"] == "arm" and m["rail_position_m"] == 3.5 and not m["rail_moving"], ros_node,
                     "the carriage stopped at 3.5 m", publish=carriage(3.5, False))
    assert arm["carriage"]["base_xy_m"] == [3.55, -0.45]

    # the station being worked (its camera), the unreachable studs with their reasons
    why = "unreachable: approach pose 0.66 m from the arm's base, beyond its reach"

    def status():
        cell.pub_cell.publish(CellStatus(
            state=CellStatus.STATE_WELDING, state_text="welding", station=3, stations_total=9, studs_total=90,
            unreachable=["S0090", "S0001"], unreachable_reasons=[why, "unreachable: no camera station covers it"],
            camera_xyz_m=[1.3, 0.5, 0.55], camera_yaw_rad=0.0, camera_footprint_m=[0.3, 0.2]))
    msg = inbox.wait(lambda m: m["type"] == "plan" and m["station"] is not None, ros_node, "the station on the plan",
                     publish=status)
    st = msg["station"]
    assert (st["index"], st["total"], st["camera_xyz_m"]) == (3, 9, [1.3, 0.5, 0.55])
    expected = [sid for sid, x, y in DRAWING if abs(world(x, y)[0] - 1.3) <= 0.15 and abs(world(x, y)[1] - 0.5) <= 0.1]
    assert st["stud_ids"] == expected and len(expected) == 3
    assert msg["unreachable"] == [{"stud_id": "S0001", "reason": "unreachable: no camera station covers it"},
                                  {"stud_id": "S0090", "reason": why}]
    by_id = {s["stud_id"]: s for s in msg["studs"]}
    assert by_id["S0090"]["state"] == "unreachable" and by_id["S0002"]["state"] == "planned"

    # a matched stud turns ok, then being welded: the plan follows the stud table
    view = [target("S0002", WeldTarget.STATUS_OK, (*world(0.1, 0.14), 0.2))]
    msg = inbox.wait(lambda m: m["type"] == "plan" and state_of(m, "S0002") == "ok",
                     ros_node, "S0002 ok on the plan", publish=lambda: cell.targets(view))
    cell.arm(current_stud="S0002", errors=())
    inbox.wait(lambda m: m["type"] == "plan" and state_of(m, "S0002") == "welding",
               ros_node, "S0002 being welded on the plan")
    assert ctrl_c(hmi) == 0 and "Traceback" not in hmi.output(), hmi.output()


def test_without_a_rail_the_page_gets_no_rail_and_no_carriage(ros_node, procs, tmp_path):
    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log", {"port": port})
    procs.append(hmi)
    cell = FakeCell(ros_node)
    cell.layout(["S0001", "S0002"])
    cell.wait_for_hmi(port, hmi)
    inbox = Inbox(WsClient("127.0.0.1", port))
    arm = inbox.wait(lambda m: m["type"] == "arm", ros_node, "arm", publish=lambda: cell.arm(errors=()))
    assert arm["rail_position_m"] == 0.0 and arm["carriage"] is None
    msg = inbox.wait(lambda m: m["type"] == "plan" and len(m["studs"]) == 2, ros_node, "the plan")
    assert msg["rail"] is None and msg["carriage"] is None and msg["station"] is None
    assert ctrl_c(hmi) == 0
