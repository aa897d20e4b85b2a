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

from hmi_testing import ctrl_c, free_port  # noqa: E402
from fake_cell import FakeCell, target  # noqa: E402
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


ROW_JS = """(() => {{ const r = document.querySelector('#studs tr[data-stud="{sid}"]');
  return r ? {{cls: r.className, cells: Array.from(r.children).map(td => td.textContent)}} : null; }})()"""


def test_page_in_headless_chromium_shows_published_targets_and_its_stop_button_reaches_arm_stop(
        ros_node, procs, tmp_path, browser_factory):
    port = free_port()
    hmi = ros2_run("stud_planner", "hmi", tmp_path / "hmi.log", {"port": port})
    procs.append(hmi)
    cell = FakeCell(ros_node)
    cell.wait_for_hmi(port, hmi)
    url = f"http://127.0.0.1:{port}/"
    page = browser_factory(url)
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
