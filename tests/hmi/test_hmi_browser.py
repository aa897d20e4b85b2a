"""The HMI page in a real browser: headless Chromium driven over the DevTools protocol (CDP) with
the tests' own WebSocket client, against `ros2 run stud_planner hmi` and this test process as
the rest of the cell. Skipped when no Chromium binary is found (set CHROMIUM=/path to choose one).
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import time
import urllib.request
from pathlib import Path
from urllib.parse import urlsplit

import pytest

pytest.importorskip("rclpy")
pytest.importorskip("stud_welding_msgs.msg", reason="workspace not built/sourced (source ros2_ws/setup.bash)")

from stud_welding_msgs.msg import WeldTarget  # noqa: E402

from fake_cell import FakeCell, target  # noqa: E402
from hmi_testing import ctrl_c, free_port  # noqa: E402
from rosproc import ros2_run, wait_for  # noqa: E402
from ws_client import WsClient  # noqa: E402


def find_chromium() -> str | None:
    candidates = [os.environ.get("CHROMIUM")] + [shutil.which(n) for n in (
        "chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")]
    return next((c for c in candidates if c and os.access(c, os.X_OK)), None)


CHROMIUM = find_chromium()


@pytest.fixture(autouse=True)
def _chromium(prerequisite):
    """Skips without Chromium; fails under CI=true (.ci/run installs it when it runs as root)."""
    prerequisite(CHROMIUM is not None, "no Chromium binary found (apt-get install chromium, or set "
                                       "CHROMIUM=/path/to/chrome)")


class Browser:
    """Headless Chromium on ``url`` in a process group of its own; one CDP session to its page."""

    def __init__(self, url: str, tmp_path: Path):
        self.profile = tmp_path / "chromium-profile"
        self.log_path = tmp_path / "chromium.log"
        self._log = open(self.log_path, "w")
        self.popen = subprocess.Popen(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync", "--disable-quic",
             "--disable-dev-shm-usage", "--no-default-browser-check", "--remote-debugging-port=0",
             f"--user-data-dir={self.profile}", url],
            stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True)
        self.cdp: WsClient | None = None
        self._id = 0

    def output(self) -> str:
        if not self._log.closed:
            self._log.flush()
        return self.log_path.read_text(errors="replace")[-3000:]

    def connect(self, url: str, timeout_s: float = 30.0) -> None:
        """Find the DevTools port (DevToolsActivePort in the profile) and attach to the page."""
        port_file = self.profile / "DevToolsActivePort"

        def port_known() -> bool:
            assert self.popen.poll() is None, f"chromium exited:\n{self.output()}"
            return port_file.is_file() and len(port_file.read_text().split()) >= 2
        wait_for(port_known, timeout_s, what="chromium's DevToolsActivePort")
        port = int(port_file.read_text().split()[0])
        page = []

        def page_listed() -> bool:
            targets = json.loads(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=2).read())
            page[:] = [t for t in targets if t.get("type") == "page" and t.get("url", "").startswith(url)]
            return bool(page)
        wait_for(page_listed, timeout_s, what="the HMI page in chromium's target list")
        self.cdp = WsClient("127.0.0.1", port, path=urlsplit(page[0]["webSocketDebuggerUrl"]).path)

    def evaluate(self, expression: str, timeout_s: float = 10.0):
        """Runtime.evaluate in the page; the value (JSON-able) or an AssertionError with the exception."""
        self._id += 1
        self.cdp.send_json({"id": self._id, "method": "Runtime.evaluate",
                            "params": {"expression": expression, "returnByValue": True}})
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self.cdp.recv_message(max(0.01, deadline - time.monotonic()))
            if msg is not None and msg.get("id") == self._id:  # (events have no id)
                result = msg["result"]
                assert "exceptionDetails" not in result, result["exceptionDetails"]
                return result["result"].get("value")

    def close(self) -> None:
        if self.cdp is not None:
            self.cdp.close()
        try:
            os.killpg(self.popen.pid, signal.SIGTERM)
            self.popen.wait(timeout=5)
        except subprocess.TimeoutExpired:
            os.killpg(self.popen.pid, signal.SIGKILL)
            self.popen.wait()
        except ProcessLookupError:
            pass
        try:  # renderer/zygote children left in the group
            os.killpg(self.popen.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self._log.close()


@pytest.fixture()
def browser_factory(tmp_path):
    started = []

    def start(url: str) -> Browser:
        b = Browser(url, tmp_path)
        started.append(b)
        b.connect(url)
        return b
    yield start
    for b in started:
        b.close()


def start_hmi_and_page(ros_node, procs, tmp_path, browser_factory):
    """`ros2 run stud_planner hmi` on a free port, a FakeCell, and Chromium on the page: (hmi, cell, page, url)."""
    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log", {"port": port})
    procs.append(hmi)
    cell = FakeCell(ros_node)
    cell.wait_for_hmi(port, hmi)
    url = f"http://127.0.0.1:{port}/"
    return hmi, cell, browser_factory(url), url


ROW_JS = """(() => {{ const r = document.querySelector('#studs tr[data-stud="{sid}"]');
  return r ? {{cls: r.className, cells: Array.from(r.children).map(td => td.textContent)}} : null; }})()"""


def test_page_in_headless_chromium_shows_published_targets_and_its_stop_button_reaches_arm_stop(
        ros_node, procs, tmp_path, browser_factory):
    hmi, cell, page, url = start_hmi_and_page(ros_node, procs, tmp_path, browser_factory)
    fail = lambda: f"\n--- hmi\n{hmi.output()[-2000:]}\n--- chromium\n{page.output()}"  # noqa: E731

    # (a) the page loads and its WebSocket connects (the indicator turns green, buttons enabled)
    # (the page target is listed while still on about:blank: wait for the navigation to complete)
    wait_for(lambda: page.evaluate("location.href + ' ' + document.readyState") == f"{url} complete", 15,
             spin=ros_node.spin, what="page load" + fail())
    assert page.evaluate("document.title") == "Stud welding cell"
    wait_for(lambda: page.evaluate("document.getElementById('connection').className") == "conn up", 15,
             spin=ros_node.spin, what="the page's WebSocket to connect" + fail())
    # (nothing known of the cell yet: Stop and E-STOP are offered, Start is not)
    wait_for(lambda: page.evaluate("document.getElementById('btn-stop').disabled") is False, 10,
             spin=ros_node.spin, what="Stop enabled" + fail())
    assert page.evaluate("document.getElementById('btn-start').disabled") is True

    # (b) a target update published on /weld_targets appears in the page's table, and a newer one replaces it
    def shown(sid, view, check):
        last = [0.0]

        def ready():
            if time.monotonic() - last[0] > 0.5:
                cell.targets(view)
                last[0] = time.monotonic()
            row = page.evaluate(ROW_JS.format(sid=sid))
            return row is not None and check(row)
        wait_for(ready, 15, spin=ros_node.spin, what=f"{sid} in the page's table" + fail())
        return page.evaluate(ROW_JS.format(sid=sid))

    first = [target("S0001", WeldTarget.STATUS_OK, (0.1, 0.2, 0.05), incl_deg=2.5, xy_error_m=0.0004),
             target("S0002", WeldTarget.STATUS_NO_DEPTH)]
    row = shown("S0001", first, lambda r: r["cells"][1] == "ok")
    assert row["cells"][:7] == ["S0001", "ok", "2.5", "100.0", "200.0", "50.0", "0.40"]
    assert "st-ok" in row["cls"]
    assert page.evaluate(ROW_JS.format(sid="S0002"))["cells"][1:4] == ["no depth", "–", "–"]
    update = [target("S0001", WeldTarget.STATUS_NORMAL_UNCERTAIN, (0.15, 0.2, 0.05), incl_deg=7.0,
                     xy_error_m=0.0002, view=1)]
    row = shown("S0001", update, lambda r: r["cells"][1] == "normal uncertain")
    assert row["cells"][2:4] == ["7.0", "150.0"] and "st-normal_uncertain" in row["cls"]

    # (c) pressing Stop in the page reaches /arm/stop (and /cell/stop); the reply is shown
    page.evaluate("document.getElementById('btn-stop').click()")
    wait_for(lambda: cell.calls["/arm/stop"] >= 1, 15, spin=ros_node.spin, what="/arm/stop to be called" + fail())
    assert cell.calls == {"/cell/stop": 1, "/arm/stop": 1}
    reply = "document.querySelector('#replies li') && document.querySelector('#replies li').textContent"
    wait_for(lambda: "/arm/stop: ok" in (page.evaluate(reply) or ""), 10, spin=ros_node.spin,
             what="the stop reply on the page" + fail())
    assert page.evaluate("document.querySelector('#replies li').className") == "ok"
    page.close()
    assert ctrl_c(hmi) == 0 and "Traceback" not in hmi.output(), hmi.output()


def test_page_shows_the_banner_alarms_valid_buttons_progress_and_decisions_as_the_cell_changes(
        ros_node, procs, tmp_path, browser_factory):
    from rclpy.action import ActionClient
    from stud_welding_msgs.action import WeldJob
    from stud_welding_msgs.msg import ArmState, CellStatus

    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log", {"port": port, "part_name": "Bracket 7-114"})
    procs.append(hmi)
    cell = FakeCell(ros_node, services=("/cell/start", "/cell/pause", "/cell/stop", "/arm/stop", "/arm/estop"),
                    decisions=True)
    ids = [f"S{i:04d}" for i in range(1, 11)]
    cell.layout(ids, source_file="/parts/bracket.dxf")
    cell.hand_eye("rm65_driver", {"source": "file", "path": "/cal/hand_eye.yaml", "date": "2025-04-30",
                                  "xyz_m": [0.0, 0.05, 0.02], "rpy_deg": [0.0, 0.0, 90.0], "position_rms_mm": 0.31})
    cell.wait_for_hmi(port, hmi)
    url = f"http://127.0.0.1:{port}/"
    page = browser_factory(url)
    js = page.evaluate

    def fail() -> str:
        shown = js("document.body ? document.body.innerText : ''")
        return f"\n--- page\n{shown[-2500:]}\n--- hmi\n{hmi.output()[-2000:]}"
    state = {"cell": lambda: None, "arm": lambda: None}

    def until(expr: str, what: str, timeout_s: float = 15.0):
        """Until the page's ``expr`` is truthy; the cell's current state is re-published meanwhile."""
        last = [0.0]

        def ready():
            if time.monotonic() - last[0] > 0.5:
                state["cell"]()
                state["arm"]()
                last[0] = time.monotonic()
            return js(f"!!({expr})") is True
        wait_for(ready, timeout_s, spin=ros_node.spin, what=what + fail())

    def buttons() -> dict:
        return js("Object.fromEntries(Array.from(document.querySelectorAll('#controls button[data-cmd]'))"
                  ".map(b => [b.dataset.cmd, !b.disabled]))")

    def cell_is(st, welded=0, message=""):
        state["cell"] = lambda: cell.cell(st, studs_welded=welded, studs_total=10, unreachable=(), message=message)

    def arm_is(mode, stud="", message="", uncertain=()):
        state["arm"] = lambda: cell.arm(mode, current_stud=stud, done=0, total=0, errors=(), message=message,
                                        uncertain=uncertain)

    banner_shown = "!document.getElementById('safety-banner').hidden"
    alarm = "document.querySelector('#alarms li[data-key=\"{key}\"]')"

    # (1) idle: only Start and E-STOP are valid; the part, drawing and hand-eye in use are shown
    wait_for(lambda: js("location.href + ' ' + document.readyState") == f"{url} complete", 15, spin=ros_node.spin,
             what="page load" + fail())
    cell_is(CellStatus.STATE_IDLE, message="waiting for start")
    arm_is(ArmState.MODE_IDLE)
    until("!document.getElementById('btn-start').disabled", "Start enabled when idle")
    assert buttons() == {"start": True, "pause": False, "resume": False, "stop": False, "estop": True}
    assert js("document.getElementById('btn-pause').title") == "no job is moving (idle)"
    assert js("document.getElementById('part').textContent") == "part Bracket 7-114 · bracket.dxf"
    assert js("document.getElementById('calibration').textContent").startswith(
        "file hand_eye.yaml (2025-04-30, residual 0.31 mm): xyz [0.0, 50.0, 20.0] mm")
    assert js(banner_shown) is False and js("document.querySelector('#alarms li').textContent") == "none"

    # (2) welding: progress counts studs (the sequencer's per-station count says 2), a cycle time and
    #     an estimate to the end; no "uncertain studs" alarm while a stud is being welded
    phases = [(sid, ph) for sid in ids[:6] for ph in ("approach", "weld", "retract")]
    cell.serve_weld_job(phases, WeldJob.Result(welded=ids[:6], success=True, message="6 welded"))
    client = ActionClient(ros_node, WeldJob, "/arm/weld_job")
    wait_for(client.server_is_ready, 10, spin=ros_node.spin, what="weld job server")
    cell_is(CellStatus.STATE_WELDING, welded=2, message="station 1/3: welding 6 stud(s)")
    arm_is(ArmState.MODE_WELDING, stud="S0003")
    until("document.getElementById('btn-pause').disabled === false", "Pause enabled while welding")
    client.send_goal_async(WeldJob.Goal())
    until("document.getElementById('progress-text').textContent.startsWith('6 / 10 studs welded')",
          "six studs welded on the bar")
    assert buttons() == {"start": False, "pause": True, "resume": False, "stop": True, "estop": True}
    assert js("document.getElementById('btn-start').title") == "a job is under way (welding)"
    assert js("document.getElementById('studs-remaining').textContent") == "4"
    until("document.getElementById('cycle').textContent.includes('s/stud')", "a cycle time")
    assert js("document.getElementById('eta').textContent") != "–"
    assert js("document.querySelector('#alarms li').textContent") == "none"

    # (3) e-stop latched: a full-width banner, the badge says so, Start greyed with the reason, alarm A100
    cell_is(CellStatus.STATE_FAILED, welded=6, message="stopped by the operator while waiting for the weld job")
    arm_is(ArmState.MODE_ESTOP, message="e-stop engaged (/arm/estop service)")
    until(banner_shown, "the e-stop banner")
    assert js("document.getElementById('safety-title').textContent") == "E-STOP LATCHED"
    assert js("document.getElementById('safety-banner').getBoundingClientRect().width") >= \
        js("document.documentElement.clientWidth") - 1
    until("document.getElementById('cell-state').textContent === 'E-STOP LATCHED'", "the badge")
    assert buttons() == {"start": False, "pause": False, "resume": False, "stop": False, "estop": True}
    assert js("document.getElementById('btn-start').title") == "e-stop latched"
    key = "A100@rm65_driver"
    until(alarm.format(key=key), "alarm A100")
    assert "unacked" in js(alarm.format(key=key) + ".className")
    assert js("document.querySelectorAll('#alarms li').length") == 1  # the operator's stop is no alarm
    assert "1 new" in js("document.getElementById('alarm-summary').textContent")
    js(alarm.format(key=key) + ".querySelector('button.ack').click()")
    until(alarm.format(key=key) + ".className.includes(' acked')", "A100 acknowledged")
    assert js("document.getElementById('alarm-summary').textContent") == "1 alarm(s)"

    # (4) released: the banner goes, the alarm clears into the history
    arm_is(ArmState.MODE_IDLE, message="e-stop released")
    until("document.getElementById('safety-banner').hidden", "the banner gone")
    until(f"document.querySelector('#alarm-history li[data-key=\"{key}\"]')", "A100 in the history")
    assert js("document.querySelector('#alarms li').textContent") == "none"

    # (5) an arm FAULT (a damaged weld journal) has the banner too
    arm_is(ArmState.MODE_FAULT, message="weld journal FAULT: line 7 damaged (weld jobs refused)")
    until(banner_shown + " && document.getElementById('safety-banner').className === 'banner fault'", "FAULT banner")
    assert "line 7 damaged" in js("document.getElementById('safety-text').textContent")
    assert js("document.getElementById('safety-title').textContent") == "ARM FAULT"

    # (6) an uncertain stud: the decision is a control on the page (two clicks), it reaches /arm/resolve_stud
    cell_is(CellStatus.STATE_DONE, welded=6, message="done")
    arm_is(ArmState.MODE_IDLE, uncertain=("S0007",))
    until("document.querySelector('#uncertain li[data-stud=\"S0007\"]')"
          " && !document.getElementById('decisions').hidden",
          "the uncertain-stud decision")
    until("document.querySelector('#alarms li[data-key=\"A104@rm65_driver\"]')", "alarm A104")
    js("(() => { const b = Array.from(document.querySelectorAll('#uncertain li[data-stud=\"S0007\"] button'))"
       ".find(x => x.textContent === 'Mark as welded'); b.click(); return b.textContent; })()")
    assert cell.resolved == []  # the first click only asks to confirm
    assert js("document.querySelector('#uncertain button.armed').textContent") == "Confirm: S0007 is welded?"
    js("document.querySelector('#uncertain button.armed').click()")
    wait_for(lambda: cell.resolved, 10, spin=ros_node.spin, what="/arm/resolve_stud called" + fail())
    assert cell.resolved == [("S0007", 0)]  # ResolveStud.DECISION_WELDED
    arm_is(ArmState.MODE_IDLE)  # the driver no longer lists it
    until("document.getElementById('decisions').hidden", "the decision panel gone")

    # (7) inspection verdicts in the table; the rework decision on a failed stud reaches the inspector
    cell.inspection({"S0001": ("pass", []), "S0002": ("fail", ["lean 8.0 deg > 5.0"]), "S0003": ("pass", [])})
    row = "document.querySelector('#studs tr[data-stud=\"{sid}\"] td.c-inspection').textContent"
    until(row.format(sid="S0002") + " === 'fail'", "S0002's verdict in the table")
    assert js(row.format(sid="S0001")) == "pass" and js(row.format(sid="S0009")) == ""
    until("document.querySelector('#rework li[data-stud=\"S0002\"]')", "the rework decision for S0002")
    assert "lean 8.0 deg" in js("document.querySelector('#rework li[data-stud=\"S0002\"]').textContent")
    rework_button = ("Array.from(document.querySelectorAll('#rework li[data-stud=\"S0002\"] button'))"
                     ".find(x => x.textContent === 'Rework')")
    # a decision is signed: until the operator gives a name (once per session) its buttons wait for it
    assert js(rework_button + ".disabled") is True
    assert "enter your name" in js("document.getElementById('operator-why').textContent")
    js("(() => { const i = document.getElementById('operator-name'); i.value = 'A. Inspector';"
       " i.dispatchEvent(new Event('input')); })()")
    until("!" + rework_button + ".disabled", "the decision buttons enabled once signed")
    assert js("sessionStorage.getItem('operator')") == "A. Inspector"
    js("(() => { const li = document.querySelector('#rework li[data-stud=\"S0002\"]');"
       " li.querySelector('input.note').value = 'lean checked with a gauge';"
       " const b = Array.from(li.querySelectorAll('button')).find(x => x.textContent === 'Rework');"
       " b.click(); b.click(); })()")
    wait_for(lambda: cell.reworked, 10, spin=ros_node.spin, what="/inspection/record_rework called" + fail())
    assert cell.reworked == [("S0002", "rework", "lean checked with a gauge")] and cell.operators == ["A. Inspector"]
    cell.rework_recorded("S0002", "rework")
    until(row.format(sid="S0002") + " === 'fail → rework'", "the decision in the table")
    until("document.getElementById('decisions').hidden", "no decision pending")

    # (7b) the QA record's bend tests: entered on the page, signed, they reach the inspector
    cell.bend_tests([("S0003", "lot sample (2 of 6 welded)", ""), ("S0001", "pre-production test stud", "pass")])
    until("!document.getElementById('bend-box').hidden"
          " && document.querySelector('#bend-tests li[data-stud=\"S0003\"]')",
          "the bend-test list")
    assert "gb50205" in js("document.getElementById('bend-code').textContent")
    assert "B. Welder" in js("document.querySelector('#bend-tests li[data-stud=\"S0001\"]').textContent")
    js("(() => { const li = document.querySelector('#bend-tests li[data-stud=\"S0003\"]');"
       " li.querySelector('input.angle').value = '32'; li.querySelector('input.note').value = 'no crack';"
       " const b = Array.from(li.querySelectorAll('button')).find(x => x.textContent === 'Pass');"
       " b.click(); b.click(); })()")
    wait_for(lambda: cell.bent, 10, spin=ros_node.spin, what="/inspection/record_bend_test called" + fail())
    assert cell.bent == [("S0003", "pass", 32.0, "no crack", "A. Inspector")]
    until(row.format(sid="S0001") + " === 'pass · bend pass'", "the bend result in the table")

    # (8) a warning a node repeats every second is one alarm, with no count
    for _ in range(20):
        cell.diagnostic("drawing", 1, "2 studs closer than 5 mm")
    until("document.querySelector('#alarms li[data-key=\"A201@drawing\"]')", "the drawing's warning")
    assert js("document.querySelectorAll('#alarms li[data-key=\"A201@drawing\"]').length") == 1
    assert "×" not in js("document.querySelector('#alarms li[data-key=\"A201@drawing\"]').textContent")
    page.close()
    assert ctrl_c(hmi) == 0 and "Traceback" not in hmi.output(), hmi.output()


def test_page_shows_the_inspection_overlay_the_result_names_and_nothing_a_url_names(
        ros_node, procs, tmp_path, browser_factory):
    import cv2
    import numpy as np

    hmi, cell, page, url = start_hmi_and_page(ros_node, procs, tmp_path, browser_factory)
    js = page.evaluate

    def fail() -> str:
        shown = js("document.body ? document.body.innerText : ''")
        return f"\n--- page\n{shown[-1500:]}\n--- hmi\n{hmi.output()[-2000:]}"
    wait_for(lambda: js("location.href + ' ' + document.readyState") == f"{url} complete", 15, spin=ros_node.spin,
             what="page load" + fail())
    assert js("document.getElementById('inspection-empty').textContent") == "no inspection yet (/inspection/result)"

    # the inspector's PNG (a distinctive size: the page must show this very file), outside the page's folder
    shots = tmp_path / "inspection"
    shots.mkdir()
    png = shots / "inspection_station_02_123.png"
    assert cv2.imwrite(str(png), np.full((60, 90, 3), (0, 0, 255), np.uint8))
    (tmp_path / "secret.txt").write_text("not for the browser")
    cell.inspection({"S0001": ("pass", []), "S0002": ("fail", ["lean 8.0 deg > 5.0"])}, station=2, overlay_file=png)
    img = "document.getElementById('inspection-overlay')"
    wait_for(lambda: js(f"{img}.complete && {img}.naturalWidth") == 90, 15, spin=ros_node.spin,
             what="the inspection overlay on the page" + fail())
    assert js(f"{img}.naturalHeight") == 60 and "/inspection/overlay.png?v=" in js(f"{img}.src")
    assert js("document.getElementById('inspection-info').textContent") == "station 2 · inspection_station_02_123.png"

    # from the page: URLs that try to climb to a file beside the overlay get 404, never the file
    def status(u: str) -> list:
        return js("(() => { const x = new XMLHttpRequest(); x.open('GET', " + json.dumps(u) + ", false); x.send();"
                  " return [x.status, x.responseText.includes('not for the browser')]; })()")
    for attempt in ("/inspection/..%2f..%2fsecret.txt", "/inspection/%2e%2e/%2e%2e/secret.txt",
                    "/inspection/overlay.png/..%2f..%2fsecret.txt", "/..%2f..%2fsecret.txt"):
        assert status(attempt) == [404, False], attempt

    # a result naming a file that is no PNG: the old image goes, the page says so, the file is not served
    cell.inspection({"S0001": ("pass", [])}, station=3, overlay_file=tmp_path / "secret.txt")
    wait_for(lambda: (js("document.getElementById('inspection-empty').textContent")
                      == "overlay secret.txt not available"),
             15, spin=ros_node.spin, what="the missing overlay said" + fail())
    assert js(f"{img}.classList.contains('shown')") is False
    assert status("/inspection/overlay.png") == [404, False]
    page.close()
    assert ctrl_c(hmi) == 0 and "Traceback" not in hmi.output(), hmi.output()
