"""A loopback simulator of the RM-65 controller's JSON-over-TCP interface.

Speaks the protocol of docs/RM65_PROTOCOL.md (``§`` cites its sections) well enough for our driver
*and* the official SDK (robotic-arm 1.1.6) to connect: ``\\r\\n`` framing (pretty-printed requests tolerated), the
eleven connect-time queries of §1.11, ``movej`` / ``movej_p`` / ``movel`` with the
acknowledgement followed by the ``current_trajectory_state`` arrival message, stop / slow stop
/ pause / continue, tool and work frames, controller and tool-flange IO, arm state in the
current (``err`` list) or the older error formats.

The arm moves in (scaled) real time along trapezoidal profiles: ``v`` % scales speeds and
accelerations alike, as RealMan documents; a joint move lasts as long as the slowest joint needs
at ``v`` % of its maximum speed and acceleration (``get_joint_max_acc``), a linear move as long
as the path needs at ``v`` % of the line and angular limits (:class:`.motion.MotionLimits`),
starting and ending at rest; ``time_scale`` multiplies every duration (0.02 makes tests 50x faster). Targets outside
the joint limits are refused with ``receive_state:false`` and error 0x1002 in the state,
unreachable poses with 0x1003 (the exact channel is [UNCERTAIN] in the docs; this is the one
the official SDK reports as "refused", §2). Numbers no arm can reach -- non-finite, too large for
a float, a flange beyond the working sphere -- are refused the same way at once, before any IK.

For tests: every received command is recorded with its arrival time (``commands``), every
digital-output change with the tool pose at that instant (``do_events``,
:meth:`rising_edges`), and faults can be injected (:meth:`drop_connections`,
:meth:`drop_after_commands`, :meth:`drop_mid_motion`, :meth:`refuse_connections`,
:meth:`fail_next`, :meth:`stall_next_motion`, :meth:`set_error`).

A rail under the arm (``rail_axis``): the controller's expansion joint, device 4 (:mod:`.rail`),
with its sim-only true deviation (``rail_deviation``); none by default.

Its options are one frozen :class:`~rm65_sim.config.SimulatorConfig` (:mod:`.config`). Parts, by concern: the
motion model (:mod:`.motion`), the controller's state and its
non-motion commands (:mod:`.controller`), the rail (:mod:`.rail`), the TCP server (:mod:`.server`)
and the fault injection (:mod:`.faults`); this module holds the state, dispatches the commands, runs the
motion thread and the command line.

Run stand-alone: ``python -m rm65_sim.simulator --port 8080`` (binds 127.0.0.1 unless told
otherwise). Usage from pytest::

    sim = ArmSimulator(port=0, config=SimulatorConfig(time_scale=0.02)); sim.start(); ... sim.port ...; sim.stop()
"""
from __future__ import annotations

import argparse
import collections
import logging
import signal
import socket
import sys
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from rm65_driver.kinematics.rm65 import DHModel, RM65Kinematics, matrix_to_pose6
from rm65_driver.protocol import messages as P
from rm65_driver.rail.axis import EXPAND_SET_POS, RailAxis
from rm65_sim.config import SimulatorConfig
from rm65_sim.controller import N_IO, N_TOOL_IO, ControllerCommands, DOEvent
from rm65_sim.faults import Fault, FaultInjection
from rm65_sim.motion import (
    Motion,
    SegmentProfile,
    junction_speed,
    line_segment,
    plan_motion,
    trajectory_msg,
)
from rm65_sim.rail import SimRail
from rm65_sim.server import Connection, TcpServer
from stud_common.frames import RailDeviation
from stud_common.stacks import dump_stacks_on_signal

_log = logging.getLogger(__name__)

MAX_QUEUED_MOTIONS = 10  # Gen-2 buffers 10 points (DOCS-FAQ); plenty for the driver
#: Commands whose handler is told the commanding connection (its arrival message goes there).
_CONN_COMMANDS = P.MOTION_COMMANDS | {EXPAND_SET_POS}


