"""The plan of the part in a real browser: headless Chromium on the page of `ros2 run stud_planner hmi`,
this test process the rest of the cell (a 6 m girder's drawing, its registration, the arm on a rail,
the sequencer). Skipped when no Chromium binary is found (test_hmi_browser.py's fixtures)."""
from __future__ import annotations

import math
import time

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stud_welding_msgs.msg", reason="workspace not built/sourced (source ros2_ws/setup.bash)")

from stud_welding_msgs.msg import ArmState, CellStatus, Registration, WeldTarget  # noqa: E402

from fake_cell import FakeCell, target  # noqa: E402
from hmi_testing import ctrl_c, free_port  # noqa: E402
from rosproc import ros2_run, wait_for  # noqa: E402
from stud_common import ros_io  # noqa: E402
from stud_hmi.part_plan import fit_view  # noqa: E402
from test_hmi_browser import _chromium, browser_factory  # noqa: E402,F401  (fixtures)
from test_hmi_plan_node import DRAWING, MOUNT, layout_msg, registration_msg, world  # noqa: E402

CIRCLE = "document.querySelector('#plan-studs circle[data-stud=\"{sid}\"]')"


def cdp(page, method: str, params: dict, timeout_s: float = 10.0) -> dict:
    """One DevTools command to the page (real input events), its result."""
    page._id += 1
    page.cdp.send_json({"id": page._id, "method": method, "params": params})
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = page.cdp.recv_message(max(0.01, deadline - time.monotonic()))
        if msg is not None and msg.get("id") == page._id:
            assert "error" not in msg, msg
            return msg.get("result", {})
    raise AssertionError(f"no answer to {method}")


def mouse(page, kind: str, x: float, y: float, **extra) -> None:
    cdp(page, "Input.dispatchMouseEvent", {"type": kind, "x": x, "y": y, "button": "left",
                                           "buttons": 1 if kind != "mouseReleased" else 0, "clickCount": 1, **extra})


