"""The controller simulator's TCP side: listening, one thread per client, sending replies and events.

:class:`TcpServer` is a part of :class:`~rm65_sim.simulator.ArmSimulator`: it binds
``host:port`` (127.0.0.1 by default), accepts clients (or refuses them while a refusal is
injected), decodes their ``\\r\\n``-framed JSON with :class:`~rm65_driver.protocol.messages.FrameDecoder`
and hands every message to the simulator's ``_handle``; it also starts the motion thread.
"""
from __future__ import annotations

import logging
import socket
import struct
import threading
import time
from typing import Any, Callable, Self

from rm65_driver.protocol import messages as P
from rm65_sim.config import SimulatorConfig

_log = logging.getLogger("rm65_sim.simulator")  # one logger for all parts of the simulator


class Connection:
    """One client connection: its socket, frame decoder and a send lock (replies and events interleave)."""

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



class TcpServer:
    """Life cycle and networking of :class:`~rm65_sim.simulator.ArmSimulator` (state lives there)."""

    host: str
    config: SimulatorConfig
    connection_count: int
    _requested_port: int
    _bound_port: int | None
    _server: socket.socket | None
    _threads: list[threading.Thread]
    _running: threading.Event
    _lock: threading.RLock
    _changed: threading.Condition
    _conns: dict[int, Connection]
    _next_conn_id: int
    _refuse: int
    _motion_loop: Callable[[], None]
    _handle: Callable[[Connection, dict[str, Any], float], None]
    _halt_motions_of: Callable[[int], None]

    # ------------------------------------------------------------------------------------
    # life cycle
    # ------------------------------------------------------------------------------------
    def start(self) -> Self:
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

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    @property
    def port(self) -> int:
        """The bound port (also after :meth:`stop`: a restarted controller binds it again)."""
        return self._requested_port if self._bound_port is None else self._bound_port

    @property
    def client_count(self) -> int:
        with self._lock:
            return sum(1 for c in self._conns.values() if c.alive)

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
            # Blocking reads: Connection.close (a drop, stop()) shuts the socket down, which ends recv;
            # no per-connection polling, so hundreds of clients cost nothing while idle.
            sock.settimeout(None)
            # ...but a client that stops reading must not block the replies to everyone else for ever
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, struct.pack("ll", 2, 0))
            with self._lock:
                conn = Connection(self._next_conn_id, sock, peer)
                self._next_conn_id += 1
                self._conns[conn.id] = conn
                self.connection_count += 1
            t = threading.Thread(target=self._serve, args=(conn,), name=f"sim-conn-{conn.id}", daemon=True)
            t.start()
            self._threads = [x for x in self._threads if x.is_alive()] + [t]

    def _serve(self, conn: Connection) -> None:
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
                if not self.config.keep_moving_on_disconnect:
                    self._halt_motions_of(conn.id)
                self._changed.notify_all()

    def _reply(self, conn: Connection, msg: dict[str, Any]) -> None:
        conn.send(msg, self.config.pretty_replies)

    def _send_to(self, conn_id: int, msg: dict[str, Any]) -> None:
        with self._lock:
            conn = self._conns.get(conn_id)
        if conn is not None:
            conn.send(msg, self.config.pretty_replies)
