"""`ros2 run stud_planner hmi` as a real process; this test process is the rest of the cell (topics,
Trigger services, a WeldJob action server) and a browser (a raw WebSocket client)."""
from __future__ import annotations

import base64
import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stud_welding_msgs.msg", reason="workspace not built/sourced (source ros2_ws/setup.bash)")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from stud_welding_msgs.action import WeldJob  # noqa: E402
from stud_welding_msgs.msg import WeldTarget  # noqa: E402

from fake_cell import FakeCell, target  # noqa: E402
from hmi_testing import ctrl_c, free_port  # noqa: E402
from rosproc import ros2_run, wait_for  # noqa: E402
from ws_client import WsClient  # noqa: E402

OK, NO_DEPTH, OUT = WeldTarget.STATUS_OK, WeldTarget.STATUS_NO_DEPTH, WeldTarget.STATUS_OUT_OF_VIEW


class Inbox:
    """Messages of one WebSocket client, read while the test node spins."""

    def __init__(self, ws: WsClient):
        self.ws = ws
        self.msgs: list[dict] = []

    def find(self, pred):
        self.msgs.extend(self.ws.poll(0.01))
        return next((m for m in reversed(self.msgs) if pred(m)), None)

    def wait(self, pred, node, what, timeout_s=15.0, every_s=0.5, publish=None) -> dict:
        """The newest message matching ``pred``; ``publish()`` is repeated every ``every_s`` meanwhile."""
        last = [0.0]

        def ready():
            if publish is not None and time.monotonic() - last[0] > every_s:
                publish()
                last[0] = time.monotonic()
            return self.find(pred) is not None
        wait_for(ready, timeout_s, spin=node.spin, what=what)
        return self.find(pred)


def rows(msg) -> dict:
    return {r["stud_id"]: r for r in msg["rows"]}


