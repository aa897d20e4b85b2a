"""A loopback simulator of the RM-65 controller's JSON-over-TCP interface.

Speaks the protocol of RM65_PROTOCOL.md well enough for our driver *and* the official SDK
(robotic-arm 1.1.6) to connect: ``\\r\\n`` framing (pretty-printed requests tolerated), the
eleven connect-time queries of §1.11, ``movej`` / ``movej_p`` / ``movel`` with the
acknowledgement followed by the ``current_trajectory_state`` arrival message, stop / slow stop
/ pause / continue, tool and work frames, controller and tool-flange IO, arm state in the
current (``err`` list) or the older error formats.

The arm moves in (scaled) real time: a joint move lasts as long as the slowest joint needs at
``v`` % of its maximum speed, a linear move as long as the path needs at ``v`` % of the line
speed; ``time_scale`` multiplies every duration (0.02 makes tests 50x faster). Targets outside
the joint limits are refused with ``receive_state:false`` and error 0x1002 in the state,
unreachable poses with 0x1003 (the exact channel is [UNCERTAIN] in the docs; this is the one
the official SDK reports as "refused", §3). Numbers no arm can reach -- non-finite, too large for
a float, a flange beyond the working sphere -- are refused the same way at once, before any IK.

For tests: every received command is recorded with its arrival time (``commands``), every
digital-output change with the tool pose at that instant (``do_events``,
:meth:`rising_edges`), and faults can be injected (:meth:`drop_connections`,
:meth:`drop_after_commands`, :meth:`drop_mid_motion`, :meth:`refuse_connections`,
:meth:`fail_next`, :meth:`stall_next_motion`, :meth:`set_error`).

Run stand-alone: ``python -m rm65_driver.simulator --port 8080`` (binds 127.0.0.1 unless told
otherwise). Usage from pytest::

    sim = ArmSimulator(port=0, time_scale=0.02); sim.start(); ... sim.port ...; sim.stop()
"""
from __future__ import annotations

import argparse
import collections
import logging
import signal
import socket
import struct
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from . import protocol as P
from .kinematics import (
    JOINT_MAX_SPEED_DEG_S,
    DHModel,
    RM65Kinematics,
    invert_transform,
    matrix_to_pose6,
    pose6_to_matrix,
    rotation_angle,
)

_log = logging.getLogger(__name__)

#: Controller IO (Gen-3: four multiplexed DI/DO) and tool-flange IO (two), §1.8.
N_IO = 4
N_TOOL_IO = 2
MAX_QUEUED_MOTIONS = 10  # Gen-2 buffers 10 points (DOCS-FAQ); plenty for the driver


@dataclass(frozen=True)
class CommandRecord:
    """A command as received: ``t`` is ``time.monotonic()`` when its frame was decoded."""

    t: float
    conn_id: int
    msg: dict[str, Any]

    @property
    def name(self) -> str:
        return str(self.msg.get("command", ""))


@dataclass(frozen=True)
class DOEvent:
    """A digital-output level change. ``tcp_pose`` (4x4, m) is the tool in the work frame, then."""

    t: float
    io: int
    tool: bool
    value: int
    joints_rad: np.ndarray
    tcp_pose: np.ndarray

    @property
    def position(self) -> np.ndarray:
        return self.tcp_pose[:3, 3]


@dataclass
class _Motion:
    kind: str  # "movej" | "movel" | "movej_p"
    path: np.ndarray  # (N, 6) joint waypoints, rad
    duration_s: float  # simulated seconds (before time_scale)
    conn_id: int
    elapsed_s: float = 0.0  # simulated seconds done
    stall_at: float | None = None  # fraction where it freezes, never arriving
    fail_at: float | None = None  # fraction where it aborts with trajectory_state false
    fail_code: int = 0
    drop_at: float | None = None  # fraction where the commanding connection is dropped
    released_at: float | None = None  # monotonic time the acknowledgement was on the wire

    @property
    def released(self) -> bool:  # ack always precedes motion and arrival
        return self.released_at is not None

    def release(self) -> None:
        self.released_at = time.monotonic()

    def fraction(self) -> float:
        return 1.0 if self.duration_s <= 0 else min(1.0, self.elapsed_s / self.duration_s)

    def joints_at(self, fraction: float) -> np.ndarray:
        s = 3 * fraction**2 - 2 * fraction**3  # smooth start and stop
        n = len(self.path) - 1
        if n == 0:
            return self.path[0].copy()
        x = s * n
        i = min(int(x), n - 1)
        return self.path[i] + (x - i) * (self.path[i + 1] - self.path[i])


class _Conn:
    def __init__(self, conn_id: int, sock: socket.socket, peer: Any):
        self.id = conn_id
        self.sock = sock
        self.peer = peer
        self.send_lock = threading.Lock()
        self.decoder = P.FrameDecoder()
        self.alive = True

    def send(self, msg: dict[str, Any], pretty: bool) -> None:
        data = P.encode(msg, pretty=pretty)
        with self.send_lock:
            if not self.alive:
                return
            try:
                self.sock.sendall(data)
            except OSError:
                self.alive = False

    def close(self) -> None:
        self.alive = False
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        try:
            self.sock.close()
        except OSError:
            pass


