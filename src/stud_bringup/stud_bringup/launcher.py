"""Process supervisor for the weld cell: start child processes, prefix and log their output, report
deaths, respawn, and stop everything on Ctrl-C. ROS-free (standard library only).

ROS 2's ``launch`` does this on a full install; it has no PyPI wheel, so :mod:`stud_bringup.launch`
builds on this module instead. Any command can be a child (a node's executable, ``ros2 bag play``,
the arm simulator); nothing here knows about ROS.

Process model
  * Every child runs in a session and process group of its own (``start_new_session``). A terminal's
    Ctrl-C therefore reaches only the launcher, which stops the children in a defined order; signals
    go to a child's whole group, so a child's own children (a ``ros2 run`` wrapper's node) get them too.
  * Stop sequence (Ctrl-C, SIGTERM or SIGHUP to the launcher, a required child's death, an ``exit_on``
    child's exit): SIGINT to every running child, wait up to ``sigint_timeout_s``; SIGTERM to those
    still alive, wait up to ``sigterm_timeout_s``; then SIGKILL. Another Ctrl-C while stopping skips
    to the next step. Processes left in a child's group after the child exits are killed: no orphans.
  * With ``setpriv`` (util-linux) on PATH every child also gets ``PR_SET_PDEATHSIG`` = SIGTERM, so
    even a launcher killed with SIGKILL does not leave its children running. The death signal fires
    when the *thread* that started the child ends: call :meth:`Launcher.run` from a thread that
    outlives the launch (normally the main thread, which also receives the signals).
  * stdout and stderr of a child are one pipe, read line by line: each line goes to our stdout as
    ``[name] line``, to ``<out_dir>/<name>.log``, and into a ring buffer of the last ``ring_lines``
    lines (shown when the child dies, see :meth:`Launcher.last_lines`).

Exit code of :meth:`Launcher.run`: 0 when the launch was stopped by a signal or ended by an
``exit_on`` child's successful exit (or every child finished) *and* every child ended well — exit
code 0, or stopped by our SIGINT within the grace period; 1 otherwise (a required child died, a child
failed and was not respawned back to health, a child needed SIGTERM/SIGKILL, an ``exit_on`` child
failed). The report names the child, its exit code or signal and its last lines.
"""
from __future__ import annotations

import collections
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence, TextIO

#: Exit statuses that mean "stopped as asked" after we sent SIGINT (rclpy nodes return 0, a Python
#: script dies of the re-raised KeyboardInterrupt (-SIGINT), shells return 128 + signal).
_CLEAN_STOP_CODES = frozenset({0, -signal.SIGINT, 128 + signal.SIGINT, -signal.SIGTERM, 128 + signal.SIGTERM})
_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


class LaunchError(Exception):
    """A child specification that cannot be launched (bad name, duplicate, unknown dependency)."""


@dataclass(frozen=True)
class ChildSpec:
    """One child process of a launch.

    ``argv``: the command (``argv[0]`` looked up on PATH). ``env``: variables added to (or, with a
    value of ``None``, removed from) the launcher's environment. ``required``: its death stops the
    launch with exit code 1. ``respawn``: restart it ``respawn_delay_s`` seconds after it ends, at
    most ``max_respawns`` times (-1: no limit); only when its respawns are used up does ``required``
    apply. ``exit_on``: its exit ends the launch (exit code 0 if it exited with 0, else 1), e.g. a
    sequencer that finished the job. ``ready_pattern``: a regular expression; a matching output line
    marks the child ready. ``start_after``: the name(s) of children whose ready lines this one waits
    for before it starts (at most ``start_timeout_s`` seconds; then it starts anyway, with a warning;
    a child without a ``ready_pattern`` counts as ready once it has been started).
    ``stack_dump_signal``: a signal that makes the child print its threads' stacks and go on
    (``stud_common.stacks``: SIGUSR1 for our nodes); sent when it outlives its SIGINT grace period,
    so the log shows where it is stuck. ``None``: the child does not have one (SIGUSR1 would kill it).
    """

    name: str
    argv: Sequence[str]
    env: Mapping[str, str | None] = field(default_factory=dict)
    cwd: str | None = None
    required: bool = False
    respawn: bool = False
    max_respawns: int = 3
    respawn_delay_s: float = 1.0
    exit_on: bool = False
    ready_pattern: str | None = None
    start_after: str | Sequence[str] | None = None
    start_timeout_s: float = 30.0
    stack_dump_signal: int | None = None

    def __post_init__(self) -> None:
        if not _NAME_RE.match(self.name or ""):
            raise LaunchError(f"child name {self.name!r}: use letters, digits, '_', '.', '-' (it names the log file)")
        if not self.argv or not all(isinstance(a, str) for a in self.argv):
            raise LaunchError(f"child {self.name}: argv must be a non-empty list of strings, got {self.argv!r}")
        if self.max_respawns < -1 or self.respawn_delay_s < 0 or self.start_timeout_s < 0:
            raise LaunchError(f"child {self.name}: max_respawns >= -1, respawn_delay_s >= 0, start_timeout_s >= 0")
        if isinstance(self.start_after, str):
            object.__setattr__(self, "start_after", (self.start_after,))
        elif self.start_after is not None:
            object.__setattr__(self, "start_after", tuple(self.start_after) or None)
        if self.ready_pattern is not None:
            try:
                re.compile(self.ready_pattern)
            except re.error as exc:
                raise LaunchError(f"child {self.name}: bad ready_pattern {self.ready_pattern!r}: {exc}") from None