@dataclass(frozen=True)
class CommandRecord:
    """A command as received: ``t`` is ``time.monotonic()`` when its frame was decoded."""

    t: float
    conn_id: int
    msg: dict[str, Any]

    @property
    def name(self) -> str:
        return str(self.msg.get("command", ""))



class ArmSimulator(TcpServer, FaultInjection, ControllerCommands):
    """Threaded TCP controller simulator (see the module docstring), behaving as its
    :class:`~rm65_sim.config.SimulatorConfig` says: the error format, IO strictness, what a dropped
    connection or a stop does, the rail under the arm.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = P.DEFAULT_PORT, config: SimulatorConfig | None = None):
        """Serve on ``host``:``port`` (0: a free port, :attr:`port` tells which once started) as ``config``
        says (:class:`~rm65_sim.config.SimulatorConfig`; None: its defaults)."""
        self.config = config or SimulatorConfig()
        self.host = host
        self._requested_port = int(port)
        self.time_scale = float(self.config.time_scale)  # live: tests change it while the simulator runs
        self.kin = RM65Kinematics(dh=DHModel.rm65(self.config.d6_m))

        self._lock = threading.RLock()
        self._joints = np.radians(np.asarray(self.config.initial_joints_deg, dtype=np.float64))
        self._queue: collections.deque[Motion] = collections.deque()
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
        self._faults: list[Fault] = []
        self._refuse = 0  # connections still to refuse; -1: all
        self._conns: dict[int, Connection] = {}
        self._next_conn_id = 1
        self.connection_count = 0

        self._server: socket.socket | None = None
        self._bound_port: int | None = None
        self._threads: list[threading.Thread] = []
        self._running = threading.Event()
        self._changed = threading.Condition(self._lock)
        cfg = self.config
        self.rail = SimRail(cfg.rail_axis, self._lock, self._changed, tuple(cfg.rail_mount_xyz_m), cfg.rail_deviation,
                            cfg.min_motion_real_s)

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

    # ------------------------------------------------------------------------------------
    # command handling
    # ------------------------------------------------------------------------------------
    def _handle(self, conn: Connection, msg: dict[str, Any], t_received: float) -> None:
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
                    reply = handler(conn, msg, fault) if name in _CONN_COMMANDS else handler(msg)
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
    def _plan(self, name: str, msg: dict[str, Any], q_start: np.ndarray) -> tuple[np.ndarray | None, float, float, int]:
        """Joint path, duration and acceleration time, or (None, 0, 0, error code) (:func:`.motion.plan_motion`)."""
        return plan_motion(self.kin, name, msg, q_start, self._frames, self.config.limits)

    def _frames(self) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            return self._frames_locked()

    def _motion_cmd(self, conn: Connection, msg: dict[str, Any], fault: Fault | None) -> Any:
        name = msg["command"]
        connect = int(msg.get("trajectory_connect", 0)) != 0
        if connect and int(msg.get("r", 0)) != 0:
            _log.warning("simulator: blend radius r=%s is not simulated: corners are passed at rest", msg.get("r"))
        with self._lock:
            q_start = self._queue[-1].path[-1].copy() if self._queue else self._joints.copy()
            if len(self._queue) >= MAX_QUEUED_MOTIONS:
                return {"command": name, "receive_state": False}
        path, duration, accel, code = self._plan(name, msg, q_start)
        with self._lock:
            if path is None:
                self._errors = [code]
                self._changed.notify_all()
                return {"command": name, "receive_state": False}
            motion = Motion(name, path, SegmentProfile.rest_to_rest(max(duration, 0.01), accel), conn.id,
                            connect_next=connect)
            if name == "movel":
                motion.line = line_segment(self.kin, path, self._frames_locked()[1], duration, accel)
            if self._queue and self._queue[-1].connect_next:
                self._join(self._queue[-1], motion)
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

    @staticmethod
    def _join(prev: Motion, nxt: Motion) -> None:
        """``nxt`` follows ``prev`` (sent with trajectory_connect=1), which has not started: pass the junction at speed.

        Only where one line continues the other (:func:`.motion.junction_speed`); anywhere else
        the arm stops at the junction, as it does between unconnected motions.
        """
        if prev.line is None or nxt.line is None or prev.elapsed_s > 0:
            return
        u = prev.profile.u  # 0 unless joined to the motion before it too
        w = junction_speed(prev.line, nxt.line)
        if w <= 0 or abs(u * u - w * w) > 2 * prev.line.accel * prev.line.length:
            return
        prev.profile = SegmentProfile(prev.line.length, u, w, prev.line.speed, prev.line.accel)
        nxt.profile = SegmentProfile(nxt.line.length, w, 0.0, nxt.line.speed, nxt.line.accel)

    _cmd_movej = _motion_cmd
    _cmd_movej_p = _motion_cmd
    _cmd_movel = _motion_cmd

    def _motion_loop(self) -> None:
        last = time.monotonic()
        while self._running.is_set():
            time.sleep(self.config.tick_s)
            now = time.monotonic()
            dt = (now - last) / max(self.time_scale, 1e-9)
            last = now
            for conn_id, msg in self.rail.advance(dt, now):
                self._send_to(conn_id, msg)
            outbox: list[tuple[int, dict[str, Any]]] = []
            drops: list[int] = []
            with self._lock:
                if not self._queue or self._paused:
                    continue
                m = self._queue[0]
                if not m.released or (m.connect_next and len(self._queue) == 1):
                    continue  # acknowledged, not on the wire yet / planned with a motion still to come
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
                    outbox.append((m.conn_id, trajectory_msg(False)))
                elif f >= 1.0 and now - (m.released_at or now) >= self.config.min_motion_real_s:
                    self._queue.popleft()
                    connected = m.connect_next and self.config.report_connected
                    outbox.append((m.conn_id, trajectory_msg(True, connected=connected)))
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
            if self._queue and self.config.stop_reports_trajectory:
                out = [(self._queue[0].conn_id, trajectory_msg(False))]
            self._queue.clear()
            self._paused = False
            out += self.rail.stop()  # the arm's stop stops the rail too (rm65_sim.rail's choice)
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

    # -- the rail (expansion joint, device 4): rail.py --------------------------------------
    def _cmd_expand_set_pos(self, conn: Connection, msg: dict[str, Any], fault: Fault | None) -> list[Any]:
        return self.rail.cmd_set_pos(conn.id, msg)

    def _cmd_expand_set_speed(self, msg: dict[str, Any]) -> list[Any]:
        return self.rail.cmd_set_speed(msg)

    def _cmd_expand_get_state(self, msg: dict[str, Any]) -> dict[str, Any]:
        return self.rail.cmd_get_state(msg)



# --------------------------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------------------------


def _three_floats(text: str) -> tuple[float, float, float]:
    """``"x,y,z"``, ``"[x, y, z]"`` or ``"x y z"`` (one command-line word, as a cell var renders a list)."""
    parts = text.strip().strip("[]").replace(",", " ").split()
    try:
        x, y, z = (float(v) for v in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not three numbers x,y,z") from None
    return x, y, z


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point ``simulator``: serve until Ctrl-C."""
    parser = argparse.ArgumentParser(prog="simulator", description="RM-65 controller simulator (loopback)")
    parser.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1, loopback)")
    parser.add_argument("--port", type=int, default=P.DEFAULT_PORT, help="TCP port (default 8080)")
    parser.add_argument("--time-scale", type=float, default=1.0, help="motion duration factor (default 1.0)")
    parser.add_argument("--err-format", choices=("list", "scalar", "arm_sys"), default="list",
                        help="arm state error format: list (current firmware), scalar, arm_sys (older docs)")
    parser.add_argument("--pretty", action="store_true", help="send pretty-printed replies")
    rail = parser.add_argument_group("rail", "a linear axis under the arm: the expansion joint (device 4)")
    rail.add_argument("--rail-length-m", type=float, default=0.0, help="travel [m]; 0 (default): no rail")
    rail.add_argument("--rail-pos-unit-m", type=float, default=1e-6, help="metres per wire count (default 1e-6)")
    rail.add_argument("--rail-max-speed-m-s", type=float, default=0.5, help="speed at 100 %% [m/s]")
    rail.add_argument("--rail-accel-m-s2", type=float, default=0.5, help="acceleration at 100 %% [m/s^2]")
    rail.add_argument("--rail-mount-xyz-m", type=_three_floats, default=(0.0, 0.0, 0.0), metavar="X,Y,Z",
                      help="the arm's base on the carriage [m]: '0,0,0.1' or '[0.0, 0.0, 0.1]'")
    rail.add_argument("--true-rail-scale-ppm", type=float, default=0.0, help="sim-only truth: scale error [ppm]")
    rail.add_argument("--true-rail-offset-m", type=float, default=0.0, help="sim-only truth: zero offset [m]")
    rail.add_argument("--true-rail-yaw-urad-per-m", type=float, default=0.0,
                      help="sim-only truth: the carriage's heading change per metre [urad/m]")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    dump_stacks_on_signal()
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(asctime)s %(levelname)s %(message)s")
    if args.host not in ("127.0.0.1", "localhost", "::1"):
        _log.warning("binding the simulator to a non-loopback address %s", args.host)
    # SIGINT and SIGTERM are blocked in every thread (the simulator's threads, started below, inherit
    # the mask) and taken synchronously by sigwait: no handler runs at an arbitrary point of this thread.
    # Not a Python handler setting a threading.Event: this thread holds that Event's lock for a few
    # bytecodes of every Event.wait turn, and a signal landing then would block the handler on that lock
    # for ever, the simulator outliving its SIGTERM.
    stop_signals = {signal.SIGINT, signal.SIGTERM}
    # Whatever main changes of the process's signal state is put back when it returns (a caller in the
    # same process, a test, must not be left with the stop signals blocked: its children would inherit
    # the mask and never see a SIGINT).
    handlers = {sig: signal.getsignal(sig) for sig in stop_signals}
    for sig in stop_signals:  # not Python's KeyboardInterrupt either (never ignored: an ignored signal is lost)
        signal.signal(sig, signal.SIG_DFL)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, stop_signals)
    try:
        return _serve(args, stop_signals)
    finally:
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def _serve(args: argparse.Namespace, stop_signals: set[signal.Signals]) -> int:
    """Start the simulator ``args`` describe and serve until one of ``stop_signals`` (blocked) arrives."""
    try:
        rail_axis = (RailAxis(args.rail_length_m, args.rail_pos_unit_m, args.rail_max_speed_m_s, args.rail_accel_m_s2)
                     if args.rail_length_m != 0 else None)
        deviation = RailDeviation(args.true_rail_scale_ppm, args.true_rail_offset_m, args.true_rail_yaw_urad_per_m)
        config = SimulatorConfig(time_scale=args.time_scale, err_format=args.err_format, pretty_replies=args.pretty,
                                 rail_axis=rail_axis, rail_mount_xyz_m=args.rail_mount_xyz_m, rail_deviation=deviation)
        sim = ArmSimulator(host=args.host, port=args.port, config=config)
        sim.start()
    except (OSError, ValueError) as exc:
        print(f"simulator: cannot start on {args.host}:{args.port}: {exc}", file=sys.stderr)
        return 2
    print(f"RM65 simulator on {args.host}:{sim.port}"
          + (f", rail of {args.rail_length_m:g} m" if rail_axis is not None else "") + " (Ctrl-C to stop)", flush=True)
    signal.sigwait(stop_signals)
    sim.stop()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