@dataclass
class _Fault:
    command: str | None
    remaining: int
    action: str
    code: int = 0
    fraction: float = 0.5

    def matches(self, name: str) -> bool:
        return self.command is None or self.command == name


class ArmSimulator:
    """Threaded TCP controller simulator (see the module docstring).

    ``err_format``: ``"list"`` (current firmware, what the SDK needs), ``"scalar"`` or
    ``"arm_sys"`` (older documented formats). ``strict_io_mode``: ``set_DO_state`` is refused
    unless the IO was switched to output mode first (Gen-3 behaviour, [INFERRED]).
    ``keep_moving_on_disconnect``: a dropped TCP connection does not stop a planned motion
    (what a controller executing its own trajectory does; [UNCERTAIN] on hardware).
    ``min_motion_real_s``: floor on a motion's wall-clock duration, whatever ``time_scale``.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = P.DEFAULT_PORT,
        time_scale: float = 1.0,
        err_format: str = "list",
        pretty_replies: bool = False,
        d6_m: float = 0.144,
        initial_joints_deg: Sequence[float] = (0.0, 0.0, 90.0, 0.0, 90.0, 0.0),
        tick_s: float = 0.002,
        max_line_speed_m_s: float = 0.5,
        max_angular_speed_rad_s: float = 3.0,
        stop_reports_trajectory: bool = True,
        strict_io_mode: bool = True,
        keep_moving_on_disconnect: bool = True,
        product_version: str = "RM65-BI",
        min_motion_real_s: float = 0.01,
    ):
        if err_format not in ("list", "scalar", "arm_sys"):
            raise ValueError(f"err_format {err_format!r}: expected list, scalar or arm_sys")
        self.host = host
        self._requested_port = int(port)
        self.time_scale = float(time_scale)
        self.err_format = err_format
        self.pretty_replies = pretty_replies
        self.kin = RM65Kinematics(dh=DHModel.rm65(d6_m))
        self.tick_s = tick_s
        self.max_line_speed_m_s = max_line_speed_m_s
        self.max_angular_speed_rad_s = max_angular_speed_rad_s
        self.stop_reports_trajectory = stop_reports_trajectory
        self.strict_io_mode = strict_io_mode
        self.keep_moving_on_disconnect = keep_moving_on_disconnect
        self.product_version = product_version
        # No real trajectory ends within milliseconds of its acknowledgement; the official SDK's
        # single-thread mode misses an arrival message that shares a TCP read with the ack.
        self.min_motion_real_s = min_motion_real_s

        self._lock = threading.RLock()
        self._joints = np.radians(np.asarray(initial_joints_deg, dtype=np.float64))
        self._queue: collections.deque[_Motion] = collections.deque()
        self._paused = False
        self._errors: list[int] = []
        self._tool_frames: dict[str, tuple[np.ndarray, int, list[int]]] = {"Arm_Tip": (np.zeros(6), 0, [0, 0, 0])}
        self._work_frames: dict[str, np.ndarray] = {"Base": np.zeros(6), "World": np.zeros(6)}
        self._tool_name = "Arm_Tip"
        self._work_name = "Base"
        self._io_mode = [0] * N_IO
        self._do = [0] * N_IO
        self._tool_io_mode = [0] * N_TOOL_IO
        self._tool_do = [0] * N_TOOL_IO
        self._tool_voltage = 0
        self._realtime_push = {"cycle": 1, "enable": False, "port": 8089, "ip": "127.0.0.1", "force_coordinate": 0}
        self._power = 1

        self.commands: list[CommandRecord] = []
        self.do_events: list[DOEvent] = []
        self.motion_log: list[tuple[str, np.ndarray]] = []  # accepted motions: (kind, final joints)
        self._faults: list[_Fault] = []
        self._refuse = 0  # connections still to refuse; -1: all
        self._conns: dict[int, _Conn] = {}
        self._next_conn_id = 1
        self.connection_count = 0

        self._server: socket.socket | None = None
        self._bound_port: int | None = None
        self._threads: list[threading.Thread] = []
        self._running = threading.Event()
        self._changed = threading.Condition(self._lock)

    # ------------------------------------------------------------------------------------
    # life cycle
    # ------------------------------------------------------------------------------------
    def start(self) -> "ArmSimulator":
        if self._running.is_set():
            return self
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind((self.host, self._requested_port))
        # A short backlog drops the SYNs of a burst of clients, which then retry after 1, 3, 7 s...
        srv.listen(socket.SOMAXCONN)
        srv.settimeout(0.05)
        self._server = srv
        self._bound_port = srv.getsockname()[1]
        self._running.set()
        for target, name in ((self._accept_loop, "sim-accept"), (self._motion_loop, "sim-motion")):
            t = threading.Thread(target=target, name=name, daemon=True)
            t.start()
            self._threads.append(t)
        _log.info("RM65 simulator listening on %s:%d", self.host, self.port)
        return self

    def stop(self) -> None:
        if not self._running.is_set():
            return
        self._running.clear()
        if self._server is not None:
            self._server.close()
        with self._lock:
            conns = list(self._conns.values())
        for c in conns:
            c.close()
        for t in self._threads:
            t.join(timeout=2.0)
        self._threads.clear()

    def __enter__(self) -> "ArmSimulator":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    @property
    def port(self) -> int:
        """The bound port (also after :meth:`stop`: a restarted controller binds it again)."""
        return self._requested_port if self._bound_port is None else self._bound_port

    # ------------------------------------------------------------------------------------
    # inspection (tests)
    # ------------------------------------------------------------------------------------
    @property
    def joints(self) -> np.ndarray:
        with self._lock:
            return self._joints.copy()

    def set_joints(self, q_rad: Sequence[float]) -> None:
        """Teleport the arm (test set-up only)."""
        with self._lock:
            self._joints = np.asarray(q_rad, dtype=np.float64).reshape(6).copy()

    @property
    def moving(self) -> bool:
        with self._lock:
            return bool(self._queue)

    @property
    def errors(self) -> list[int]:
        with self._lock:
            return list(self._errors)

    def tcp_pose(self) -> np.ndarray:
        """Current tool pose in the current work frame, 4x4 (m)."""
        with self._lock:
            return self._tcp_pose_locked()

    def do_state(self, io: int, tool: bool = False) -> int:
        with self._lock:
            return (self._tool_do if tool else self._do)[io - 1]

    def command_names(self) -> list[str]:
        with self._lock:
            return [c.name for c in self.commands]

    def commands_named(self, name: str) -> list[CommandRecord]:
        with self._lock:
            return [c for c in self.commands if c.name == name]

    def rising_edges(self, io: int, tool: bool = False) -> list[DOEvent]:
        """Every 0 -> 1 transition of one output (a weld-gun trigger per edge)."""
        with self._lock:
            return [e for e in self.do_events if e.io == io and e.tool == tool and e.value == 1]

    def wait_until(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Wait (on the simulator's change condition) until ``predicate()`` is true."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._changed.wait(min(left, 0.05))
        return True

    @property
    def client_count(self) -> int:
        with self._lock:
            return sum(1 for c in self._conns.values() if c.alive)

    # ------------------------------------------------------------------------------------
    # fault injection
    # ------------------------------------------------------------------------------------
    def drop_connections(self) -> None:
        """Close every client connection now (as a cable pull would look to the client)."""
        with self._lock:
            conns = list(self._conns.values())
        for c in conns:
            c.close()

    def drop_after_commands(self, n: int, command: str | None = None) -> None:
        """Close the connection right after replying to the ``n``-th (matching) command from now."""
        with self._lock:
            self._faults.append(_Fault(command, int(n), "drop_after"))

    def drop_mid_motion(self, nth: int = 1, fraction: float = 0.5, command: str | None = None) -> None:
        """Drop the commanding connection when the ``nth`` (matching) motion reaches ``fraction``."""
        with self._lock:
            self._faults.append(_Fault(command, int(nth), "drop_mid_motion", fraction=fraction))

    def refuse_connections(self, count: int | None = None) -> None:
        """Accept and immediately close the next ``count`` connection attempts (None: all, until
        :meth:`accept_connections`)."""
        with self._lock:
            self._refuse = -1 if count is None else int(count)

    def accept_connections(self) -> None:
        with self._lock:
            self._refuse = 0

    def fail_next(self, command: str, code: int, mode: str = "reject", nth: int = 1, fraction: float = 0.5) -> None:
        """Make the ``nth`` ``command`` from now fail with controller error ``code``.

        ``mode``: ``"reject"`` — the acknowledgement carries ``false`` and the state shows
        ``code``; ``"trajectory"`` (motions) — accepted, then at ``fraction`` the motion aborts
        with ``trajectory_state:false`` and ``code`` (e.g. 0x100D collision); ``"no_reply"`` — the
        command is swallowed.
        """
        if mode not in ("reject", "trajectory", "no_reply"):
            raise ValueError(f"mode {mode!r}")
        with self._lock:
            self._faults.append(_Fault(command, int(nth), mode, code=int(code), fraction=fraction))

    def stall_next_motion(self, fraction: float = 0.5, command: str | None = None) -> None:
        """The next (matching) motion freezes at ``fraction`` and never reports arrival."""
        with self._lock:
            self._faults.append(_Fault(command, 1, "stall", fraction=fraction))

    def set_error(self, code: int) -> None:
        """Raise a controller error (shown in the state until cleared or the next motion)."""
        with self._lock:
            self._errors.append(int(code))

    def clear_faults(self) -> None:
        with self._lock:
            self._faults.clear()
            self._refuse = 0

    def _take_fault(self, name: str, actions: Sequence[str]) -> _Fault | None:
        """Count ``name`` against the pending faults of the given actions; return one that fires."""
        fired = None
        for f in list(self._faults):
            if f.action in actions and f.matches(name):
                f.remaining -= 1
                if f.remaining <= 0:
                    self._faults.remove(f)
                    if fired is None:
                        fired = f
        return fired

    # ------------------------------------------------------------------------------------
    # networking
    # ------------------------------------------------------------------------------------
    def _accept_loop(self) -> None:
        assert self._server is not None
        while self._running.is_set():
            try:
                sock, peer = self._server.accept()
            except socket.timeout:
                continue
            except OSError:
                break
            with self._lock:
                refuse = self._refuse != 0
                if self._refuse > 0:
                    self._refuse -= 1
            if refuse:
                _log.info("simulator: refusing connection from %s (fault injection)", peer)
                sock.close()
                continue
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            # Blocking reads: _Conn.close (a drop, stop()) shuts the socket down, which ends recv;
            # no per-connection polling, so hundreds of clients cost nothing while idle.
            sock.settimeout(None)
            # ...but a client that stops reading must not block the replies to everyone else for ever
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, struct.pack("ll", 2, 0))
            with self._lock:
                conn = _Conn(self._next_conn_id, sock, peer)
                self._next_conn_id += 1
                self._conns[conn.id] = conn
                self.connection_count += 1
            t = threading.Thread(target=self._serve, args=(conn,), name=f"sim-conn-{conn.id}", daemon=True)
            t.start()
            self._threads = [x for x in self._threads if x.is_alive()] + [t]

    def _serve(self, conn: _Conn) -> None:
        try:
            while self._running.is_set() and conn.alive:
                try:
                    data = conn.sock.recv(65536)
                except (OSError, ValueError):
                    break
                if not data:
                    break
                now = time.monotonic()
                for msg in conn.decoder.feed(data):
                    if not conn.alive:
                        break
                    self._handle(conn, msg, now)
        finally:
            conn.close()
            with self._lock:
                self._conns.pop(conn.id, None)
                if not self.keep_moving_on_disconnect:
                    self._halt_motions_of(conn.id)
                self._changed.notify_all()

    def _reply(self, conn: _Conn, msg: dict[str, Any]) -> None:
        conn.send(msg, self.pretty_replies)

    def _send_to(self, conn_id: int, msg: dict[str, Any]) -> None:
        with self._lock:
            conn = self._conns.get(conn_id)
        if conn is not None:
            conn.send(msg, self.pretty_replies)

    # ------------------------------------------------------------------------------------
    # command handling
    # ------------------------------------------------------------------------------------
    def _handle(self, conn: _Conn, msg: dict[str, Any], t_received: float) -> None:
        name = msg.get("command")
        with self._lock:
            self.commands.append(CommandRecord(t_received, conn.id, msg))
            self._changed.notify_all()
            if not isinstance(name, str):
                _log.warning("simulator: message without a command: %r", msg)
                return
            fault = self._take_fault(name, ("reject", "no_reply", "trajectory"))
            drop = self._take_fault(name, ("drop_after",))
        if fault is not None and fault.action == "no_reply":
            return
        if fault is not None and fault.action == "reject":
            with self._lock:
                self._errors = [fault.code] if fault.code else self._errors
            key = P.RESULT_KEY.get(name, "set_state")
            self._reply(conn, {"command": name, key: False})
        else:
            handler = getattr(self, "_cmd_" + name, None)
            if handler is None:
                # What a real controller answers to an unknown command is undocumented: stay silent.
                _log.warning("simulator: unknown command %r ignored", name)
            else:
                try:
                    reply = handler(conn, msg, fault) if name in P.MOTION_COMMANDS else handler(msg)
                except (KeyError, TypeError, ValueError, IndexError, ArithmeticError) as exc:
                    _log.warning("simulator: bad %s request %r: %s", name, msg, exc)
                    reply = {"command": name, P.RESULT_KEY.get(name, "set_state"): False}
                # A handler returns its reply, or a list: the reply, then (conn_id, event) pairs to
                # send and callables to run once the reply is on the wire.
                for item in reply if isinstance(reply, list) else [reply]:
                    if callable(item):
                        item()
                    elif isinstance(item, tuple):
                        self._send_to(*item)
                    elif item is not None:
                        self._reply(conn, item)
        if drop is not None:
            _log.info("simulator: dropping connection %d after %r (fault injection)", conn.id, name)
            conn.close()

    # -- motion --------------------------------------------------------------------------
    def _plan(self, name: str, msg: dict[str, Any], q_start: np.ndarray) -> tuple[np.ndarray | None, float, int]:
        """Joint path and simulated duration, or (None, 0, error code)."""
        v = int(msg["v"])
        if not 1 <= v <= 100:
            raise ValueError(f"v={v}")
        frac = v / 100.0
        if name == "movej":
            wire = _finite_floats(msg["joint"], 6)
            if wire is None:
                return None, 0.0, 0x1002  # no joint is at 1e300 degrees: out of its limits
            q_goal = P.joints_from_wire(wire)
            if not self.kin.within_limits(q_goal):
                return None, 0.0, 0x1002
            path = np.vstack([q_start, q_goal])
            return path, self.kin.joint_move_time(q_start, q_goal, frac), 0
        wire = _finite_floats(msg["pose"], 6)
        if wire is None or np.any(np.abs(wire[3:]) > 1e6):  # non-finite, or angles beyond +-1000 rad
            return None, 0.0, 0x1003
        with self._lock:
            T_work, T_tool = self._frames_locked()
        T_goal = T_work @ pose6_to_matrix(P.pose_from_wire(wire))  # tool in base
        if not self._within_reach(T_goal, T_tool):
            return None, 0.0, 0x1003
        if name == "movej_p":
            res = self.kin.ik(T_goal, q_start, tool=T_tool, restarts=6, max_iterations=100)
            if not res.success:
                return None, 0.0, 0x1003
            path = np.vstack([q_start, res.q])
            return path, self.kin.joint_move_time(q_start, res.q, frac), 0
        # movel
        path, why = self.kin.linear_path(q_start, T_goal, tool=T_tool)
        if path is None:
            _log.info("simulator: movel refused: %s", why)
            return None, 0.0, 0x1003
        T0 = self.kin.fk(q_start, T_tool)
        length = float(np.linalg.norm(T_goal[:3, 3] - T0[:3, 3]))
        angle = rotation_angle(T0, T_goal)
        dq = np.abs(np.diff(path, axis=0))
        joint_t = float(np.sum(np.max(dq / self.kin.max_speed_rad_s, axis=1))) / frac
        t = max(length / (self.max_line_speed_m_s * frac), angle / (self.max_angular_speed_rad_s * frac), joint_t)
        return path, t, 0

    def _within_reach(self, T_goal: np.ndarray, T_tool: np.ndarray) -> bool:
        """Cheap necessary condition, checked before the IK: the flange inside the working sphere."""
        dh = self.kin.dh
        reach = dh.a[2] + dh.d[3] + dh.d[5]  # upper arm + forearm + flange: 0.61 m for the RM65-B
        with np.errstate(all="ignore"):
            flange = (T_goal @ invert_transform(T_tool))[:3, 3]
            d = float(np.linalg.norm(flange - np.array([0.0, 0.0, dh.d[0]])))
        return bool(np.isfinite(d) and d <= reach + 1e-3)

    def _motion_cmd(self, conn: _Conn, msg: dict[str, Any], fault: _Fault | None) -> Any:
        name = msg["command"]
        if int(msg.get("trajectory_connect", 0)) != 0:
            _log.warning("simulator: trajectory_connect=1 is executed as 0 (blending not simulated)")
        with self._lock:
            q_start = self._queue[-1].path[-1].copy() if self._queue else self._joints.copy()
            if len(self._queue) >= MAX_QUEUED_MOTIONS:
                return {"command": name, "receive_state": False}
        path, duration, code = self._plan(name, msg, q_start)
        with self._lock:
            if path is None:
                self._errors = [code]
                self._changed.notify_all()
                return {"command": name, "receive_state": False}
            motion = _Motion(name, path, max(duration, 0.01), conn.id)
            if fault is not None and fault.action == "trajectory":
                motion.fail_at, motion.fail_code = fault.fraction, fault.code
            stall = self._take_fault(name, ("stall",))
            if stall is not None:
                motion.stall_at = stall.fraction
            drop = self._take_fault(name, ("drop_mid_motion",))
            if drop is not None:
                motion.drop_at = drop.fraction
            self._errors = []  # errors clear on the next motion command (DOCS)
            self._queue.append(motion)
            self.motion_log.append((name, path[-1].copy()))
            self._changed.notify_all()
        return [{"command": name, "receive_state": True}, motion.release]

    _cmd_movej = _motion_cmd
    _cmd_movej_p = _motion_cmd
    _cmd_movel = _motion_cmd

    def _motion_loop(self) -> None:
        last = time.monotonic()
        while self._running.is_set():
            time.sleep(self.tick_s)
            now = time.monotonic()
            dt = (now - last) / max(self.time_scale, 1e-9)
            last = now
            outbox: list[tuple[int, dict[str, Any]]] = []
            drops: list[int] = []
            with self._lock:
                if not self._queue or self._paused:
                    continue
                m = self._queue[0]
                if not m.released:
                    continue
                m.elapsed_s += dt
                f = m.fraction()
                for limit in (m.stall_at, m.fail_at, m.drop_at):
                    if limit is not None and f >= limit:
                        f = min(f, limit)
                if m.drop_at is not None and f >= m.drop_at:
                    drops.append(m.conn_id)
                    m.drop_at = None
                if m.stall_at is not None and f >= m.stall_at:
                    m.elapsed_s = m.stall_at * m.duration_s
                    f = m.stall_at
                self._joints = m.joints_at(f)
                if m.fail_at is not None and f >= m.fail_at:
                    self._queue.clear()
                    self._errors = [m.fail_code]
                    outbox.append((m.conn_id, _trajectory_msg(False)))
                elif f >= 1.0 and now - (m.released_at or now) >= self.min_motion_real_s:
                    self._queue.popleft()
                    outbox.append((m.conn_id, _trajectory_msg(True)))
                self._changed.notify_all()
            for conn_id in drops:
                with self._lock:
                    conn = self._conns.get(conn_id)
                if conn is not None:
                    _log.info("simulator: dropping connection %d mid-motion (fault injection)", conn_id)
                    conn.close()
            for conn_id, msg in outbox:
                self._send_to(conn_id, msg)

    def _halt_motions_of(self, conn_id: int) -> None:
        self._queue = collections.deque(m for m in self._queue if m.conn_id != conn_id)

    def _stop_motion(self) -> list[tuple[int, dict[str, Any]]]:
        with self._lock:
            out = []
            if self._queue and self.stop_reports_trajectory:
                out = [(self._queue[0].conn_id, _trajectory_msg(False))]
            self._queue.clear()
            self._paused = False
            self._changed.notify_all()
        return out

    def _cmd_set_arm_stop(self, msg: dict[str, Any]) -> list[Any]:
        # The stop reply goes out first, then the "trajectory failed" event (the SDK tolerates it).
        return [{"command": "set_arm_stop", "arm_stop": True}, *self._stop_motion()]

    def _cmd_set_arm_slow_stop(self, msg: dict[str, Any]) -> list[Any]:
        # Decelerating along the path is not modelled: a slow stop halts like a stop.
        return [{"command": "set_arm_slow_stop", "arm_slow_stop": True}, *self._stop_motion()]

    def _cmd_set_arm_pause(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            self._paused = True
            self._changed.notify_all()
        return {"command": "set_arm_pause", "arm_pause": True}

    def _cmd_set_arm_continue(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            self._paused = False
            self._changed.notify_all()
        return {"command": "set_arm_continue", "arm_continue": True}

    def _cmd_set_delete_current_trajectory(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = self._paused
            if ok and self._queue:
                self._queue.popleft()
        return {"command": "set_delete_current_trajectory", "delete_current_trajectory": ok}

    def _cmd_set_arm_delete_trajectory(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = self._paused
            if ok:
                self._queue.clear()
        return {"command": "set_arm_delete_trajectory", "arm_delete_trajectory": ok}

    def _cmd_clear_system_err(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            self._errors = []
        return {"command": "clear_system_err", "clear_state": True}

    def _cmd_get_arm_current_trajectory(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            if self._queue:
                m = self._queue[0]
                kind = "movel" if m.kind == "movel" else "movej"
                data = P.joints_to_wire(m.path[-1]) if kind == "movej" else P.pose_to_wire(
                    matrix_to_pose6(self._tcp_pose_at(m.path[-1])))
            else:
                kind, data = "none", P.joints_to_wire(self._joints)
        return {"state": "arm_current_trajectory", "type": kind, "data": data}

    # -- state ---------------------------------------------------------------------------
    def _frames_locked(self) -> tuple[np.ndarray, np.ndarray]:
        T_work = pose6_to_matrix(self._work_frames[self._work_name])
        T_tool = pose6_to_matrix(self._tool_frames[self._tool_name][0])
        return T_work, T_tool

    def _tcp_pose_at(self, q: np.ndarray) -> np.ndarray:
        T_work, T_tool = self._frames_locked()
        return invert_transform(T_work) @ self.kin.fk(q, T_tool)

    def _tcp_pose_locked(self) -> np.ndarray:
        return self._tcp_pose_at(self._joints)

    def _cmd_get_current_arm_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            pose = matrix_to_pose6(self._tcp_pose_locked())
            return P.arm_state_message(self._joints, pose, self._errors, self.err_format)

    def _cmd_get_joint_degree(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "joint_degree", "joint": P.joints_to_wire(self._joints)}

    def _cmd_get_arm_all_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "arm_all_state", "all_state": {
            "temperature": [35000] * 6, "current": [500000] * 6, "voltage": [24000] * 6,
            "err_flag": [0] * 6, "en_flag": [1] * 6, "sys_err": 0}}

    def _cmd_get_controller_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "controller_state", "voltage": 24000, "current": 1500, "temperature": 42000,
                "err_flag": 0}

    def _cmd_set_arm_power(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            self._power = int(msg["arm_power"])
        return {"command": "set_arm_power", "arm_power": True}

    def _cmd_get_arm_power_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "arm_power_state", "power_state": self._power}

    def _cmd_set_arm_run_mode(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"command": "set_arm_run_mode", "set_state": True}  # reply format [UNCERTAIN]

    # -- connect-time queries of the official SDK (§1.11) --------------------------------
    def _cmd_get_arm_software_info(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {
            "Product_version": self.product_version,
            "algorithm_info": {"version": "1.2.3"},
            "command": "arm_software_info",
            "ctrl_info": {"build_time": "2024-10-17 10:00:00", "version": "V1.4.6"},
            "dynamic_info": {"model_version": "1"},
            "plan_info": {"build_time": "2024-10-17 10:00:00", "version": "V1.4.6"},
        }

    def _cmd_get_realtime_push(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            cfg = dict(self._realtime_push)
        return {"command": "get_realtime_push", "custom": {"expand_state": False, "joint_speed": False,
                "lift_state": False}, **cfg}

    def _cmd_set_realtime_push(self, msg: dict[str, Any]) -> dict[str, Any]:
        # Stored and reported back; the UDP push itself is not simulated.
        with self._lock:
            for k in ("cycle", "enable", "port", "ip", "force_coordinate"):
                if k in msg:
                    self._realtime_push[k] = msg[k]
        return {"command": "set_realtime_push", "state": True}

    def _cmd_get_install_pose(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "install_pose", "pose": [0, 0, 0]}

    def _cmd_get_joint_min_pos(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "joint_min_pos", "min_pos": P.joints_to_wire(self.kin.limits_rad[:, 0])}

    def _cmd_get_joint_max_pos(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "joint_max_pos", "max_pos": P.joints_to_wire(self.kin.limits_rad[:, 1])}

    def _cmd_get_joint_max_speed(self, msg: dict[str, Any]) -> dict[str, Any]:
        # 0.001 deg/s ([UNCERTAIN] unit, see §1.6)
        return {"state": "joint_max_speed", "joint_speed": [int(v * 1000) for v in JOINT_MAX_SPEED_DEG_S]}

    def _cmd_get_joint_max_acc(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "joint_max_acc", "joint_acc": [600000] * 6}

    def _cmd_get_DH_data(self, msg: dict[str, Any]) -> dict[str, Any]:
        dh = self.kin.dh
        out: dict[str, Any] = {"command": "get_DH_data"}
        for i in range(6):
            out[f"joint_{i + 1}"] = [
                int(round(np.degrees(dh.alpha[i]) * 1000)), int(round(dh.a[i] * 1e6)),
                int(round(dh.d[i] * 1e6)), int(round(np.degrees(dh.offset[i]) * 1000)),
            ]
        return out

    # -- frames (§1.7) -------------------------------------------------------------------
    def _cmd_set_manual_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        name = str(msg["tool_name"])
        ok = 0 < len(name) <= 10
        with self._lock:
            ok = ok and (name in self._tool_frames or len(self._tool_frames) < 10)
            if ok:
                self._tool_frames[name] = (P.pose_from_wire(msg["tool_pose"]), int(msg.get("payload", 0)),
                                           [int(v) for v in msg.get("position", [0, 0, 0])])
        return {"command": "set_manual_tool_frame", "manual_tool_frame": ok}

    def _cmd_set_change_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["tool_name"] in self._tool_frames and not self._queue
            if ok:
                self._tool_name = msg["tool_name"]
            elif msg["tool_name"] not in self._tool_frames:
                self._errors = [0x100F]
        return {"command": "set_change_tool_frame", "change_tool_frame": ok}

    def _cmd_set_delete_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["tool_name"] in self._tool_frames and msg["tool_name"] not in (self._tool_name, "Arm_Tip")
            if ok:
                del self._tool_frames[msg["tool_name"]]
        return {"command": "set_delete_tool_frame", "delete_tool_frame": ok}

    def _cmd_get_current_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            pose, payload, com = self._tool_frames[self._tool_name]
            return {"state": "current_tool_frame", "tool_name": self._tool_name, "pose": P.pose_to_wire(pose),
                    "payload": payload, "position": list(com)}

    def _cmd_get_total_tool_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "total_tool_frame", "tool_names": list(self._tool_frames)}

    def _cmd_set_manual_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        name = str(msg["frame_name"])
        ok = 0 < len(name) <= 10
        with self._lock:
            ok = ok and (name in self._work_frames or len(self._work_frames) < 10)
            if ok:
                self._work_frames[name] = P.pose_from_wire(msg["frame_pose"])
        return {"command": "set_manual_work_frame", "manual_work_frame": ok}

    def _cmd_set_change_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["frame_name"] in self._work_frames and not self._queue
            if ok:
                self._work_name = msg["frame_name"]
            elif msg["frame_name"] not in self._work_frames:
                self._errors = [0x100E]
        return {"command": "set_change_work_frame", "change_work_frame": ok}

    def _cmd_set_delete_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            ok = msg["frame_name"] in self._work_frames and msg["frame_name"] not in (self._work_name, "Base")
            if ok:
                del self._work_frames[msg["frame_name"]]
        return {"command": "set_delete_work_frame", "delete_work_frame": ok}

    def _cmd_get_current_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "current_work_frame", "frame_name": self._work_name,
                    "pose": P.pose_to_wire(self._work_frames[self._work_name])}

    def _cmd_get_total_work_frame(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "total_work_frame", "frame_names": list(self._work_frames)}

    # -- IO (§1.8) -----------------------------------------------------------------------
    def _record_do(self, io: int, tool: bool, value: int) -> None:
        self.do_events.append(DOEvent(time.monotonic(), io, tool, value, self._joints.copy(), self._tcp_pose_locked()))

    def _cmd_set_IO_mode(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, mode = int(msg["IO_Num"]), int(msg["IO_mode"])
        ok = 1 <= io <= N_IO and 0 <= mode <= 14
        if ok:
            with self._lock:
                self._io_mode[io - 1] = mode
        return {"command": "set_IO_mode", "set_state": ok}

    def _cmd_set_DO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, value = int(msg["IO_Num"]), 1 if int(msg["state"]) else 0
        with self._lock:
            ok = 1 <= io <= N_IO and (not self.strict_io_mode or self._io_mode[io - 1] == 1)
            if ok and self._do[io - 1] != value:
                self._do[io - 1] = value
                self._record_do(io, False, value)
                self._changed.notify_all()
        return {"command": "set_DO_state", "set_state": ok}

    def _cmd_get_IO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        io = int(msg["IO_Num"])
        if not 1 <= io <= N_IO:
            raise ValueError(f"IO_Num {io}")
        with self._lock:
            return {"state": "IO_state", "IO_Num": io, "IO_Mode": self._io_mode[io - 1], "IO_state": self._do[io - 1]}

    def _cmd_get_IO_output(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "IO_output_state", "DO": list(self._do), "AO": [0] * 4}

    def _cmd_get_IO_input(self, msg: dict[str, Any]) -> dict[str, Any]:
        return {"state": "IO_input_state", "DI": [0] * N_IO, "AI": [0] * 4}

    def _cmd_set_tool_IO_mode(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, mode = int(msg["IO_Num"]), int(msg["state"])
        ok = 1 <= io <= N_TOOL_IO and mode in (0, 1)
        if ok:
            with self._lock:
                self._tool_io_mode[io - 1] = mode
        return {"command": "set_tool_IO_mode", "set_state": ok}

    def _cmd_set_tool_DO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        io, value = int(msg["IO_Num"]), 1 if int(msg["state"]) else 0
        with self._lock:
            ok = 1 <= io <= N_TOOL_IO and (not self.strict_io_mode or self._tool_io_mode[io - 1] == 1)
            if ok and self._tool_do[io - 1] != value:
                self._tool_do[io - 1] = value
                self._record_do(io, True, value)
                self._changed.notify_all()
        return {"command": "set_tool_DO_state", "set_state": ok}

    def _cmd_get_tool_IO_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        with self._lock:
            return {"state": "tool_IO_state", "IO_Mode": list(self._tool_io_mode), "IO_State": list(self._tool_do)}

    def _cmd_set_tool_voltage(self, msg: dict[str, Any]) -> dict[str, Any]:
        vt = int(msg["voltage_type"])
        ok = vt in (0, 1, 2, 3)
        if ok:
            with self._lock:
                self._tool_voltage = vt
        return {"command": "set_tool_voltage", "state": ok}


def _finite_floats(values: Any, n: int) -> np.ndarray | None:
    """``n`` wire numbers as floats, or None if any is not a finite number (NaN, 1e400, a 400-digit int)."""
    if not isinstance(values, (list, tuple)) or len(values) != n:
        raise ValueError(f"expected {n} numbers, got {values!r:.80}")
    try:
        out = np.array([float(v) for v in values], dtype=np.float64)
    except OverflowError:
        return None
    return out if np.all(np.isfinite(out)) and np.all(np.abs(out) < 1e15) else None


def _trajectory_msg(success: bool) -> dict[str, Any]:
    return {"state": P.TRAJECTORY_STATE, "trajectory_state": bool(success), "device": 0, "trajectory_connect": 0}


# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point ``simulator``: serve until Ctrl-C."""
    parser = argparse.ArgumentParser(prog="simulator", description="RM-65 controller simulator (loopback)")
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1, loopback)")
    parser.add_argument("--port", type=int, default=P.DEFAULT_PORT, help="TCP port (default 8080)")
    parser.add_argument("--time-scale", type=float, default=1.0, help="motion duration factor (default 1.0)")
    parser.add_argument("--err-format", choices=("list", "scalar", "arm_sys"), default="list",
                        help="arm state error format: list (current firmware), scalar, arm_sys (older docs)")
    parser.add_argument("--pretty", action="store_true", help="send pretty-printed replies")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(message)s")
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        _log.warning("binding the simulator to a non-loopback address %s", args.host)
    try:
        sim = ArmSimulator(host=args.host, port=args.port, time_scale=args.time_scale,
                           err_format=args.err_format, pretty_replies=args.pretty)
        sim.start()
    except (OSError, ValueError) as exc:
        print(f"simulator: cannot start on {args.host}:{args.port}: {exc}", file=sys.stderr)
        return 2
    done = threading.Event()
    signal.signal(signal.SIGINT, lambda *_: done.set())
    signal.signal(signal.SIGTERM, lambda *_: done.set())
    print(f"RM65 simulator on {args.host}:{sim.port} (Ctrl-C to stop)", flush=True)
    while not done.wait(0.5):  # wake up now and then: a signal's handler runs in this (main) thread
        pass
    sim.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
