"""The boilerplate every node of the cell shares, in the lowest package (no perception, no planner).

One place for: the QoS profiles of our topics, Pose <-> rotation/translation, stamps, declared-and-
validated parameters (:class:`Param`), /diagnostics, a small stamp synchroniser (message_filters
does not exist in the PyPI wheels) and the ``main()`` of a node (:func:`spin_node`). Images and
camera info are stud_perception.image_io's.
"""
from __future__ import annotations

import gc
import math
import os
import signal
import sys
import threading
import time
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any, Callable, TypeVar

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, Quaternion
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from stud_common import names
from stud_common.rotations import matrix_to_quaternion, quaternion_to_matrix
from stud_common.stacks import dump_stacks_on_signal

# -- QoS ------------------------------------------------------------------------------------------
#: Image/depth/camera-info subscriptions: best effort accepts both best-effort camera drivers
#: and reliable publishers (bag play, our sim camera).
SENSOR_QOS = qos_profile_sensor_data
#: Our own camera publishers: reliable, so a reliable subscriber (an HMI, `ros2 bag record`)
#: gets frames too; a sensor-data subscriber is compatible with it.
CAMERA_PUB_QOS = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE,
                            durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
#: Layouts and registrations: a late subscriber (the HMI, the matcher started later) gets the last one.
LATCHED_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL, history=HistoryPolicy.KEEP_LAST)
#: Results (weld targets, arm state): reliable, a short queue.
RESULT_QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)


class MessageError(ValueError):
    """A message the core cannot use (wrong encoding, size, ...): the text names field and value."""