def test_the_plan_shows_a_girder_fitted_with_states_zoom_scroll_carriage_station_and_reasons(
        ros_node, procs, tmp_path, browser_factory):  # noqa: F811
    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log",
                   {"port": port, "rail_length_m": 6.0, "rail_mount_xyz_m": MOUNT})
    procs.append(hmi)
    cell = FakeCell(ros_node)
    pub_reg = ros_node.create_publisher(Registration, "/registration/result", ros_io.LATCHED_QOS)
    cell.pub_layout.publish(layout_msg())
    pub_reg.publish(registration_msg())
    cell.wait_for_hmi(port, hmi)
    url = f"http://127.0.0.1:{port}/"
    page = browser_factory(url)
    js = page.evaluate
    again = {"arm": lambda: None, "cell": lambda: None}

    def fail() -> str:
        shown = js("document.body ? document.body.innerText : ''")
        return f"\n--- page\n{shown[-1500:]}\n--- hmi\n{hmi.output()[-1500:]}"

    def until(expr: str, what: str, timeout_s: float = 15.0):
        last = [0.0]

        def ready():
            if time.monotonic() - last[0] > 0.5:
                again["arm"]()
                again["cell"]()
                last[0] = time.monotonic()
            return js(f"!!({expr})") is True
        wait_for(ready, timeout_s, spin=ros_node.spin, what=what + fail())

    # (1) the whole girder in world, fitted to the drawing area on load (as part_plan.fit_view)
    until("document.querySelectorAll('#plan-studs circle').length === 90 && window.hmiPlan.msg.frame === 'world'",
          "90 studs on the plan in world")
    until("window.hmiPlan.view", "a fitted view")
    w, h = js("(() => { const r = document.getElementById('plan').getBoundingClientRect();"
              " return [r.width, r.height]; })()")
    bounds = js("window.hmiPlan.msg.bounds_m")
    (cx, cy), scale = fit_view(bounds, w, h)
    view = js("window.hmiPlan.view")
    assert view["scale"] == pytest.approx(scale, rel=1e-9) and (view["cx"], view["cy"]) == pytest.approx((cx, cy))
    inside = js("(() => { const r = document.getElementById('plan').getBoundingClientRect();"
                " return Array.from(document.querySelectorAll('#plan-studs circle')).every(c => {"
                " const b = c.getBoundingClientRect(); return b.left >= r.left && b.right <= r.right"
                " && b.top >= r.top && b.bottom <= r.bottom; }); })()")
    assert inside is True
    # a stud is drawn where the registration puts it: its centre on screen, from the page's own view
    box = js(f"(() => {{ const b = {CIRCLE.format(sid='S0005')}.getBoundingClientRect();"
             " const r = document.getElementById('plan').getBoundingClientRect();"
             " return [b.left + b.width / 2 - r.left, b.top + b.height / 2 - r.top]; })()")
    wx, wy = world(*DRAWING[4][1:])
    assert box == pytest.approx([w / 2 + (wx - cx) * scale, h / 2 - (wy - cy) * scale], abs=0.6)

    # (2) a stud's colour changes with its state: planned -> ok (a view) -> welding (the arm on it)
    def fill(sid: str) -> str:
        return js(f"getComputedStyle({CIRCLE.format(sid=sid)}).fill")

    def cell_status():
        cell.pub_cell.publish(CellStatus(
            state=CellStatus.STATE_WELDING, state_text="welding", station=3, stations_total=9, studs_total=90,
            unreachable=["S0090"], unreachable_reasons=["unreachable: approach pose beyond the arm's reach"],
            camera_xyz_m=[1.3, 0.5, 0.55], camera_yaw_rad=0.0, camera_footprint_m=[0.3, 0.2]))
    again["cell"] = cell_status
    until(CIRCLE.format(sid="S0002") + ".classList.contains('ps-planned')", "S0002 planned")
    planned = fill("S0002")
    cell.targets([target("S0002", WeldTarget.STATUS_OK, (*world(0.1, 0.14), 0.2))])
    until(CIRCLE.format(sid="S0002") + ".classList.contains('ps-ok')", "S0002 ok on the plan")
    ok = fill("S0002")
    again["arm"] = lambda: cell.arm(current_stud="S0002", errors=())
    until(CIRCLE.format(sid="S0002") + ".classList.contains('ps-welding')", "S0002 being welded on the plan")
    welding = fill("S0002")
    assert len({planned, ok, welding}) == 3, (planned, ok, welding)
    assert fill("S0003") == planned
    legend = js("Object.fromEntries(Array.from(document.querySelectorAll('#plan-legend li'))"
                ".map(li => [li.dataset.state, li.textContent]))")
    assert (legend["welding"] == "welding 1" and legend["unreachable"] == "unreachable 1"
            and legend["planned"] == "planned 88")

    # (3) the station being worked: its footprint, its studs ringed; the unreachable stud listed with its reason
    until("document.querySelector('#plan-station polygon.footprint')", "the camera footprint")
    ringed = js("Array.from(document.querySelectorAll('#plan-studs circle.in-station')).map(c => c.dataset.stud)")
    assert sorted(ringed) == sorted(sid for sid, x, y in DRAWING
                                    if abs(world(x, y)[0] - 1.3) <= 0.15 and abs(world(x, y)[1] - 0.5) <= 0.1)
    until("document.querySelector('#plan-unreachable li[data-stud=\"S0090\"]')", "S0090 listed as unreachable")
    assert js("document.querySelector('#plan-unreachable li[data-stud=\"S0090\"]').textContent") == \
        "S0090 unreachable: approach pose beyond the arm's reach"
    assert js("document.getElementById('plan-unreachable-box').hidden") is False

    # (4) the carriage on its rail with the arm's reach, where /arm/state puts it
    def on_rail(pos: float):
        def publish():
            state = ArmState(mode=ArmState.MODE_MOVING, connected=True, current_stud="S0002", rail_position_m=pos,
                             rail_moving=True)
            state.tool_pose.position.z = math.nan
            cell.pub_arm.publish(state)
        return publish
    again["arm"] = on_rail(3.5)
    until("document.getElementById('plan-carriage').dataset.position === '3.5'", "the carriage at 3.5 m")
    assert js("document.getElementById('plan-carriage').getAttribute('visibility')") == "visible"
    assert js("Number(document.querySelector('#plan-carriage .reach').getAttribute('cx'))") == pytest.approx(3.55)
    assert js("Number(document.querySelector('#plan-carriage .reach').getAttribute('r'))") == pytest.approx(0.61)
    assert js("document.querySelector('#plan-rail line.rail').getAttribute('x2')") == "6"
    assert "carriage 3.500 m moving" in js("document.getElementById('plan-carriage-text').textContent")

    # (5) zoom: the buttons and the wheel change the scale; drag scrolls; Fit returns
    js("document.getElementById('plan-zoom-in').click()")
    assert js("window.hmiPlan.view.scale") == pytest.approx(1.5 * scale)
    assert js("document.getElementById('plan').dataset.scale") == str(js("window.hmiPlan.view.scale"))
    r = js("(() => { const p = document.getElementById('plan'); p.scrollIntoView({block: 'start'});"
           " const r = p.getBoundingClientRect(); return [r.left, r.top]; })()")  # (real input needs it in view)
    cdp(page, "Input.dispatchMouseEvent", {"type": "mouseWheel", "x": r[0] + w / 2, "y": r[1] + h / 2,
                                           "deltaX": 0, "deltaY": -300})
    until(f"window.hmiPlan.view.scale > {1.5 * scale * 1.5}", "the wheel zooms in")
    zoomed = js("window.hmiPlan.view")
    mouse(page, "mousePressed", r[0] + 100, r[1] + 100)
    mouse(page, "mouseMoved", r[0] + 160, r[1] + 140)
    mouse(page, "mouseReleased", r[0] + 160, r[1] + 140)
    dragged = js("window.hmiPlan.view")
    assert dragged["scale"] == zoomed["scale"]
    assert (dragged["cx"], dragged["cy"]) == pytest.approx((zoomed["cx"] - 60 / zoomed["scale"],
                                                            zoomed["cy"] + 40 / zoomed["scale"]))
    # a stud's details on click (the marker at least marker_min_px: the studs stay readable zoomed out)
    js("document.querySelector('#plan-unreachable li[data-stud=\"S0090\"]').click()")  # shown and centred
    assert js("window.hmiPlan.view.cx") == pytest.approx(world(*DRAWING[89][1:])[0])
    js("document.getElementById('plan-fit').click()")
    assert js("window.hmiPlan.view.scale") == pytest.approx(scale, rel=1e-9)
    c = js(f"(() => {{ const b = {CIRCLE.format(sid='S0090')}.getBoundingClientRect();"
           " return [b.left + b.width / 2, b.top + b.height / 2, b.width]; })()")
    assert c[2] >= 2 * js("window.hmiPlan.minPx") - 0.01
    mouse(page, "mousePressed", c[0], c[1])
    mouse(page, "mouseReleased", c[0], c[1])
    assert js("document.getElementById('plan-detail').textContent").startswith(
        "S0090 · unreachable · unreachable: approach pose beyond the arm's reach")
    page.close()
    assert ctrl_c(hmi) == 0 and "Traceback" not in hmi.output(), hmi.output()


def test_the_page_of_a_cell_without_a_rail_draws_no_rail_and_no_carriage(ros_node, procs, tmp_path,
                                                                         browser_factory):  # noqa: F811
    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log", {"port": port})
    procs.append(hmi)
    cell = FakeCell(ros_node)
    cell.layout(["S0001", "S0002", "S0003"])
    cell.wait_for_hmi(port, hmi)
    page = browser_factory(f"http://127.0.0.1:{port}/")
    js = page.evaluate

    def ready():
        cell.arm(errors=())
        return js("document.querySelectorAll('#plan-studs circle').length === 3 && !!window.hmiPlan.view") is True
    wait_for(ready, 15, spin=ros_node.spin, what="the plan of three studs")
    assert js("document.getElementById('plan-info').textContent").startswith(
        "drawing coordinates: the part is not registered yet · 3 studs")
    assert js("document.querySelectorAll('#plan-rail *').length") == 0
    assert js("document.getElementById('plan-carriage').getAttribute('visibility')") == "hidden"
    assert js("document.getElementById('plan-carriage-text').textContent") == ""
    page.close()
    assert ctrl_c(hmi) == 0
