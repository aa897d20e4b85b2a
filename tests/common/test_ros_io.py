"""ros_io's process set-up for nodes: the allocator keeps freed image-sized blocks (no page faults
on every frame's fresh arrays)."""
from __future__ import annotations

import subprocess
import sys
import time

import pytest

from rosproc import REPO

_PROBE = """
import sys
sys.path.insert(0, {src!r})
import numpy as np
from stud_common import ros_io
ok = ros_io.keep_freed_memory() if {tune} else None

def rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 2**20

before = rss_mb()
block = np.ones(20 * 2**20, dtype=np.uint8)  # a 20 MB frame-sized array, every page touched
del block
print(ok, rss_mb() - before)
"""


def _run(tune: bool) -> tuple[str, float]:
    code = _PROBE.format(src=str(REPO / "src" / "stud_common"), tune=tune)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    ok, kept_mb = out.stdout.split()
    return ok, float(kept_mb)


def test_keep_freed_memory_keeps_a_freed_frame_in_the_process():
    ok, kept_mb = _run(tune=True)
    assert ok == "True"
    assert kept_mb >= 18  # freed, but kept for the next frame: no fresh pages to fault in
    _, default_kept_mb = _run(tune=False)
    assert default_kept_mb < 5  # glibc's default: unmapped on free, faulted in again next time


def test_color_to_bgr_takes_8_bit_images_only():
    import numpy as np
    import pytest

    sys.path.insert(0, str(REPO / "src" / "stud_perception"))
    from stud_common import ros_io
    from stud_perception import image_io

    grey = np.arange(12, dtype=np.uint8).reshape(3, 4)
    bgr = image_io.color_to_bgr(image_io.numpy_to_image(grey, "mono8"))
    assert bgr.shape == (3, 4, 3) and (bgr[:, :, 2] == grey).all()
    for encoding, dtype in (("16UC1", np.uint16), ("mono16", np.uint16), ("32FC1", np.float32)):
        msg = image_io.numpy_to_image(grey.astype(dtype), encoding)
        with pytest.raises(ros_io.MessageError, match=f"colour image encoding '{encoding}' is not supported"):
            image_io.color_to_bgr(msg)


def test_pose_with_a_non_finite_value_is_a_message_error():
    import numpy as np
    import pytest
    from geometry_msgs.msg import Pose

    sys.path.insert(0, str(REPO / "src" / "stud_perception"))
    from stud_common import ros_io

    pose = Pose()
    pose.orientation.w = 1.0
    R, t = ros_io.pose_to_rt(pose)
    assert np.allclose(R, np.eye(3)) and not t.any()
    pose.orientation.z = float("inf")
    with pytest.raises(ros_io.MessageError, match=r"non-finite values \(orientation.z=inf\)"):
        ros_io.pose_to_rt(pose)