def test_hmi_streams_the_cell_to_a_websocket_client_and_stop_calls_both_services(ros_node, procs, tmp_path):
    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log",
                   {"port": port, "overlay_max_width": 320, "overlay_rate_hz": 20.0})
    procs.append(hmi)
    cell = FakeCell(ros_node)
    cell.layout(["S0001", "S0002", "S0003", "S0004"])  # latched: the hmi gets it whenever it starts
    cell.wait_for_hmi(port, hmi)
    ws = WsClient("127.0.0.1", port)
    inbox = Inbox(ws)
    assert inbox.wait(lambda m: m["type"] == "hello", ros_node, "hello")["commands"] == [
        "start", "pause", "resume", "stop", "estop", "ack", "resolve_stud", "record_rework", "record_bend_test"]

    # -- targets: the table's rows, NaN as null -------------------------------------------------------
    view = [target("S0001", OK, (0.1, 0.2, 0.05), incl_deg=2.5, xy_error_m=0.0004),
            target("S0002", NO_DEPTH), target("S0003", OUT)]
    msg = inbox.wait(lambda m: m["type"] == "targets" and m["view"] == 0 and len(m["rows"]) == 4, ros_node,
                     "targets and the layout", publish=lambda: cell.targets(view))
    r = rows(msg)
    assert [row["stud_id"] for row in msg["rows"]] == ["S0001", "S0002", "S0003", "S0004"]  # drawing order
    assert r["S0004"]["status"] == "not_seen" and r["S0004"]["position_mm"] is None
    assert r["S0001"]["status"] == "ok" and r["S0001"]["inclination_deg"] == pytest.approx(2.5)
    assert r["S0001"]["position_mm"] == pytest.approx([100.0, 200.0, 50.0])
    assert r["S0001"]["xy_error_mm"] == pytest.approx(0.4) and r["S0001"]["welded"] is False
    assert r["S0002"]["status"] == "no_depth" and r["S0002"]["position_mm"] == [None, None, None]
    assert r["S0002"]["inclination_deg"] is None and r["S0003"]["status"] == "out_of_view"
    assert msg["counts"] == {"ok": 1, "no_depth": 1, "out_of_view": 1, "not_seen": 1}

    # -- overlay: downscaled JPEG, same picture ---------------------------------------------------------
    ov = inbox.wait(lambda m: m["type"] == "overlay", ros_node, "overlay", publish=cell.overlay)
    img = cv2.imdecode(np.frombuffer(base64.b64decode(ov["jpeg_base64"]), np.uint8), cv2.IMREAD_COLOR)
    assert img.shape == (240, 320, 3) and (ov["width"], ov["source_width"]) == (320, 1280)
    assert np.allclose(img[120, 40], (0, 0, 255), atol=40) and np.allclose(img[120, 280], (0, 0, 0), atol=40)

    # -- arm, cell, errors --------------------------------------------------------------------------------
    arm = inbox.wait(lambda m: m["type"] == "arm", ros_node, "arm", publish=cell.arm)
    assert (arm["mode"], arm["current_stud"], arm["done"], arm["total"], arm["connected"]) == (
        "welding", "S0001", 1, 3, True)
    assert arm["errors"] == ["joint 3 over temperature"] and arm["error_codes"] == [0x5001]
    assert arm["tool_position_mm"][0] == pytest.approx(250.0) and arm["tool_position_mm"][2] is None
    active = inbox.wait(lambda m: m["type"] == "targets" and rows(m)["S0001"]["weld"] == "active", ros_node,
                        "S0001 shown as being welded")
    assert rows(active)["S0002"]["weld"] == ""
    c = inbox.wait(lambda m: m["type"] == "cell", ros_node, "cell", publish=cell.cell)
    assert (c["state"], c["station"], c["stations_total"], c["studs_welded"], c["studs_total"]) == (
        "welding", 2, 4, 1, 3)
    assert c["unreachable"] == ["S0099"]
    alarms = inbox.wait(lambda m: m["type"] == "alarms" and any(a["source"] == "fake_node" for a in m["active"]),
                        ros_node, "alarms", publish=lambda: cell.diagnostic("fake_node", 2, "camera not found"))
    item = next(a for a in alarms["active"] if a["source"] == "fake_node")
    assert (item["code"], item["severity"], item["text"], item["acked"]) == ("A202", "error", "camera not found", False)
    assert "A112" in [a["code"] for a in alarms["active"]]  # S0099 unreachable, from /cell/status
    status = inbox.wait(lambda m: m["type"] == "status" and m["cell"] is not None and m["arm"] is not None,
                        ros_node, "status")
    assert status["controls"]["start"] == {"enabled": False, "why": "a job is under way (welding)"}
    assert status["controls"]["pause"]["enabled"] and status["controls"]["stop"]["enabled"]
    assert status["safety"] is None and status["part"]["part"] == "part"
    ws.send_json({"cmd": "ack", "alarm": item["key"], "id": 40})
    reply = inbox.wait(lambda m: m["type"] == "reply" and m.get("id") == 40, ros_node, "reply to ack")
    assert reply["ok"] and reply["message"] == "1 alarm(s) acknowledged"
    inbox.wait(lambda m: m["type"] == "alarms" and any(a["key"] == item["key"] and a["acked"] for a in m["active"]),
               ros_node, "the alarm acknowledged")

    # -- Stop: both services are called, the reply names both ---------------------------------------------
    ws.send_json({"cmd": "stop", "id": 42})
    reply = inbox.wait(lambda m: m["type"] == "reply" and m.get("id") == 42, ros_node, "reply to stop")
    assert cell.calls == {"/cell/stop": 1, "/arm/stop": 1}
    assert reply["ok"] is True and reply["cmd"] == "stop"
    assert [(x["service"], x["success"], x["message"]) for x in reply["results"]] == [
        ("/cell/stop", True, "/cell/stop done (fake)"), ("/arm/stop", True, "/arm/stop done (fake)")]

    # -- a command not valid now is refused before ROS; a service that is not there: a clear error ---------
    ws.send_json({"cmd": "start", "id": 43})
    reply = inbox.wait(lambda m: m["type"] == "reply" and m.get("id") == 43, ros_node, "reply to start")
    assert reply["ok"] is False and reply["error"] == "not valid now: a job is under way (welding)"
    ws.send_json({"cmd": "pause", "id": 46})
    reply = inbox.wait(lambda m: m["type"] == "reply" and m.get("id") == 46, ros_node, "reply to pause")
    assert reply["ok"] is False and "/cell/pause is not available" in reply["results"][0]["message"]
    ws.send_json({"cmd": "weld everything", "id": 44})
    reply = inbox.wait(lambda m: m["type"] == "reply" and m.get("id") == 44, ros_node, "reply to unknown")
    assert reply["ok"] is False and "unknown command" in reply["error"]
    ws.send_json({"cmd": ["stop"], "id": 45})
    reply = inbox.wait(lambda m: m["type"] == "reply" and m.get("id") == 45, ros_node, "reply to a list")
    assert reply["ok"] is False and "unknown command" in reply["error"]

    # -- a weld job: feedback and the job's result mark studs welded / failed -----------------------------
    result = WeldJob.Result(welded=["S0001"], failed=["S0002"], messages=["S0002: no depth"], success=False,
                            message="done: 1 welded, 0 skipped, 1 failed")
    cell.serve_weld_job([("S0001", "approach"), ("S0001", "weld"), ("S0001", "retract"), ("S0002", "skip")], result)
    client = ActionClient(ros_node, WeldJob, "/arm/weld_job")
    wait_for(lambda: client.server_is_ready(), 10, spin=ros_node.spin, what="weld job server")
    client.send_goal_async(WeldJob.Goal(targets=view[:2]))
    cell.arm(mode=0, current_stud="", done=0, total=0)  # the job is over: no stud in progress
    job = inbox.wait(lambda m: m["type"] == "job", ros_node, "job result")
    assert (job["status"], job["welded"], job["failed"]) == ("succeeded", ["S0001"], ["S0002"])
    final = inbox.wait(lambda m: m["type"] == "targets" and rows(m)["S0002"]["weld"] == "failed", ros_node,
                       "table after the job")
    r = rows(final)
    assert (r["S0001"]["weld"], r["S0001"]["welded"], r["S0003"]["weld"]) == ("welded", True, "")
    assert final["welded"] == 1

    # -- Ctrl-C (to the process group, as a terminal sends it): clean exit, the browser is told -----------
    assert ctrl_c(hmi) == 0
    assert "Traceback" not in hmi.output(), hmi.output()
    wait_for(lambda: inbox.find(lambda m: False) is None and ws.closed_with is not None, 5,
             what="the close frame")
    assert ws.closed_with == 1001
    ws.close()
