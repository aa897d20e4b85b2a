"""Blocking, thread-safe client of the RM-65 controller (JSON over TCP, see :mod:`.messages`).

One reader thread per connection decodes the stream and dispatches each message:

* ``current_trajectory_state`` (unsolicited arrival message) -> the motion waiters;
* anything else -> the oldest pending request whose expected reply tag it carries (replies have
  no request id; the controller answers in order, so FIFO per tag is the matching rule).

Sending takes ``_send_lock`` only for the ``sendall`` itself — never while waiting for a reply —
so :meth:`ArmClient.stop` reaches the controller within milliseconds even while another thread
blocks in :meth:`ArmClient.move_joints_and_wait` (the e-stop latency test measures this). A stop
also wakes every motion waiter at once with :class:`ArmStopped`.

Units are SI (rad, m) on this API; :mod:`.messages` converts at the wire. ``§`` cites docs/RM65_PROTOCOL.md.
"""
from __future__ import annotations

import logging
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from rm65_driver.protocol import messages as P

_log = logging.getLogger(__name__)


class ArmError(Exception):
    """Base class of every error raised by :class:`ArmClient`."""


class ArmConnectionError(ArmError):
    """Not connected, connection refused / lost, or reconnection gave up."""


class ArmTimeout(ArmError):
    """No reply (or no motion arrival) within the timeout."""


class ArmCommandError(ArmError):
    """The controller refused a command or a motion failed; ``code`` is its error code (0 if none)."""

    def __init__(self, command: str, code: int = 0, text: str = "", codes: Sequence[int] = ()):
        self.command = command
        self.code = int(code)
        self.codes = tuple(codes) or ((self.code,) if self.code else ())
        self.text = text or (P.describe_error(code) if code else "refused, no error code reported")
        super().__init__(f"{command}: {self.text}")


class ArmStopped(ArmError):
    """A motion wait ended because :meth:`ArmClient.stop` (or an e-stop) was called."""


@dataclass
class _Pending:
    tags: frozenset[str]
    event: threading.Event = field(default_factory=threading.Event)
    reply: dict[str, Any] | None = None
    traj_seq: int = 0  # arrival messages seen when the reply was dispatched
    error: ArmError | None = None


