"""The drawing node and a drawing beyond its work budget (``drawing_limits.*``): it stays up
without a layout, says why on /diagnostics (the block, its level, the count, the parameter that
raises the limit), and loads a good drawing afterwards. A real process, received over DDS."""
from __future__ import annotations

import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from stud_welding_msgs.msg import StudLayout
from stud_welding_msgs.srv import LoadDrawing

from rosproc import REPO, ros2_run, wait_for
from stud_common import ros_io

sys.path.insert(0, str(REPO / "tests" / "planner"))
from test_drawing_budget import insert_bomb, minsert_bomb  # noqa: E402

DEMO_DXF = REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf"


def _call(node, client, request, timeout=30):
    wait_for(lambda: client.service_is_ready(), timeout, spin=node.spin, what=f"service {client.srv_name}")
    future = client.call_async(request)
    wait_for(future.done, timeout, spin=node.spin, what=f"reply of {client.srv_name}")
    return future.result()


def test_drawing_node_refuses_a_bomb_stays_up_says_why_on_diagnostics_and_loads_a_good_drawing(
        ros_node, procs, tmp_path):
    bomb = insert_bomb(tmp_path / "bomb.dxf")
    node = ros2_run("stud_planner", "drawing", tmp_path / "drawing.log", {"drawing_file": str(bomb)})
    procs.append(node)
    diags: list[DiagnosticArray] = []
    layouts: list[StudLayout] = []
    ros_node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
    ros_node.create_subscription(StudLayout, "/drawing/layout", layouts.append, ros_io.LATCHED_QOS)

    def refusal() -> str | None:
        for d in diags:
            for s in d.status:
                if s.level == DiagnosticStatus.ERROR and "max_expanded_entities" in s.message:
                    return s.message
        return None

    wait_for(lambda: refusal() is not None, 60, spin=ros_node.spin,
             what=f"the refusal on /diagnostics\n{node.output()}")
    message = refusal()
    assert f"{bomb}: block 'L7' (nesting level 4) placed 10 times in block 'L8'" in message, message
    assert "raise the parameter drawing_limits.max_expanded_entities" in message
    assert "\n" not in message and "Traceback" not in node.output()
    assert node.popen.poll() is None and not layouts  # up, and no layout: nothing to plan from

    client = ros_node.create_client(LoadDrawing, "/drawing/load")
    reply = _call(ros_node, client, LoadDrawing.Request(drawing_file=str(minsert_bomb(tmp_path / "minsert.dxf"))))
    assert not reply.success and "max_minsert_cells = 1,000,000" in reply.message
    reply = _call(ros_node, client, LoadDrawing.Request(drawing_file=str(DEMO_DXF)))
    assert reply.success and reply.stud_count > 0, reply.message
    wait_for(lambda: layouts, 30, spin=ros_node.spin, what="/drawing/layout after the good drawing")
    assert len(layouts[-1].studs) == reply.stud_count and node.popen.poll() is None


def test_the_cell_var_drawing_limits_reaches_the_drawing_node_and_lets_a_large_drawing_through(
        ros_node, procs, tmp_path):
    """``--var 'drawing_limits={...}'`` -> the drawing node's parameter file (the cell's own) -> the node
    reads a drawing beyond the default it would refuse."""
    from rosproc import Proc
    from stud_bringup.launch import default_config_path, load_config, plan_cell, write_params_file

    drawing = insert_bomb(tmp_path / "large.dxf", levels=4)  # 1,000 studs, 2,110 entities expanded
    plan, _ = plan_cell(load_config(default_config_path()), "sim", out_dir=str(tmp_path / "run"),
                        cli_vars={"drawing": str(drawing), "drawing_limits": {"max_expanded_entities": 2110}})
    (node_plan,) = [n for n in plan if n.name == "drawing"]
    assert node_plan.params["drawing_limits"] == {"max_expanded_entities": 2110}
    params_file = write_params_file(node_plan, tmp_path / "run" / "params")
    node = Proc(node_plan.command(str(params_file)), tmp_path / "drawing.log")
    procs.append(node)
    layouts: list[StudLayout] = []
    ros_node.create_subscription(StudLayout, "/drawing/layout", layouts.append, ros_io.LATCHED_QOS)
    wait_for(lambda: layouts, 60, spin=ros_node.spin, what=f"/drawing/layout\n{node.output()}")
    assert len(layouts[-1].studs) == 1000

    # one entity fewer, through the node's own parameter: refused, the node up
    refused = ros2_run("stud_planner", "drawing", tmp_path / "refused.log",
                       {"drawing_file": str(drawing), "drawing_limits.max_expanded_entities": 2109})
    procs.append(refused)
    wait_for(lambda: "beyond the limit max_expanded_entities = 2,109" in refused.output(), 60,
             what=f"the refusal in the log\n{refused.output()}")
    assert refused.popen.poll() is None