# -- Poses and stamps ------------------------------------------------------------------------------
def pose_to_rt(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """A Pose -> rotation R (3, 3), translation t (3,) [m]; MessageError for a non-finite value or a zero quaternion."""
    q = pose.orientation
    values = {"position.x": pose.position.x, "position.y": pose.position.y, "position.z": pose.position.z,
              "orientation.x": q.x, "orientation.y": q.y, "orientation.z": q.z, "orientation.w": q.w}
    bad = [f"{k}={v}" for k, v in values.items() if not math.isfinite(v)]
    if bad:
        raise MessageError(f"pose has non-finite values ({', '.join(bad)}); expected finite metres and quaternion")
    try:
        R = quaternion_to_matrix(q.x, q.y, q.z, q.w)
    except ValueError:
        raise MessageError("pose orientation is a zero quaternion") from None
    t = np.array([pose.position.x, pose.position.y, pose.position.z])
    return R, t


def rt_to_pose(R: np.ndarray, t: np.ndarray) -> Pose:
    """Rotation R (3, 3) and translation t (3,) [m] -> a Pose."""
    x, y, z, w = matrix_to_quaternion(R)
    return Pose(position=Point(x=float(t[0]), y=float(t[1]), z=float(t[2])),
                orientation=Quaternion(x=x, y=y, z=z, w=w))


def stamp_to_ns(stamp: Time) -> int:
    """A builtin_interfaces Time -> integer nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    """Integer nanoseconds -> a builtin_interfaces Time."""
    return Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


# -- Parameters -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Param:
    """A node parameter: name, default, description, and an optional range or validator.

    ``validate(value) -> str | None`` returns a reason to reject the value. Numbers (and lists of
    numbers) must be finite whatever the range: NaN compares false with every bound -- unless
    ``nan_means`` says what a NaN stands for (a documented "not set" value, e.g. "the believed
    hand-eye"), in which case NaN is accepted and inf still is not.
    """

    name: str
    default: Any
    description: str
    min: float | None = None
    max: float | None = None
    choices: tuple | None = None
    read_only: bool = False
    validate: Callable[[Any], str | None] | None = None
    nan_means: str | None = None

    def expected(self) -> str:
        """What a valid value looks like, for error messages ("a number in [0.005, 0.3]")."""
        if self.choices is not None:
            return f"one of {list(self.choices)}"
        d = self.default
        kind = ("true or false" if isinstance(d, bool) else "an integer" if isinstance(d, int)
                else "a number" if isinstance(d, float) else "a string" if isinstance(d, str)
                else "a list of numbers" if isinstance(d, (list, tuple)) else type(d).__name__)
        if self.min is not None and self.max is not None:
            return f"{kind} in [{self.min}, {self.max}]"
        if self.min is not None:
            return f"{kind} >= {self.min}"
        if self.max is not None:
            return f"{kind} <= {self.max}"
        return kind

    def check(self, value: Any) -> str | None:
        if self.choices is not None and value not in self.choices:
            return f"{self.name}={value!r}: expected one of {list(self.choices)}"
        numbers = value if isinstance(value, (list, tuple)) else [value]
        allowed = (lambda v: math.isfinite(v) or math.isnan(v)) if self.nan_means else math.isfinite
        if any(isinstance(v, float) and not allowed(v) for v in numbers):
            extra = f" (or NaN: {self.nan_means})" if self.nan_means else ""
            return f"{self.name}={_show(value)}: expected {self.expected()}, finite{extra}"
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            if (self.min is not None and value < self.min) or (self.max is not None and value > self.max):
                return f"{self.name}={value!r}: expected {self.expected()}"
        if self.validate is not None:
            return self.validate(value)
        return None


#: Reliable sensor subscriptions (``sensor_qos: reliable``): nothing is lost on the way, but only
#: a reliable publisher matches -- our camera and shot nodes, ``ros2 bag play``; not a best-effort
#: vendor driver (subscribe to that with the default, or through the shot node).
SENSOR_RELIABLE_QOS = CAMERA_PUB_QOS  # the same profile our camera publishes with


def sensor_qos(choice: str) -> QoSProfile:
    """The QoS of a node's image, depth, camera-info and pose subscriptions: its ``sensor_qos``."""
    return SENSOR_RELIABLE_QOS if choice == "reliable" else SENSOR_QOS


def three_numbers(name: str) -> Callable[[Any], str | None]:
    """A :class:`Param` validator: ``name`` must hold 3 numbers (an x, y, z or a roll, pitch, yaw)."""
    return lambda v: None if v is not None and len(v) == 3 else f"{name} needs 3 numbers, got {list(v or [])}"


#: The ``sensor_qos`` parameter of the nodes that take camera views (:func:`sensor_qos`).
SENSOR_QOS_PARAM = Param("sensor_qos", "best_effort", "image/depth/camera-info/pose subscriptions: best_effort "
                         "(sensor data, matches any publisher; a lost sample is lost) or reliable (nothing lost; "
                         "matches reliable publishers only: our camera and shot nodes, ros2 bag play)",
                         choices=("best_effort", "reliable"), read_only=True)


def _show(value: Any) -> str:
    return repr(list(value)) if isinstance(value, (list, tuple)) else repr(value)


def declare_params(node: Node, params: list[Param], on_change: Callable[[dict], None] | None = None,
                   check: Callable[[dict], str | None] | None = None) -> dict:
    """Declare ``params`` with descriptions and ranges, reject bad values, return the current values.

    At start-up a bad value (out of range, wrong type, non-finite, refused by a validator, or a
    combination ``check(values)`` refuses, e.g. a box whose min is above its max) is logged as one
    line naming the parameter, the value and what is expected, and ends the node with
    ``SystemExit(2)`` -- never a traceback, never a node that starts and fails later. At run time
    the same checks refuse the change through the parameter callback.
    """
    from rclpy.exceptions import (
        InvalidParameterTypeException,
        InvalidParameterValueException,
        ParameterUninitializedException,
    )

    def current(p: Param) -> Any:
        # An empty list (a parameter file's [], -p name:=[]) has no ROS type: rclpy holds it as "not set".
        try:
            value = node.get_parameter(p.name).value
        except ParameterUninitializedException:
            value = None
        return [] if value is None and isinstance(p.default, list) else value

    by_name = {p.name: p for p in params}
    problems = []
    for p in params:
        # an empty list default has no element type (rclpy takes it for bytes): any list may replace it
        desc = ParameterDescriptor(description=p.description, read_only=p.read_only,
                                   dynamic_typing=isinstance(p.default, list) and not p.default)
        # (rclpy's range refuses NaN: a parameter whose NaN means "not set" is range-checked by Param.check alone)
        if p.min is not None and p.max is not None and isinstance(p.default, float) and p.nan_means is None:
            desc.floating_point_range = [FloatingPointRange(from_value=float(p.min), to_value=float(p.max))]
        elif p.min is not None and p.max is not None and isinstance(p.default, int) and not isinstance(p.default, bool):
            desc.integer_range = [IntegerRange(from_value=int(p.min), to_value=int(p.max), step=1)]
        try:
            node.declare_parameter(p.name, p.default, desc)
        except (InvalidParameterValueException, InvalidParameterTypeException) as exc:
            # rclpy refused the override against the range/type: read it back untyped to say what it was
            value = node.declare_parameter(p.name, p.default, ParameterDescriptor(dynamic_typing=True)).value
            wrong_type = isinstance(exc, InvalidParameterTypeException)
            problems.append(f"{p.name}={_show(value)}"
                            + (f" ({type(value).__name__})" if wrong_type else "") + f": expected {p.expected()}")
    values = {p.name: current(p) for p in params}
    problems += [r for p in params if not any(x.startswith(p.name + "=") for x in problems)
                 and (r := p.check(values[p.name]))]
    if not problems and check is not None:
        problems += [r for r in [check(values)] if r]
    if problems:
        for r in problems:
            node.get_logger().fatal(f"bad parameter {r}")
        raise SystemExit(2)

    def _callback(changes) -> SetParametersResult:
        update = {}
        for change in changes:
            spec = by_name.get(change.name)
            if spec is None:
                continue
            reason = spec.check(change.value)
            if reason:
                node.get_logger().warn(f"rejected parameter {reason}")
                return SetParametersResult(successful=False, reason=reason)
            update[change.name] = change.value
        if update and check is not None:
            reason = check({**values, **update})
            if reason:
                node.get_logger().warn(f"rejected parameters {reason}")
                return SetParametersResult(successful=False, reason=reason)
        values.update(update)
        if update and on_change is not None:
            on_change(update)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(_callback)
    return values


# -- Diagnostics ------------------------------------------------------------------------------------
class Diagnostics:
    """Publishes one DiagnosticStatus for this node on /diagnostics (call :meth:`publish` from a timer)."""

    OK, WARN, ERROR, STALE = DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR, DiagnosticStatus.STALE

    def __init__(self, node: Node, name: str | None = None, hardware_id: str = ""):
        self._node = node
        self._pub = node.create_publisher(DiagnosticArray, names.DIAGNOSTICS, 10)
        self.name = name or f"{node.get_name()}"
        self.hardware_id = hardware_id
        self.level = DiagnosticStatus.OK
        self.message = "starting"
        self.values: dict[str, str] = {}

    def set(self, level: int, message: str, **values: Any) -> None:
        self.level, self.message = level, message
        self.values.update({k: str(v) for k, v in values.items()})

    def publish(self) -> None:
        status = DiagnosticStatus(level=self.level, name=self.name, message=self.message,
                                  hardware_id=self.hardware_id,
                                  values=[KeyValue(key=k, value=v) for k, v in self.values.items()])
        arr = DiagnosticArray(status=[status])
        arr.header.stamp = self._node.get_clock().now().to_msg()
        self._pub.publish(arr)


# -- Stamp synchroniser ----------------------------------------------------------------------------
class StampSync:
    """Pairs messages of several streams that carry the same header stamp (within ``slop_ns``).

    Our camera publishes colour, depth, camera info and pose with one shared stamp (one
    triggered shot); a real driver's streams may differ by a little, hence the slop. Calls
    ``callback(dict name -> msg)`` once per complete set. An incomplete set is dropped when a
    newer set completes, or when more than ``max_sets`` newer ones wait; ``on_drop(stamp_ns,
    missing names)`` hears of each (a view lost on the way: a best-effort sample, a stream that
    stopped), and ``dropped`` counts them.
    """

    def __init__(self, names: list[str], callback: Callable[[dict], None], slop_ns: int = 0, max_sets: int = 10,
                 on_drop: Callable[[int, list[str]], None] | None = None):
        self.names = list(names)
        self.callback = callback
        self.slop_ns = slop_ns
        self.max_sets = max_sets
        self.on_drop = on_drop
        self.dropped = 0
        self._sets: OrderedDict[int, dict] = OrderedDict()

    def add(self, name: str, msg: Any) -> None:
        stamp = stamp_to_ns(msg.header.stamp)
        key = next((k for k in self._sets if abs(k - stamp) <= self.slop_ns), stamp)
        entry = self._sets.setdefault(key, {})
        entry[name] = msg
        if len(entry) == len(self.names):
            del self._sets[key]
            for older in [k for k in self._sets if k < key]:  # a newer complete set supersedes them
                self._drop(older, self._sets.pop(older))
            self.callback(entry)
        while len(self._sets) > self.max_sets:
            self._drop(*self._sets.popitem(last=False))

    def _drop(self, stamp_ns: int, entry: dict) -> None:
        self.dropped += 1
        if self.on_drop is not None:
            self.on_drop(stamp_ns, [n for n in self.names if n not in entry])


def warn_dropped(node: Node, what: str = "view") -> Callable[[int, list[str]], None]:
    """A :class:`StampSync` ``on_drop`` that says so in the node's log (at most every 5 s)."""
    def on_drop(stamp_ns: int, missing: list[str]) -> None:
        node.get_logger().warn(f"dropped an incomplete {what} stamped {stamp_ns * 1e-9:.3f} s: its "
                               f"{', '.join(missing)} never arrived (a lost best-effort sample, or a stream that "
                               "stopped)", throttle_duration_sec=5.0)
    return on_drop


def keep_freed_memory(max_block_bytes: int = 32 << 20) -> bool:
    """Tell glibc's allocator to serve blocks up to ``max_block_bytes`` from the heap and keep freed
    memory instead of returning it to the kernel.

    Every frame allocates and frees image-sized arrays (depth in metres, window point clouds: 1-10
    MB). By default glibc maps each with mmap and unmaps it on free, so every frame touches fresh
    pages: thousands of page faults per frame, which on a virtual machine cost as much as the
    matching itself (bench/RESULTS.md, *Latency*). The price is that the process keeps its peak heap.
    Returns False where there is no glibc or it refuses a setting.
    """
    import ctypes

    M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD = -1, -2, -3
    try:
        mallopt = ctypes.CDLL("libc.so.6").mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(M_MMAP_THRESHOLD, int(max_block_bytes)) and mallopt(M_TRIM_THRESHOLD, 1 << 30)
                and mallopt(M_TOP_PAD, 64 << 20))


AnyNode = TypeVar("AnyNode", bound=Node)


#: Longest wait of a node's executor for work (s): how late an idle node notices a shutdown.
SPIN_WAKE_S = 0.1


#: Set by the first SIGINT or SIGTERM of a node process set up by :func:`init_node_process`: its
#: spin loop (:func:`spin_until_shutdown`) ends at its next turn.
STOP_REQUESTED = threading.Event()


def init_node_process(args: list[str] | None = None) -> None:
    """``rclpy.init`` for a node's own process, with our SIGINT/SIGTERM handlers instead of rclpy's.

    rclpy's handler shuts the context down from its signal thread while the executor may be in the
    middle of taking a message: the take then raises (RuntimeError "Unable to convert call argument")
    or crashes the process (SIGSEGV), and the launch reports the node FAILED after a job that went
    well. Ours only asks the spin loop
    to end; it ends between turns and the node is torn down in order, its context still valid.
    Further SIGINTs (Ctrl-C pressed twice) are ignored from then on: the teardown is bounded anyway
    (:func:`teardown_within`). A second SIGTERM (the launcher escalating, the teardown stuck) ends
    the process at once."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    STOP_REQUESTED.clear()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _request_stop)


def _request_stop(signum: int, _frame) -> None:
    if signum == signal.SIGTERM and STOP_REQUESTED.is_set():
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        os.kill(os.getpid(), signal.SIGTERM)
        return
    # SIG_IGN, not this handler: Python's finalisation puts a Python handler back to SIG_DFL, and a
    # second Ctrl-C would then kill the process as it exits (code 130 instead of its own)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    STOP_REQUESTED.set()


def spin_until_shutdown(executor_or_node, until: Callable[[], int | None] | None = None) -> int | None:
    """``rclpy.spin`` without its unbounded wait: spin until the context shuts down or a stop is
    requested (:data:`STOP_REQUESTED`; returns None), or until ``until()`` returns a value (returned).

    On SIGINT rclpy's signal thread wakes the executors first and shuts the context down after
    (rclpy signal_handler.cpp, Jazzy and later). An executor that looks in between finds the
    context still valid and waits again -- in ``rclpy.spin``, for ever if the node is idle (no
    timer, nothing arriving): the node never stops. Waiting at most :data:`SPIN_WAKE_S` at a time,
    the next turn sees the shutdown."""
    import rclpy
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor

    executor = executor_or_node
    if isinstance(executor_or_node, Node):
        executor = SingleThreadedExecutor(context=executor_or_node.context)
        executor.add_node(executor_or_node)
    try:
        while rclpy.ok(context=executor.context) and not STOP_REQUESTED.is_set():
            executor.spin_once(timeout_sec=SPIN_WAKE_S)
            done = until() if until is not None else None
            if done is not None:
                return done
    except ExternalShutdownException:  # the shutdown, seen from inside a wait
        pass
    return None


def spin_node(node_factory: Callable[[], AnyNode], args: list[str] | None = None, multithreaded: bool = False,
              until: Callable[[AnyNode], int | None] | None = None) -> int:
    """`main()` body shared by our nodes: init, spin (``multithreaded`` for nodes whose service
    callbacks wait on their own subscriptions), clean shutdown on Ctrl-C (no traceback).

    ``until(node)``: the exit code once the node is done (None: not yet), checked every
    :data:`SPIN_WAKE_S` at least.
    A node with a ``shutdown()`` method has it called before its callbacks are drained."""
    import rclpy
    from rclpy.executors import Executor, ExternalShutdownException, MultiThreadedExecutor, SingleThreadedExecutor

    keep_freed_memory()
    dump_stacks_on_signal()
    init_node_process(args if args is not None else sys.argv)
    node = None
    executor: Executor | None = None
    code = 0
    try:
        node = node_factory()
        # Everything built so far (modules, the node) lives as long as the process: move it out of
        # the collector's sight, so a full collection -- triggered at random while a callback
        # allocates messages -- does not walk a few hundred thousand objects (tens of ms).
        gc.freeze()
        executor = MultiThreadedExecutor(num_threads=4) if multithreaded else SingleThreadedExecutor()
        executor.add_node(node)
        done = spin_until_shutdown(executor, None if until is None else lambda: until(node))
        code = done if done is not None else 0
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except SystemExit as exc:
        code = int(exc.code or 0)
    except RuntimeError:
        # Ctrl-C shuts the context down under a take in progress (a large image arriving):
        # rclpy then raises from the middle of it. That is a shutdown, not a failure.
        if rclpy.ok():
            raise
    finally:
        shutdown = getattr(node, "shutdown", None)
        if callable(shutdown):
            shutdown()
        if executor is not None:
            drain_executor(executor)
        steps = [node.destroy_node] if node is not None else []
        steps.append(lambda: rclpy.try_shutdown() if rclpy.ok() else None)
        teardown_within(TEARDOWN_TIMEOUT_S, 1 if sys.exc_info()[0] is not None else code, steps)
    return code


#: Longest wait for a node's teardown (``destroy_node``, rclpy's shutdown) once its own ``shutdown()``
#: and its callbacks are done (the executor's drain takes up to 3 s before it); with the backstop's
#: second, well within the launcher's 10 s SIGINT grace period.
TEARDOWN_TIMEOUT_S = 3.0
#: The backstop's SIGTERM comes this long after the teardown's own timeout.
TEARDOWN_BACKSTOP_S = 1.0


def teardown_within(timeout_s: float, code: int, steps: list[Callable[[], object]]) -> None:
    """Run ``steps``; if they are still running after ``timeout_s``, end the process with ``code``.

    ``destroy_node`` of an idle node can fail to return after Ctrl-C (inside rclpy's node
    destruction, the DDS participant's teardown); the launcher then kills the node and the cell
    reports a failure. Everything the node owes is done before its teardown (its
    ``shutdown()`` hook, its callbacks drained; journal records are synced as they are written), so
    leaving then loses nothing, and the process stops as asked.

    The timer is Python and needs the GIL, which a hang inside a C call may hold: the node then
    outlives the timer and the launcher's grace period both. A backstop
    process therefore sends SIGTERM ``TEARDOWN_BACKSTOP_S`` later, SIGTERM's default action
    restored: the kernel ends the process, no Python code needs to run, and the launcher counts
    a SIGTERM as a clean stop."""
    import os
    import threading

    backstop = _sigterm_backstop(timeout_s + TEARDOWN_BACKSTOP_S)

    def give_up() -> None:
        sys.stderr.write(f"node teardown still running after {timeout_s:g} s (the middleware's node "
                         f"destruction); exiting with code {code}\n")
        sys.stderr.flush()
        sys.stdout.flush()
        _end_backstop(backstop)
        os._exit(code)

    timer = threading.Timer(timeout_s, give_up)
    timer.daemon = True
    timer.start()
    try:
        for step in steps:
            step()
    finally:
        timer.cancel()
        _end_backstop(backstop)


def _sigterm_backstop(after_s: float):
    """A process (its own session) that sends this one SIGTERM after ``after_s``, SIGTERM's default
    action (end the process) restored here first; None where that cannot be set up."""
    import os
    import signal
    import subprocess

    try:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)
        return subprocess.Popen(["/bin/sh", "-c", f"sleep {after_s:.3f} && kill -TERM {os.getpid()}"],
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
    except (OSError, ValueError):  # no /bin/sh, or not the main thread: the timer alone
        return None


def _end_backstop(backstop) -> None:
    """Stop the backstop (its shell and its sleep) before it fires."""
    import os
    import signal
    import subprocess

    if backstop is None:
        return
    try:
        os.killpg(backstop.pid, signal.SIGKILL)
        backstop.wait(timeout=1.0)
    except (OSError, subprocess.TimeoutExpired):  # gone already, or not reaped in time: it cannot fire
        pass


def drain_executor(executor, timeout_s: float = 3.0) -> None:
    """Let a multi-threaded executor's running callbacks finish before the node is destroyed: a
    callback still converting an image when its subscription is freed crashes the process (SIGSEGV
    at Ctrl-C). rclpy's MultiThreadedExecutor.shutdown() does not wait for its thread pool (Jazzy),
    so its pool is stopped here: queued callbacks cancelled, running ones given ``timeout_s``."""
    executor.shutdown(timeout_sec=0)
    pool = getattr(executor, "_executor", None)  # rclpy's ThreadPoolExecutor (not public API)
    if pool is None:
        return
    pool.shutdown(wait=False, cancel_futures=True)
    deadline = time.monotonic() + timeout_s
    for thread in list(getattr(pool, "_threads", ())):
        thread.join(max(0.0, deadline - time.monotonic()))