class ArmClient:
    """Client of one controller at ``host:port`` (default loopback; the real arm is 192.168.1.18).

    ``reply_timeout_s``: wait for a command's reply (the SDK uses ~0.5 s). ``connect_timeout_s``:
    TCP connect. ``backoff_s``: (first, max) delay between reconnection attempts, doubling.
    """

    def __init__(
        self,
        host: str = "127.0.0.1",
        port: int = P.DEFAULT_PORT,
        connect_timeout_s: float = 2.0,
        reply_timeout_s: float = 1.0,
        backoff_s: tuple[float, float] = (0.05, 2.0),
    ):
        self.host = host
        self.port = int(port)
        self.connect_timeout_s = connect_timeout_s
        self.reply_timeout_s = reply_timeout_s
        self.backoff_s = backoff_s

        self._sock: socket.socket | None = None
        self._reader: threading.Thread | None = None
        self._send_lock = threading.Lock()  # held only during sendall
        self._state_lock = threading.Lock()  # connection, pending table, trajectory events
        self._connect_lock = threading.Lock()  # one (re)connect at a time
        self._pending: deque[_Pending] = deque()
        self._traj_cond = threading.Condition(self._state_lock)
        self._traj_events: deque[tuple[int, P.TrajectoryEvent]] = deque(maxlen=32)  # (seq, event)
        self._traj_seq = 0
        self._stop_seq = 0
        self._generation = 0  # connection generation, bumped on every connect and loss
        self._paused = False
        self.on_disconnect: Callable[[str], None] | None = None
        self.last_error: str = ""
        self.last_stop_sent_at: float | None = None  # time.monotonic() of the last stop send

    # ------------------------------------------------------------------------------------
    # connection
    # ------------------------------------------------------------------------------------
    @property
    def connected(self) -> bool:
        with self._state_lock:
            return self._sock is not None

    def connect(self, timeout_s: float | None = None) -> None:
        """Open the TCP connection and check that the controller answers ``get_current_arm_state``."""
        with self._connect_lock:
            self._close_socket("reconnecting")
            t = self.connect_timeout_s if timeout_s is None else timeout_s
            try:
                sock = socket.create_connection((self.host, self.port), timeout=t)
            except OSError as exc:
                raise ArmConnectionError(f"cannot connect to {self.host}:{self.port}: {exc}") from exc
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            sock.settimeout(None)
            with self._state_lock:
                self._sock = sock
                self._generation += 1
                gen = self._generation
                self._traj_events.clear()
            self._reader = threading.Thread(target=self._read_loop, args=(sock, gen), name="rm65-reader", daemon=True)
            self._reader.start()
        try:
            self.get_state(timeout_s=max(t, self.reply_timeout_s))
        except ArmError as exc:
            self._close_socket(f"no answer after connect: {exc}")
            raise ArmConnectionError(f"{self.host}:{self.port} accepted the connection but did not answer: "
                                     f"{exc}") from exc
        _log.info("connected to RM65 controller at %s:%d", self.host, self.port)

    def reconnect(self, deadline_s: float) -> None:
        """Reconnect with exponential back-off until connected or ``deadline_s`` seconds passed."""
        end = time.monotonic() + deadline_s
        delay = self.backoff_s[0]
        attempt = 0
        while True:
            attempt += 1
            try:
                self.connect(timeout_s=min(self.connect_timeout_s, max(0.05, end - time.monotonic())))
                _log.info("reconnected after %d attempt(s)", attempt)
                return
            except ArmConnectionError as exc:
                left = end - time.monotonic()
                if left <= 0:
                    raise ArmConnectionError(f"gave up reconnecting after {attempt} attempts: {exc}") from exc
                _log.warning("reconnect attempt %d failed (%s); retrying in %.2f s", attempt, exc, min(delay, left))
                time.sleep(min(delay, left))
                delay = min(delay * 2, self.backoff_s[1])

    def close(self) -> None:
        self._close_socket("closed by the client")

    def __enter__(self) -> "ArmClient":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def _close_socket(self, reason: str) -> None:
        with self._state_lock:
            sock = self._sock
            if sock is None:
                return
            self._sock = None
            self._generation += 1
            self.last_error = reason
            pending = list(self._pending)
            self._pending.clear()
            self._traj_cond.notify_all()
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        sock.close()
        for p in pending:
            p.error = ArmConnectionError(f"connection lost: {reason}")
            p.event.set()
        if self.on_disconnect is not None:
            try:
                self.on_disconnect(reason)
            except Exception:  # a callback must not break the client
                _log.exception("on_disconnect callback failed")

    def _read_loop(self, sock: socket.socket, gen: int) -> None:
        decoder = P.FrameDecoder()
        reason = "connection closed by the controller"
        while True:
            try:
                data = sock.recv(65536)
            except OSError as exc:
                reason = f"read error: {exc}"
                break
            if not data:
                break
            for msg in decoder.feed(data):
                self._dispatch(msg)
        with self._state_lock:
            current = self._generation == gen and self._sock is sock
        if current:
            _log.warning("controller connection lost: %s", reason)
            self._close_socket(reason)

    def _dispatch(self, msg: dict[str, Any]) -> None:
        with self._state_lock:
            if P.is_trajectory_event(msg):
                self._traj_seq += 1
                self._traj_events.append((self._traj_seq, P.parse_trajectory_event(msg)))
                self._traj_cond.notify_all()
                return
            tag = P.reply_tag(msg)
            for p in self._pending:
                if tag in p.tags:
                    self._pending.remove(p)
                    p.reply = msg
                    p.traj_seq = self._traj_seq
                    p.event.set()
                    return
        _log.debug("unsolicited controller message ignored: %s", str(msg)[:200])

    # ------------------------------------------------------------------------------------
    # request / reply
    # ------------------------------------------------------------------------------------
    def _send(self, msg: dict[str, Any]) -> None:
        data = P.encode(msg)
        with self._state_lock:
            sock = self._sock
        if sock is None:
            raise ArmConnectionError(f"not connected to {self.host}:{self.port} "
                                     f"({self.last_error or 'never connected'})")
        with self._send_lock:
            try:
                sock.sendall(data)
                return
            except OSError as exc:
                err = ArmConnectionError(f"send of {msg.get('command')} failed: {exc}")
        self._close_socket(str(err))  # outside the send lock: a failed send ends the connection
        raise err

    def _request_raw(self, msg: dict[str, Any], timeout_s: float | None = None) -> _Pending:
        command = str(msg["command"])
        pending = _Pending(P.expected_reply_tags(command))
        with self._state_lock:
            if self._sock is None:
                raise ArmConnectionError(f"not connected to {self.host}:{self.port} "
                                         f"({self.last_error or 'never connected'})")
            self._pending.append(pending)
        try:
            self._send(msg)
        except ArmError:
            with self._state_lock:
                if pending in self._pending:
                    self._pending.remove(pending)
            raise
        t = self.reply_timeout_s if timeout_s is None else timeout_s
        if not pending.event.wait(t):
            with self._state_lock:
                if pending in self._pending:
                    self._pending.remove(pending)
            if pending.reply is None and pending.error is None:
                raise ArmTimeout(f"no reply to {command} within {t:.2f} s")
        if pending.error is not None:
            raise pending.error
        return pending

    def request(self, msg: dict[str, Any], timeout_s: float | None = None) -> dict[str, Any]:
        """Send ``msg`` and return the controller's reply (the next message with the expected tag)."""
        return self._request_raw(msg, timeout_s).reply  # type: ignore[return-value]

    def command(self, msg: dict[str, Any], timeout_s: float | None = None) -> dict[str, Any]:
        """Like :meth:`request`, and raise :class:`ArmCommandError` when the result key is false."""
        reply = self.request(msg, timeout_s)
        if not P.reply_ok(msg["command"], reply):
            raise self._refusal(msg["command"])
        return reply

    def _refusal(self, command: str) -> ArmCommandError:
        """Build the error for a refused command, with the controller's error codes if it has any."""
        codes: tuple[int, ...] = ()
        try:
            codes = self.get_state().error_codes
        except ArmError:
            pass
        if codes:
            return ArmCommandError(command, codes[0], "; ".join(P.describe_error(c) for c in codes), codes)
        return ArmCommandError(command, 0, "refused by the controller (no error code in the state)")

    # ------------------------------------------------------------------------------------
    # state
    # ------------------------------------------------------------------------------------
    def get_state(self, timeout_s: float | None = None) -> P.ArmStateReading:
        """Joints (rad), tool pose in the work frame (m, rad) and the controller's error codes."""
        reply = self.request(P.get_current_arm_state(), timeout_s)
        try:
            return P.parse_arm_state(reply)
        except P.ProtocolError as exc:
            raise ArmCommandError("get_current_arm_state", 0, str(exc)) from exc

    def current_trajectory(self, timeout_s: float | None = None) -> str:
        """Type of the motion the controller is executing: ``"movej"``, ``"movel"`` … or ``"none"``."""
        return str(self.request(P.get_arm_current_trajectory(), timeout_s).get("type", "none"))

    def wait_idle(self, timeout_s: float, poll_s: float = 0.02) -> None:
        """Poll until the controller reports no running trajectory (after a reconnect, say)."""
        end = time.monotonic() + timeout_s
        while self.current_trajectory() != "none":
            if time.monotonic() > end:
                raise ArmTimeout(f"arm still moving after {timeout_s:.1f} s")
            time.sleep(poll_s)

    def controller_info(self) -> dict[str, Any]:
        """Run the official SDK's connect-time queries (§1.11); returns ``{command: reply}``.

        A query without a reply maps to ``None`` (older controller generations lack some).
        """
        out: dict[str, Any] = {}
        for name in P.HANDSHAKE_COMMANDS:
            try:
                out[name] = self.request({"command": name})
            except ArmTimeout:
                out[name] = None
        return out

    # ------------------------------------------------------------------------------------
    # motion
    # ------------------------------------------------------------------------------------
    @property
    def stop_count(self) -> int:
        """Number of stops requested so far (pass to ``move_*_and_wait(stop_count=...)``)."""
        with self._state_lock:
            return self._stop_seq

    def _move_and_wait(self, msg: dict[str, Any], timeout_s: float, stop_count: int | None) -> None:
        self._connected_move_and_wait([msg], timeout_s, stop_count, None)

    def _connected_move_and_wait(self, msgs: Sequence[dict[str, Any]], timeout_s: float, stop_count: int | None,
                                 on_handover: Callable[[int], None] | None) -> None:
        """Send ``msgs`` as one trajectory (``trajectory_connect`` 1 on all but the last) and wait for its end.

        An arrival with ``trajectory_connect`` 1 is a hand-over to the next motion: ``on_handover(i)``
        is called (i = 1, 2, ... motions done), without the client's lock; the trajectory ends
        with the ``len(msgs)``-th arrival, or with one that says every queued motion is done (0)
        once the controller also reports no running trajectory.
        """
        msgs = [dict(m, trajectory_connect=int(i < len(msgs) - 1)) for i, m in enumerate(msgs)]
        name = msgs[-1]["command"]
        with self._state_lock:
            stop_seq = self._stop_seq if stop_count is None else stop_count
            gen = self._generation
            if stop_seq != self._stop_seq:
                raise ArmStopped(f"{name} not sent: a stop was requested")
        seen = -1
        for i, msg in enumerate(msgs):
            pending = self._request_raw(msg)
            if not P.reply_ok(msg["command"], pending.reply or {}):
                if i > 0:  # the motions already accepted wait for this one: drop them
                    self._send(P.set_arm_stop())
                raise self._refusal(msg["command"])
            seen = pending.traj_seq if seen < 0 else seen
        with self._state_lock:
            stopped_meanwhile = self._stop_seq != stop_seq
        if stopped_meanwhile:
            # A stop was requested while this command was on its way: it must not run.
            self._send(P.set_arm_stop())
            raise ArmStopped(f"{name} stopped right after it was accepted")
        # arrival messages before our first acknowledgement belong to older motions
        end = time.monotonic() + timeout_s
        frozen_left: float | None = None
        done = 0
        early_end = False
        while True:
            handed_over = False
            with self._traj_cond:
                if self._stop_seq != stop_seq:
                    raise ArmStopped(f"{name} interrupted by a stop")
                if self._generation != gen or self._sock is None:
                    raise ArmConnectionError(f"connection lost during {name} ({self.last_error})")
                nxt = next(((seq, ev) for seq, ev in self._traj_events if seq > seen and ev.device == 0), None)
                if nxt is not None:
                    seen, ev = nxt
                    if not ev.success:
                        break
                    done += 1
                    if done >= len(msgs):
                        return
                    if ev.trajectory_connect == 0:
                        early_end = True  # "all done" before every segment reported: see below
                        break
                    handed_over = True
                else:
                    now = time.monotonic()
                    if self._paused:  # a paused motion does not use up its time budget
                        frozen_left = end - now if frozen_left is None else frozen_left
                        end = now + max(frozen_left, 0.05)
                    else:
                        frozen_left = None
                    left = end - now
                    if left <= 0:
                        raise ArmTimeout(f"{name} did not arrive within {timeout_s:.1f} s")
                    self._traj_cond.wait(min(left, 0.05))
            if handed_over and on_handover is not None:
                on_handover(done)
        if early_end:
            # A controller that reports a connected trajectory once, at its end -- or one that ran the
            # first segment alone: the arm must be still before the caller acts on "arrived" (a weld
            # trigger), so ask it.
            self.wait_idle(max(end - time.monotonic(), 0.1))
            return
        raise self._refusal(name)  # decoded outside the lock: it queries the state

    def move_joints_and_wait(self, q_rad: ArrayLike, v: int, timeout_s: float = 30.0,
                             stop_count: int | None = None) -> None:
        """``movej`` to ``q_rad`` (6,) at ``v`` % and wait for arrival.

        Raises :class:`ArmStopped` if a stop is requested while waiting — or, with ``stop_count``
        (a value of :attr:`stop_count` taken earlier), if any stop was requested since then: a
        caller that checked "not cancelled" and then moves cannot race a concurrent stop.
        """
        self._move_and_wait(P.movej(q_rad, v), timeout_s, stop_count)

    def move_pose_and_wait(self, pose6: Sequence[float], v: int, timeout_s: float = 30.0,
                           stop_count: int | None = None) -> None:
        """``movej_p`` (joint-space move) to a tool pose ``[m, m, m, rad, rad, rad]`` in the work frame."""
        self._move_and_wait(P.movej_p(pose6, v), timeout_s, stop_count)

    def move_linear_and_wait(self, pose6: ArrayLike, v: int, timeout_s: float = 30.0,
                             stop_count: int | None = None) -> None:
        """``movel`` (straight line) to a tool pose ``[m, m, m, rad, rad, rad]`` in the work frame."""
        self._move_and_wait(P.movel(pose6, v), timeout_s, stop_count)

    def move_linear_path_and_wait(self, segments: Sequence[tuple[ArrayLike, int]], timeout_s: float = 30.0,
                                  stop_count: int | None = None,
                                  on_handover: Callable[[int], None] | None = None) -> None:
        """``movel`` through ``(pose6, v)`` segments as one connected trajectory, without stopping where they join.

        Each segment keeps its own speed; where one continues the other along a line the controller
        only slows to the next one's speed (a corner is passed at rest: no blend radius is sent).
        ``on_handover(i)`` is called when segment i ends and the next begins.
        """
        self._connected_move_and_wait([P.movel(p6, v) for p6, v in segments], timeout_s, stop_count, on_handover)

    def move_axis_and_wait(self, msg: dict[str, Any], device: int, timeout_s: float = 30.0,
                           stop_count: int | None = None) -> None:
        """An external axis's position move and the wait for its arrival.

        The rail's move is :func:`rm65_driver.rail.axis.expand_set_pos`.

        The axis reports its end with an arrival message of its own ``device`` (4: expansion joint,
        3: lift); arm waits ignore those and this one ignores the arm's. A refusal raises
        :class:`ArmCommandError`, a stopped move (``trajectory_state`` false) too; a stop requested
        meanwhile (:meth:`stop`, or any since ``stop_count``) :class:`ArmStopped`.
        """
        name = str(msg["command"])
        with self._state_lock:
            stop_seq = self._stop_seq if stop_count is None else stop_count
            gen = self._generation
            if stop_seq != self._stop_seq:
                raise ArmStopped(f"{name} not sent: a stop was requested")
        pending = self._request_raw(msg)
        if not P.reply_ok(name, pending.reply or {}):
            raise ArmCommandError(name, 0, "refused by the controller (target outside the travel, the axis moving, "
                                           "or no such axis)")
        seen, end = pending.traj_seq, time.monotonic() + timeout_s
        with self._traj_cond:
            while True:
                if self._stop_seq != stop_seq:
                    raise ArmStopped(f"{name} interrupted by a stop")
                if self._generation != gen or self._sock is None:
                    raise ArmConnectionError(f"connection lost during {name} ({self.last_error})")
                ev = next((e for seq, e in self._traj_events if seq > seen and e.device == device), None)
                if ev is not None:
                    if ev.success:
                        return
                    raise ArmCommandError(name, 0, "the axis stopped before its target (trajectory_state false)")
                left = end - time.monotonic()
                if left <= 0:
                    raise ArmTimeout(f"{name} did not arrive within {timeout_s:.1f} s")
                self._traj_cond.wait(min(left, 0.05))

    # -- stop fast path ------------------------------------------------------------------
    def stop(self, wait_reply: bool = True) -> None:
        """Trajectory stop (``set_arm_stop``), sent at once; wakes every motion waiter.

        The bytes go out before anything else is waited on: the send lock is never held across
        a wait. With ``wait_reply`` the controller's acknowledgement is awaited afterwards.
        """
        self._stop_with(P.set_arm_stop(), wait_reply)

    def slow_stop(self, wait_reply: bool = True) -> None:
        self._stop_with(P.set_arm_slow_stop(), wait_reply)

    def _stop_with(self, msg: dict[str, Any], wait_reply: bool) -> None:
        with self._state_lock:
            self._stop_seq += 1
            self._paused = False
            self._traj_cond.notify_all()
        if wait_reply:
            t0 = time.monotonic()
            self.command(msg)
            self.last_stop_sent_at = t0
        else:
            self._send(msg)
            self.last_stop_sent_at = time.monotonic()

    def pause(self) -> None:
        """``set_arm_pause``: the motion halts on its path, resumable; motion waits keep waiting."""
        self.command(P.set_arm_pause())
        with self._state_lock:
            self._paused = True

    def resume(self) -> None:
        """``set_arm_continue`` after :meth:`pause`."""
        self.command(P.set_arm_continue())
        with self._state_lock:
            self._paused = False
            self._traj_cond.notify_all()

    @property
    def paused(self) -> bool:
        with self._state_lock:
            return self._paused

    def clear_errors(self) -> None:
        self.command(P.clear_system_err())

    # ------------------------------------------------------------------------------------
    # IO and frames
    # ------------------------------------------------------------------------------------
    def set_do(self, io: int, value: bool, tool: bool = False) -> None:
        """Set controller DO ``io`` (1..4) or tool-flange DO (1..2) high/low."""
        self.command(P.set_tool_DO_state(io, value) if tool else P.set_DO_state(io, value))

    def set_io_output_mode(self, io: int, tool: bool = False) -> None:
        """Switch a multiplexed IO (Gen-3 controller IO1..4 / tool IO1..2) to output mode."""
        self.command(P.set_tool_IO_mode(io, 1) if tool else P.set_IO_mode(io, 1))

    def get_do(self, io: int, tool: bool = False) -> int:
        """Read back an output level."""
        if tool:
            reply = self.request(P.get_tool_IO_state())
            return int(reply["IO_State"][io - 1])
        reply = self.request(P.get_IO_state(io))
        return int(reply["IO_state"])

    def set_tool_frame(self, name: str, tool_pose6: Sequence[float], payload_kg: float = 0.0,
                       com_m: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """Define tool frame ``name`` (flange -> tool) and make it the active one, then verify."""
        self.command(P.set_manual_tool_frame(name, tool_pose6, payload_kg, com_m))
        self.command(P.set_change_tool_frame(name))
        name_now, pose_now = self.current_tool_frame()
        if name_now != name or not np.allclose(pose_now, tool_pose6, atol=2e-6):
            raise ArmCommandError("set_change_tool_frame", 0x100F,
                                  f"active tool frame is {name_now!r} {pose_now}, expected {name!r}")

    def current_tool_frame(self) -> tuple[str, np.ndarray]:
        reply = self.request(P.get_current_tool_frame())
        return str(reply.get("tool_name", "")), P.pose_from_wire(reply["pose"])

    def current_work_frame(self) -> tuple[str, np.ndarray]:
        reply = self.request(P.get_current_work_frame())
        return str(reply.get("frame_name", "")), P.pose_from_wire(reply["pose"])

    def set_work_frame(self, name: str) -> None:
        self.command(P.set_change_work_frame(name))