@dataclass(frozen=True)
class ChildOutcome:
    """How a child ended (its last instance). ``returncode``: negative = killed by that signal,
    ``None`` = never started. ``stopped_by``: the strongest signal the launcher sent it, if any."""

    name: str
    pid: int | None
    returncode: int | None
    respawns: int
    stopped_by: str | None
    ok: bool
    note: str = ""


def describe_returncode(returncode: int | None) -> str:
    """``exit code 3`` / ``signal SIGKILL`` / ``not started``."""
    if returncode is None:
        return "not started"
    if returncode < 0:
        try:
            return f"signal {signal.Signals(-returncode).name}"
        except ValueError:
            return f"signal {-returncode}"
    return f"exit code {returncode}"


def group_members(pgid: int) -> list[int]:
    """Live (non-zombie) processes in process group ``pgid``, from /proc; elsewhere a best guess."""
    proc = Path("/proc")
    if not proc.is_dir():
        try:
            os.killpg(pgid, 0)
            return [pgid]
        except (ProcessLookupError, PermissionError):
            return []
    members = []
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rfind(")") + 2:].split()  # after "pid (comm) ": state ppid pgrp ...
        if len(fields) > 2 and fields[0] not in ("Z", "X") and int(fields[2]) == pgid:
            members.append(int(entry.name))
    return members


class _Child:
    """Run-time state of one child (all instances)."""

    def __init__(self, spec: ChildSpec, log_path: Path, ring_lines: int):
        self.spec = spec
        self.log_path = log_path
        self.ring: collections.deque[tuple[int, str]] = collections.deque(maxlen=ring_lines)
        self.seq = 0                  # number of lines read so far (all instances)
        self.instance_first_seq = 0   # seq of the current instance's first line
        self.ready = threading.Event()
        self.ready_rx = re.compile(spec.ready_pattern) if spec.ready_pattern else None
        self.popen: subprocess.Popen | None = None
        self.reader: threading.Thread | None = None
        self.state = "pending"        # pending, waiting, running, respawn_wait, exited, skipped
        self.started_at = 0.0
        self.respawn_at = 0.0
        self.wait_deadline = 0.0
        self.respawns = 0
        self.returncode: int | None = None
        self.stop_signal: int | None = None
        self.note = ""

    @property
    def pid(self) -> int | None:
        return self.popen.pid if self.popen is not None else None

    @property
    def process(self) -> subprocess.Popen:
        """The running (or ended) instance; only asked of a child that has been started."""
        assert self.popen is not None, f"{self.spec.name} has not been started"
        return self.popen