def test_raw_images_are_rectified_and_rectified_ones_use_p():
    from geometry_msgs.msg import Pose
    from sensor_msgs.msg import CameraInfo

    from stud_common import ros_io
    from stud_perception import image_io

    K = [800.0, 0.0, 320.0, 0.0, 800.0, 240.0, 0.0, 0.0, 1.0]
    P = [700.0, 0.0, 330.0, 0.0, 0.0, 700.0, 250.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    info = CameraInfo(width=640, height=480, distortion_model="plumb_bob", d=[0.0] * 5, k=K, p=P)
    assert image_io.camera_rectifier(info) is None  # a pinhole camera: nothing to do
    info.d = [0.02, -0.11, 0.0, 0.0, 0.0]
    rect = image_io.camera_rectifier(info)
    assert rect is not None and rect.D.tolist() == list(info.d) and (rect.width, rect.height) == (640, 480)
    assert "model 'plumb_bob', largest d[1] = -0.11" in image_io.rectification_note(info)
    pose = Pose()
    pose.orientation.w = 1.0
    assert image_io.camera_model_from_msgs(info, pose).K[0, 0] == 800.0  # raw images: K
    # image_rect topics: the rectified projection P, and no second rectification
    assert image_io.camera_rectifier(info, images_rectified=True) is None
    assert image_io.camera_model_from_msgs(info, pose, images_rectified=True).K.tolist() == [
        [700.0, 0.0, 330.0], [0.0, 700.0, 250.0], [0.0, 0.0, 1.0]]
    info.p = [0.0] * 12
    with pytest.raises(ros_io.MessageError, match=r"camera_info P has fx=0.0, fy=0.0: rectified images need"):
        image_io.camera_model_from_msgs(info, pose, images_rectified=True)
    info.distortion_model = "kannala_brandt"
    with pytest.raises(ValueError, match=r"distortion model 'kannala_brandt' is not supported"):
        image_io.camera_rectifier(info)


# -- spinning until a shutdown ------------------------------------------------------------------
_IDLE_NODE = """
import sys, threading, time
sys.path.insert(0, {src!r})
import rclpy
from rclpy.node import Node
from std_msgs.msg import String
from stud_common import ros_io

rclpy.init()
node = Node("idle_probe")  # no timer, and nothing is published on its topic: idle
node.create_subscription(String, "/nobody_publishes_this", lambda _m: None, 10)
# What rclpy's signal thread does on SIGINT once it has woken the executors: rcl_shutdown, which
# wakes no one (the Python context's on_shutdown callbacks are not called).
threading.Timer(0.5, node.context.handle.shutdown).start()
t0 = time.monotonic()
if {bounded}:
    ros_io.spin_until_shutdown(node)
else:
    rclpy.spin(node)
print(f"returned after {{time.monotonic() - t0:.2f}} s", flush=True)
"""


@pytest.mark.parametrize("bounded", [True, False], ids=["spin_until_shutdown", "rclpy.spin"])
def test_an_idle_node_notices_a_shutdown_that_wakes_no_one(bounded):
    """The rare Ctrl-C hang of idle nodes: rclpy.spin waits for ever once the context is shut
    down behind its back; spin_until_shutdown (and so every node's spin_node) notices it within
    SPIN_WAKE_S."""
    code = _IDLE_NODE.format(src=str(REPO / "src" / "stud_common"), bounded=bounded)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        out, _ = proc.communicate(timeout=5.0 if bounded else 3.0)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        assert not bounded, f"spin_until_shutdown did not return: {out}"
        return  # rclpy.spin: still waiting after 2.5 s -- the hazard is real
    assert bounded, f"rclpy.spin returned after a shutdown that woke no one; the guard may be obsolete: {out}"
    seconds = float(out.split("returned after ")[1].split()[0])
    assert 0.5 <= seconds < 0.5 + 0.1 + 1.0, out


def test_stamp_sync_says_which_views_it_drops_and_what_they_lacked():
    from types import SimpleNamespace

    from builtin_interfaces.msg import Time

    from stud_common import ros_io

    def msg(sec):
        return SimpleNamespace(header=SimpleNamespace(stamp=Time(sec=sec)))

    views, drops = [], []
    sync = ros_io.StampSync(["depth", "info", "pose"], views.append, max_sets=2,
                            on_drop=lambda stamp, missing: drops.append((stamp // 10**9, missing)))
    sync.add("depth", msg(1))
    sync.add("info", msg(1))  # view 1 waits for its pose ...
    for name in ("depth", "info", "pose"):
        sync.add(name, msg(2))  # ... and view 2 completes first: view 1 is given up
    assert len(views) == 1 and drops == [(1, ["pose"])]
    for sec in (3, 4, 5):  # three views that only ever get a depth: the oldest beyond max_sets goes
        sync.add("depth", msg(sec))
    assert drops[-1] == (3, ["info", "pose"]) and sync.dropped == 2


_HANGING_TEARDOWN = """
import sys, threading, time
sys.path.insert(0, {src!r})
import rclpy
from rclpy.node import Node
from stud_common import ros_io
ros_io.TEARDOWN_TIMEOUT_S = 1.0

class Stuck(Node):
    def __init__(self):
        super().__init__("stuck_teardown")
        self.create_timer(0.05, lambda: None)
    def destroy_node(self):  # as the middleware's node destruction once did after Ctrl-C
        print("destroying", flush=True)
        threading.Event().wait()

t0 = time.monotonic()
threading.Timer(0.3, lambda: rclpy.try_shutdown()).start()
sys.exit(ros_io.spin_node(Stuck, [], until=lambda node: 3 if time.monotonic() - t0 > 0.2 else None))
"""


def test_a_node_whose_teardown_hangs_still_ends_with_its_exit_code():
    code = _HANGING_TEARDOWN.format(src=str(REPO / "src" / "stud_common"))
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=20)
    elapsed = time.monotonic() - t0
    assert "destroying" in proc.stdout, proc.stdout + proc.stderr
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert "node teardown still running after 1 s" in proc.stderr
    assert elapsed < 10.0  # well within the launcher's grace period: no SIGKILL, no failure reported


_GIL_HOLDING_TEARDOWN = _HANGING_TEARDOWN.replace(
    """        threading.Event().wait()""",
    """        import re
        re.match(r"(a+)+$", "a" * 64 + "b")  # catastrophic backtracking: C code that holds the GIL for ages""")


def test_a_teardown_that_hangs_holding_the_gil_is_ended_by_the_backstop_as_a_clean_stop():
    """The hang seen in CI: destroy_node stuck in a C call that holds the GIL, so the Python timer
    never ran and the launcher killed the node after its grace period. The backstop's SIGTERM ends it
    in time, and the launcher counts a SIGTERM as a clean stop."""
    import signal

    from stud_bringup.launcher import _CLEAN_STOP_CODES

    code = _GIL_HOLDING_TEARDOWN.format(src=str(REPO / "src" / "stud_common"))
    t0 = time.monotonic()
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=30)
    elapsed = time.monotonic() - t0
    assert "destroying" in proc.stdout, proc.stdout + proc.stderr
    assert proc.returncode == -signal.SIGTERM, proc.stdout + proc.stderr
    assert proc.returncode in _CLEAN_STOP_CODES
    assert "node teardown still running" not in proc.stderr  # the timer could not run: the backstop did it
    assert elapsed < 8.0


_BUSY_NODE = """
import sys, time
sys.path.insert(0, {src!r})
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import Image
from stud_common import ros_io

class Busy(Node):
    '''Takes a 0.6 MB image every 2 ms (the takes rclpy's own handler used to break into), and
    stops slowly: its shutdown() takes 0.5 s, as the driver's does halting a job.'''
    def __init__(self):
        super().__init__("busy_probe")
        self.pub = self.create_publisher(Image, "/busy_probe", 5)
        self.create_subscription(Image, "/busy_probe", lambda m: None, 5)
        self.msg = Image(height=480, width=640, encoding="16UC1", step=1280, data=bytes(640 * 480 * 2))
        self.create_timer(0.002, lambda: self.pub.publish(self.msg))
        print("ready", flush=True)
    def shutdown(self):
        time.sleep(0.5)
        print("shut down", flush=True)

sys.exit(ros_io.spin_node(Busy, []))
"""


def test_ctrl_c_pressed_twice_stops_a_busy_node_in_order_with_exit_code_0():
    """SIGINT ends the spin between turns (never under a take) and the node's shutdown() runs to its
    end; a second SIGINT during it is ignored. With rclpy's own handler the second one raised
    KeyboardInterrupt in the middle of the shutdown: a traceback and a failed node."""
    import signal

    code = _BUSY_NODE.format(src=str(REPO / "src" / "stud_common"))
    for _ in range(3):
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True)
        try:
            assert proc.stdout is not None and proc.stdout.readline().strip() == "ready"
            time.sleep(0.3)
            proc.send_signal(signal.SIGINT)
            time.sleep(0.2)  # inside shutdown()
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=15)
        finally:
            proc.kill()
        assert proc.returncode == 0 and "Traceback" not in err, (proc.returncode, err[-2000:])
        assert "shut down" in out, out