class Launcher:
    """Start ``specs`` as child processes, supervise them, stop them; see the module docstring.

    ``out_dir`` receives ``<name>.log`` per child and ``launch.log`` (the launcher's own messages).
    ``echo``: where prefixed lines go (``None``: nowhere but the log files).
    """

    def __init__(self, specs: Sequence[ChildSpec], out_dir: str | os.PathLike, *, sigint_timeout_s: float = 10.0,
                 sigterm_timeout_s: float = 5.0, ring_lines: int = 40, report_lines: int = 15,
                 echo: TextIO | None = sys.stdout, pdeathsig: bool = True, tick_s: float = 0.05):
        names = [s.name for s in specs]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise LaunchError(f"duplicate child names: {', '.join(dupes)}")
        for s in specs:
            for dep in s.start_after or ():
                if dep not in names:
                    raise LaunchError(f"child {s.name}: start_after names '{dep}', which is not in this launch")
                if dep == s.name:
                    raise LaunchError(f"child {s.name}: cannot start after itself")
        if "launch" in names:
            raise LaunchError("'launch' is reserved for the launcher's own log")
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.sigint_timeout_s = sigint_timeout_s
        self.sigterm_timeout_s = sigterm_timeout_s
        self.sigkill_timeout_s = 5.0
        self.report_lines = report_lines
        self.tick_s = tick_s
        self._echo_stream = echo
        self._setpriv = shutil.which("setpriv") if pdeathsig and sys.platform.startswith("linux") else None
        self._children = {s.name: _Child(s, self.out_dir / f"{s.name}.log", ring_lines) for s in specs}
        self._cond = threading.Condition()
        self._out_lock = threading.Lock()
        self._log: TextIO | None = None  # <out_dir>/launch.log, open while run() runs
        self._signals: list[int] = []        # appended by signal handlers (list.append is atomic)
        self._stop_requested: str | None = None
        self._stop_reason = ""
        self._exit_code = 0
        self._t0 = time.monotonic()
        self.outcomes: dict[str, ChildOutcome] = {}

    # -- public helpers -------------------------------------------------------------------------
    def request_stop(self, reason: str = "stop requested") -> None:
        """Stop the launch as Ctrl-C would (thread-safe; for callers other than signal handlers)."""
        self._stop_requested = reason

    def pids(self) -> dict[str, int]:
        """Current pid of every child that is running."""
        return {n: c.pid for n, c in self._children.items() if c.state == "running" and c.pid is not None}

    def last_lines(self, name: str, n: int | None = None, current_only: bool = False) -> list[str]:
        """The last ``n`` (default: all kept) output lines of child ``name``; with ``current_only``
        only those of its current (or last) instance, not of instances before a respawn."""
        child = self._children[name]
        with self._cond:
            first = child.instance_first_seq if current_only else 0
            lines = [text for seq, text in child.ring if seq >= first]
        return lines if n is None else lines[-n:]

    def wait_for_line(self, name: str, pattern: str, timeout_s: float) -> re.Match | None:
        """Block until the current instance of child ``name`` prints a line matching ``pattern``
        (lines already printed count, as far as the ring buffer reaches). Returns the match, or
        ``None`` after ``timeout_s``. Thread-safe: call it while :meth:`run` runs elsewhere."""
        rx = re.compile(pattern)
        child = self._children[name]
        deadline = time.monotonic() + timeout_s
        with self._cond:
            seen = child.instance_first_seq
            while True:
                for seq, text in child.ring:
                    if seq >= seen and (m := rx.search(text)):
                        return m
                seen = child.seq
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._cond.wait(remaining)

    # -- the launch -----------------------------------------------------------------------------
    def run(self) -> int:
        """Start the children, supervise until something ends the launch, stop everything, report.
        Installs SIGINT/SIGTERM/SIGHUP handlers while it runs (main thread only)."""
        self._log = open(self.out_dir / "launch.log", "a", encoding="utf-8")
        previous = self._install_signal_handlers()
        try:
            self._say(f"starting {len(self._children)} processes, logs in {self.out_dir}")
            for child in self._children.values():
                if child.spec.start_after is None:
                    self._start(child)
                else:
                    child.state = "waiting"
                    child.wait_deadline = time.monotonic() + child.spec.start_timeout_s
            self._supervise()
            self._stop_all()
        finally:
            # Whatever happened above (an exception included), nothing we started keeps running.
            self._kill_everything_left()
            self._restore_signal_handlers(previous)
            self._report()
            self._log.close()
            self._log = None
        return self._exit_code

    def _supervise(self) -> None:
        while not self._stop_reason:  # (a required child may have failed to start already)
            if self._signals:
                signum = self._signals.pop(0)
                self._end(f"{signal.Signals(signum).name} received", 0)
                return
            if self._stop_requested is not None:
                self._end(self._stop_requested, 0)
                return
            now = time.monotonic()
            for child in self._children.values():
                if child.state == "running" and child.popen is not None and child.popen.poll() is not None:
                    self._on_exit(child)
                    if self._stop_reason:
                        return
                elif child.state == "waiting":
                    self._maybe_start_waiting(child, now)
                elif child.state == "respawn_wait" and now >= child.respawn_at:
                    self._start(child)
            if self._stop_reason:
                return
            if all(c.state in ("exited", "skipped") for c in self._children.values()):
                self._end("every process has ended", 0)
                return
            time.sleep(self.tick_s)

    def _maybe_start_waiting(self, child: _Child, now: float) -> None:
        deps = [self._children[n] for n in child.spec.start_after or ()]
        # without a ready pattern a dependency is ready once started (it may be a one-shot step that has ended)
        not_ready = [d for d in deps if not (d.ready.is_set() or (d.ready_rx is None and d.popen is not None))]
        gone = [d for d in not_ready if d.state in ("exited", "skipped")]
        if not not_ready:
            self._start(child)
        elif gone:
            child.state, child.note = "skipped", f"not started: {gone[0].spec.name} ended before it was ready"
            self._say(f"{child.spec.name} {child.note}")
            if child.spec.required:
                self._end(f"required {child.spec.name} could not start", 1)
        elif now >= child.wait_deadline:
            self._say(f"{', '.join(d.spec.name for d in not_ready)} not ready after "
                      f"{child.spec.start_timeout_s:g} s: starting {child.spec.name} anyway")
            self._start(child)

    def _end(self, reason: str, code: int) -> None:
        if not self._stop_reason:
            self._stop_reason = reason
            self._exit_code = max(self._exit_code, code)

    # -- starting -------------------------------------------------------------------------------
    def _start(self, child: _Child) -> None:
        spec = child.spec
        argv = list(spec.argv)
        if self._setpriv:
            argv = [self._setpriv, "--pdeathsig", "TERM", "--", *argv]
        env = dict(os.environ)
        env.setdefault("PYTHONUNBUFFERED", "1")  # a Python child's prints arrive line by line
        for key, value in spec.env.items():
            if value is None:
                env.pop(key, None)
            else:
                env[key] = str(value)
        log = open(child.log_path, "ab")
        instance = child.respawns + 1
        log.write(f"--- {time.strftime('%Y-%m-%d %H:%M:%S')} start #{instance}: {' '.join(spec.argv)}\n".encode())
        log.flush()
        with self._cond:
            child.instance_first_seq = child.seq
        child.ready.clear()
        child.returncode, child.stop_signal, child.note = None, None, ""
        child.started_at = time.monotonic()
        try:
            child.popen = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                           stderr=subprocess.STDOUT, env=env, cwd=spec.cwd, start_new_session=True)
        except OSError as exc:
            log.close()
            child.popen = None
            self._add_line(child, f"cannot start {spec.argv[0]}: {exc.strerror or exc}", echo=True)
            child.state, child.returncode = "exited", 127
            child.note = "could not be started"
            self._after_death(child, 127)
            return
        child.state = "running"
        child.reader = threading.Thread(target=self._read, args=(child, child.process.stdout, log),
                                        name=f"launch-{spec.name}", daemon=True)
        child.reader.start()
        again = f" (respawn {child.respawns})" if child.respawns else ""
        self._say(f"started {spec.name}{again}: pid {child.process.pid}")

    def _read(self, child: _Child, pipe, log) -> None:
        try:
            for raw in iter(pipe.readline, b""):
                log.write(raw if raw.endswith(b"\n") else raw + b"\n")
                log.flush()
                self._add_line(child, raw.decode("utf-8", "replace").rstrip("\r\n"), echo=True)
        except (OSError, ValueError):
            pass
        finally:
            pipe.close()
            log.close()

    def _add_line(self, child: _Child, text: str, echo: bool) -> None:
        with self._cond:
            child.ring.append((child.seq, text))
            child.seq += 1
            if child.ready_rx is not None and not child.ready.is_set() and child.ready_rx.search(text):
                child.ready.set()
            self._cond.notify_all()
        if echo:
            self._write(f"[{child.spec.name}] {text}")

    # -- deaths ---------------------------------------------------------------------------------
    def _on_exit(self, child: _Child) -> None:
        rc = child.process.returncode
        child.state, child.returncode = "exited", rc
        self._drain_and_clean(child)
        self._after_death(child, rc)

    def _after_death(self, child: _Child, rc: int) -> None:
        spec = child.spec
        ran = time.monotonic() - child.started_at if child.started_at else 0.0
        what = f"{spec.name} {'exited' if rc == 0 else 'died'} ({describe_returncode(rc)}, pid {child.pid}, " \
               f"after {ran:.1f} s)"
        if spec.exit_on:
            if rc == 0:
                self._say(f"{what}: its job is done, stopping the launch")
                self._end(f"{spec.name} finished", 0)
            else:
                self._say_with_lines(f"{what}: stopping the launch", child)
                self._end(f"{spec.name} failed", 1)
            return
        if rc != 0:
            self._say_with_lines(what, child)
        else:
            self._say(what)
        if spec.respawn and (spec.max_respawns < 0 or child.respawns < spec.max_respawns):
            child.respawns += 1
            child.state, child.respawn_at = "respawn_wait", time.monotonic() + spec.respawn_delay_s
            limit = "no limit" if spec.max_respawns < 0 else f"{child.respawns}/{spec.max_respawns}"
            self._say(f"respawning {spec.name} in {spec.respawn_delay_s:g} s ({limit})")
            return
        if spec.respawn:
            child.note = f"gave up after {child.respawns} respawns"
            self._say(f"{spec.name}: {child.note}")
        if spec.required:
            self._end(f"required {spec.name} ended ({describe_returncode(rc)})", 1)

    # -- stopping -------------------------------------------------------------------------------
    def _stop_all(self) -> None:
        self._say(f"stopping: {self._stop_reason}")
        for child in self._children.values():
            if child.state in ("pending", "waiting", "respawn_wait"):
                child.state = "skipped" if child.popen is None else "exited"
                if child.popen is None:
                    child.note = "not started"
        steps = [(signal.SIGINT, self.sigint_timeout_s), (signal.SIGTERM, self.sigterm_timeout_s),
                 (signal.SIGKILL, self.sigkill_timeout_s)]
        for step, (sig, timeout_s) in enumerate(steps):
            alive = [c for c in self._children.values() if c.state == "running"]
            if not alive:
                return
            if step > 0:
                self._say(f"{', '.join(c.spec.name for c in alive)} still running: {sig.name}")
            for child in alive:
                child.stop_signal = sig
                self._signal_group(child, sig)
            deadline = time.monotonic() + timeout_s
            while time.monotonic() < deadline:
                for child in alive:
                    if child.state == "running" and child.process.poll() is not None:
                        child.state, child.returncode = "exited", child.process.returncode
                        self._drain_and_clean(child)
                if all(c.state != "running" for c in alive):
                    break
                if self._signals:  # another Ctrl-C: do not wait, go to the next step
                    self._signals.clear()
                    break
                time.sleep(self.tick_s)
            if sig == signal.SIGINT:
                self._report_stuck([c for c in alive if c.state == "running"])

    def _report_stuck(self, stuck: list[_Child], wait_s: float = 1.0) -> None:
        """Children still running after the SIGINT grace period: ask those that can for their
        threads' stacks, and put what they print into the launch log before escalating."""
        asked = [c for c in stuck if c.spec.stack_dump_signal is not None]
        for child in stuck:
            self._say(f"{child.spec.name} did not stop on SIGINT within {self.sigint_timeout_s:g} s"
                      + ("; its threads:" if child in asked else ""))
        first = {}
        for child in asked:
            first[child.spec.name] = child.seq
            try:
                os.kill(child.process.pid, child.spec.stack_dump_signal)  # type: ignore[arg-type]
            except (ProcessLookupError, PermissionError):
                pass
        if asked:
            time.sleep(wait_s)
        for child in asked:
            with self._cond:
                lines = [text for seq, text in child.ring if seq >= first[child.spec.name]]
            for line in lines:
                self._say(f"  {child.spec.name} | {line}")

    def _signal_group(self, child: _Child, sig: int) -> None:
        try:
            os.killpg(child.process.pid, sig)
        except (ProcessLookupError, PermissionError):
            pass

    def _drain_and_clean(self, child: _Child) -> None:
        """After a child's exit: read its last lines (they belong in the report), kill what it left
        in its group (such a process may hold the pipe open), read the rest."""
        if child.reader is not None:
            child.reader.join(timeout=0.5)
        self._kill_leftovers(child)
        if child.reader is not None:
            child.reader.join(timeout=1.0)

    def _kill_leftovers(self, child: _Child) -> None:
        """The child has exited: whatever it left in its process group would be an orphan."""
        if child.popen is None:
            return
        left = group_members(child.process.pid)
        if left:
            self._say(f"{child.spec.name} left {len(left)} process(es) behind ({', '.join(map(str, left))}): SIGKILL")
            try:
                os.killpg(child.process.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass

    def _kill_everything_left(self) -> None:
        for child in self._children.values():
            if child.popen is None:
                continue
            if child.process.poll() is None:
                child.stop_signal = signal.SIGKILL
                self._signal_group(child, signal.SIGKILL)
                try:
                    child.process.wait(timeout=self.sigkill_timeout_s)
                except subprocess.TimeoutExpired:
                    pass
                child.state, child.returncode = "exited", child.process.returncode
            self._kill_leftovers(child)

    # -- signals --------------------------------------------------------------------------------
    def _install_signal_handlers(self) -> dict:
        if threading.current_thread() is not threading.main_thread():
            return {}
        previous = {}
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
            previous[sig] = signal.signal(sig, lambda signum, _frame: self._signals.append(signum))
        return previous

    @staticmethod
    def _restore_signal_handlers(previous: dict) -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    # -- reporting ------------------------------------------------------------------------------
    def _report(self) -> None:
        for name, child in self._children.items():
            ok, note = self._judge(child)
            self.outcomes[name] = ChildOutcome(name, child.pid, child.returncode, child.respawns,
                                               signal.Signals(child.stop_signal).name if child.stop_signal else None,
                                               ok, note)
            if not ok:
                self._exit_code = max(self._exit_code, 1)
        self._say(f"summary: {self._stop_reason or 'stopped'}; exit code {self._exit_code}")
        width = max((len(n) for n in self._children), default=0)
        for o in self.outcomes.values():
            how = describe_returncode(o.returncode)
            if o.stopped_by:
                how = f"stopped by {o.stopped_by}: {how}"
            extra = f", respawned {o.respawns}x" if o.respawns else ""
            self._say(f"  {o.name:<{width}}  {'ok    ' if o.ok else 'FAILED'}  {how}{extra}"
                      f"{'; ' + o.note if o.note else ''}")

    def _judge(self, child: _Child) -> tuple[bool, str]:
        rc, note = child.returncode, child.note
        if child.state == "skipped" or rc is None:
            return True, note or "not started"  # a required child that could not start has ended the launch with 1
        if child.stop_signal is None:
            return rc == 0, note
        if child.stop_signal != signal.SIGINT:
            return False, note or f"did not stop on SIGINT within {self.sigint_timeout_s:g} s"
        return rc in _CLEAN_STOP_CODES, note

    def _say_with_lines(self, text: str, child: _Child) -> None:
        lines = self.last_lines(child.spec.name, self.report_lines, current_only=True)
        self._say(f"{text}; last {len(lines)} lines:" if lines else f"{text}; it printed nothing")
        for line in lines:
            self._say(f"  | {line}")

    def _say(self, text: str) -> None:
        if self._log is not None:
            stamp = time.time()
            self._log.write(f"{time.strftime('%H:%M:%S', time.localtime(stamp))}.{int(stamp * 1000) % 1000:03d} "
                            f"{text}\n")
            self._log.flush()
        self._write(f"[launch] {text}")

    def _write(self, line: str) -> None:
        if self._echo_stream is None:
            return
        with self._out_lock:
            try:
                self._echo_stream.write(line + "\n")
                self._echo_stream.flush()
            except (OSError, ValueError):
                pass  # our stdout went away (a closed pipe): the log files still have everything
