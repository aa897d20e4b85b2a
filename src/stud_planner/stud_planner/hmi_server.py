"""The HMI's web server: HTTP (the page, static files, ``/healthz``) and one WebSocket (``/ws``).

ROS-free and stdlib-only (no pip dependency): the RFC 6455 handshake and framing are implemented
here, just what a browser needs — text frames (fragmented or not), ping/pong, close — and nothing
else (no extensions, no binary messages: those are refused with close code 1003).

Threads: one accept thread (``serve_forever``); per HTTP request one handler thread; per WebSocket
client that same handler thread reads, and a writer thread sends. :meth:`HmiServer.publish` never
blocks on a client: every client has an outbox that keeps only the *latest* message of each
retained type (a slow browser skips overlay frames instead of stalling the ROS executor), while
replies are queued in order. :meth:`HmiServer.stop` closes every connection and joins every thread.

Security (the page's buttons move the arm; docs/HMI.md says it for operators):

* the server binds to 127.0.0.1 by default;
* **Host check** (DNS rebinding): a request -- HTTP or WebSocket -- whose ``Host`` names anything but
  an address this server serves (the loopback names, the bind address, this computer's name when
  bound beyond loopback, the local address the request came in on) or the host of an
  ``allowed_origins`` entry is refused (403). A page on evil.example whose DNS name is re-pointed at
  127.0.0.1 still sends ``Host: evil.example:PORT``;
* **Origin check**: browsers let any page open a WebSocket to any host, so a handshake whose
  ``Origin`` is neither this server's own (``Host``) nor in ``allowed_origins`` is refused (403).
  Clients that send no ``Origin`` (not a browser: scripts, other HMIs) are accepted;
* **access token**: with ``access_token`` set, a WebSocket handshake must carry it (``/ws?token=``,
  or ``Authorization: Bearer``), else 403. Bound beyond loopback without a token, every client is
  *view only*: commands are answered ``ok: false`` and never reach ``on_command``;
* **bounded messages**: a message over ``MAX_INCOMING_BYTES`` closes the connection with 1009, one
  nested deeper than ``MAX_MESSAGE_DEPTH`` with 1008 (before it is parsed: 64 KB of brackets must
  not exhaust the parser's recursion), invalid UTF-8 with 1007.
"""
from __future__ import annotations

import base64
import hashlib
import hmac
import http.server
import ipaddress
import itertools
import json
import logging
import mimetypes
import os
import re
import socket
import socketserver
import struct
import threading
import time
from collections import OrderedDict
from pathlib import Path
from typing import Any, Callable
from urllib.parse import parse_qs, urlsplit

from stud_common.strict_json import dumps, json_safe

__all__ = ["HmiServer", "WebSocketConnection", "WebSocketError", "json_safe", "to_json", "json_depth"]
_log = logging.getLogger(__name__)

WS_GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"  # RFC 6455 Sec. 1.3
OP_CONT, OP_TEXT, OP_BINARY, OP_CLOSE, OP_PING, OP_PONG = 0x0, 0x1, 0x2, 0x8, 0x9, 0xA
CLOSE_NORMAL, CLOSE_GOING_AWAY, CLOSE_PROTOCOL_ERROR, CLOSE_UNSUPPORTED = 1000, 1001, 1002, 1003
CLOSE_INVALID_DATA, CLOSE_POLICY, CLOSE_TOO_BIG = 1007, 1008, 1009
#: Largest message a browser may send us (commands are a few dozen bytes).
MAX_INCOMING_BYTES = 64 * 1024
#: Deepest nesting of a message's JSON (commands are flat objects).
MAX_MESSAGE_DEPTH = 16
#: Names that always mean this computer.
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")


class WebSocketError(Exception):
    """A protocol violation by the peer; ``code`` is the close code to answer with."""

    def __init__(self, code: int, reason: str):
        super().__init__(reason)
        self.code = code


# -- JSON -----------------------------------------------------------------------------------------
def to_json(obj: Any) -> str:
    """Strict, compact JSON text (no NaN tokens, which browsers' JSON.parse rejects):
    :func:`stud_common.strict_json.dumps`."""
    return dumps(obj, compact=True)


_JSON_STRING = re.compile(r'"(?:[^"\\]|\\.)*"')
_NOT_BRACKET = re.compile(r"[^\[\]{}]")


def json_depth(text: str) -> int:
    """The deepest nesting of arrays/objects in JSON ``text`` (brackets inside strings do not
    count), without parsing it: linear in the text, no recursion."""
    brackets = _NOT_BRACKET.sub("", _JSON_STRING.sub("", text))
    return max(itertools.accumulate(1 if c in "[{" else -1 for c in brackets), default=0)


# -- RFC 6455 framing -----------------------------------------------------------------------------
def accept_key(sec_websocket_key: str) -> str:
    """Sec-WebSocket-Accept for a client's Sec-WebSocket-Key (RFC 6455 Sec. 4.2.2)."""
    digest = hashlib.sha1((sec_websocket_key.strip() + WS_GUID).encode("ascii")).digest()
    return base64.b64encode(digest).decode("ascii")


def encode_frame(opcode: int, payload: bytes, fin: bool = True, mask: bytes | None = None) -> bytes:
    """One frame. Servers send unmasked frames; a client passes a 4-byte ``mask``."""
    head = bytes([(0x80 if fin else 0) | opcode])
    n = len(payload)
    mask_bit = 0x80 if mask is not None else 0
    if n < 126:
        head += bytes([mask_bit | n])
    elif n < 1 << 16:
        head += bytes([mask_bit | 126]) + struct.pack("!H", n)
    else:
        head += bytes([mask_bit | 127]) + struct.pack("!Q", n)
    if mask is not None:
        if len(mask) != 4:
            raise ValueError("a WebSocket mask is 4 bytes")
        return head + mask + apply_mask(payload, mask)
    return head + payload


def apply_mask(payload: bytes, mask: bytes) -> bytes:
    """XOR with the 4-byte mask (masking and unmasking are the same operation)."""
    if not payload:
        return b""
    n = len(payload)
    key = int.from_bytes((mask * (n // 4 + 1))[:n], "big")
    return (int.from_bytes(payload, "big") ^ key).to_bytes(n, "big")


def close_payload(code: int, reason: str = "") -> bytes:
    return struct.pack("!H", code) + reason.encode("utf-8")[:120]


def read_exact(sock_file, n: int) -> bytes:
    data = sock_file.read(n) if n else b""
    if len(data) != n:
        raise ConnectionError("connection closed mid-frame")
    return data


def read_frame(sock_file, require_mask: bool, max_bytes: int = MAX_INCOMING_BYTES) -> tuple[bool, int, bytes]:
    """Read one frame from a binary file object -> (fin, opcode, unmasked payload).

    ``require_mask``: a server must refuse unmasked client frames (RFC 6455 Sec. 5.1)."""
    b0, b1 = read_exact(sock_file, 2)
    fin, rsv, opcode = bool(b0 & 0x80), b0 & 0x70, b0 & 0x0F
    masked, n = bool(b1 & 0x80), b1 & 0x7F
    if rsv:
        raise WebSocketError(CLOSE_PROTOCOL_ERROR, "reserved bits set (no extension was negotiated)")
    if n == 126:
        n = struct.unpack("!H", read_exact(sock_file, 2))[0]
    elif n == 127:
        n = struct.unpack("!Q", read_exact(sock_file, 8))[0]
    if opcode >= 0x8 and (n > 125 or not fin):
        raise WebSocketError(CLOSE_PROTOCOL_ERROR, "control frames must be short and unfragmented")
    if require_mask and not masked:
        raise WebSocketError(CLOSE_PROTOCOL_ERROR, "client frames must be masked")
    if n > max_bytes:
        raise WebSocketError(CLOSE_TOO_BIG, f"frame of {n} bytes exceeds {max_bytes}")
    mask = read_exact(sock_file, 4) if masked else None
    payload = read_exact(sock_file, n)
    return fin, opcode, apply_mask(payload, mask) if mask else payload


# -- one WebSocket client -------------------------------------------------------------------------
class WebSocketConnection:
    """A connected browser: :meth:`send` queues (never blocks), a writer thread sends."""

    def __init__(self, sock: socket.socket, rfile, peer: str, max_fifo: int = 200, may_command: bool = True):
        self.sock = sock
        self.rfile = rfile
        self.peer = peer
        self.may_command = may_command  # False: view only (bound beyond loopback without a token)
        self.max_fifo = max_fifo
        self._cv = threading.Condition()
        self._latest: OrderedDict[str, bytes] = OrderedDict()  # retained type -> newest frame
        self._fifo: list[bytes] = []                           # in-order messages (replies, ...)
        self._closing: bytes | None = None
        self._closed = False
        self.writer = threading.Thread(target=self._write_loop, name=f"hmi-ws-writer {peer}", daemon=True)
        self.writer.start()

    # -- sending ---------------------------------------------------------------------------------
    def send(self, text: str, key: str | None = None) -> None:
        """Queue a text message. With ``key``, an unsent older message of that key is replaced."""
        frame = encode_frame(OP_TEXT, text.encode("utf-8"))
        with self._cv:
            if self._closed or self._closing is not None:
                return
            if key is None:
                if len(self._fifo) >= self.max_fifo:
                    self._fifo.pop(0)  # a client this far behind has lost the old ones anyway
                self._fifo.append(frame)
            else:
                self._latest.pop(key, None)
                self._latest[key] = frame
            self._cv.notify()

    def _send_raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def close(self, code: int = CLOSE_NORMAL, reason: str = "") -> None:
        """Send a close frame (after what is queued) and end the connection."""
        with self._cv:
            if self._closing is None and not self._closed:
                self._closing = encode_frame(OP_CLOSE, close_payload(code, reason))
            self._cv.notify()

    def _write_loop(self) -> None:
        try:
            while True:
                with self._cv:
                    while not (self._fifo or self._latest or self._closing or self._closed):
                        self._cv.wait()
                    if self._closed:
                        return
                    frames = self._fifo + list(self._latest.values())
                    self._fifo, self._latest = [], OrderedDict()
                    closing = self._closing
                for f in frames:
                    self._send_raw(f)
                if closing is not None:
                    self._send_raw(closing)
                    # Let the peer answer with its close frame; the reader then ends the socket.
                    self._shutdown(socket.SHUT_WR)
                    return
        except OSError:
            pass
        finally:
            self._mark_closed()

    def _shutdown(self, how: int) -> None:
        try:
            self.sock.shutdown(how)
        except OSError:
            pass

    def _mark_closed(self) -> None:
        with self._cv:
            self._closed = True
            self._cv.notify_all()

    def abort(self) -> None:
        """Drop the connection now (server stop): unblocks the reader and the writer."""
        self._mark_closed()
        self._shutdown(socket.SHUT_RDWR)

    @property
    def closed(self) -> bool:
        return self._closed

    # -- receiving -------------------------------------------------------------------------------
    def read_loop(self, on_text: Callable[["WebSocketConnection", str], None]) -> None:
        """Read frames until the connection ends; text messages go to ``on_text``."""
        parts: list[bytes] = []
        try:
            while not self._closed:
                fin, opcode, payload = read_frame(self.rfile, require_mask=True)
                if opcode == OP_PING:
                    with self._cv:
                        self._fifo.append(encode_frame(OP_PONG, payload))
                        self._cv.notify()
                elif opcode == OP_PONG:
                    pass
                elif opcode == OP_CLOSE:
                    code = struct.unpack("!H", payload[:2])[0] if len(payload) >= 2 else CLOSE_NORMAL
                    self.close(code if code in (CLOSE_NORMAL, CLOSE_GOING_AWAY) else CLOSE_NORMAL)
                    break
                elif opcode == OP_BINARY:
                    raise WebSocketError(CLOSE_UNSUPPORTED, "binary messages are not supported")
                elif opcode in (OP_TEXT, OP_CONT):
                    if (opcode == OP_TEXT) == bool(parts):
                        raise WebSocketError(CLOSE_PROTOCOL_ERROR, "unexpected continuation/text frame")
                    parts.append(payload)
                    if sum(map(len, parts)) > MAX_INCOMING_BYTES:
                        raise WebSocketError(CLOSE_TOO_BIG, f"message exceeds {MAX_INCOMING_BYTES} bytes")
                    if fin:
                        data, parts = b"".join(parts), []
                        try:
                            text = data.decode("utf-8")
                        except UnicodeDecodeError:
                            raise WebSocketError(CLOSE_INVALID_DATA, "text message is not UTF-8") from None
                        if len(text) > 2 * MAX_MESSAGE_DEPTH and json_depth(text) > MAX_MESSAGE_DEPTH:
                            raise WebSocketError(CLOSE_POLICY, f"message nests deeper than {MAX_MESSAGE_DEPTH}")
                        on_text(self, text)
                else:
                    raise WebSocketError(CLOSE_PROTOCOL_ERROR, f"unknown opcode {opcode:#x}")
        except WebSocketError as exc:
            _log.warning("WebSocket %s: %s", self.peer, exc)
            self.close(exc.code, str(exc))
        except (ConnectionError, OSError):
            pass
        finally:
            self.writer.join(timeout=2.0)
            self.abort()


# -- the server -----------------------------------------------------------------------------------
CommandHandler = Callable[[WebSocketConnection, dict], None]


class _ThreadingServer(socketserver.ThreadingMixIn, http.server.HTTPServer):
    daemon_threads = False       # handler threads are joined in server_close()
    block_on_close = True
    allow_reuse_address = True


class HmiServer:
    """HTTP + WebSocket server for the HMI page, on a background thread.

    ``on_command(conn, message)`` is called (on the client's thread) for every JSON object a
    browser sends; answer with :meth:`reply`. Messages published with ``retain=True`` (the
    default) are also sent to clients that connect later, newest per ``type``.
    """

    def __init__(self, static_dir: str | Path, host: str = "127.0.0.1", port: int = 8090,
                 on_command: CommandHandler | None = None, allowed_origins: list[str] | tuple = (),
                 hello: dict | None = None, access_token: str = ""):
        self.static_dir = Path(static_dir).resolve()
        if not (self.static_dir / "index.html").is_file():
            raise FileNotFoundError(f"HMI page not found: {self.static_dir / 'index.html'}")
        self.on_command = on_command
        self.allowed_origins = {o.rstrip("/").lower() for o in allowed_origins}
        self.hello = dict(hello or {})
        self._lock = threading.Lock()
        self._clients: set[WebSocketConnection] = set()
        self._retained: OrderedDict[str, str] = OrderedDict()
        self._sockets: set[socket.socket] = set()  # every open connection, HTTP or WebSocket
        self._started = time.monotonic()
        self._httpd = _ThreadingServer((host, port), self._handler_class())
        self._thread: threading.Thread | None = None
        self.access_token = access_token
        bind = self._httpd.server_address[0]
        self.loopback_only = _is_loopback(bind)
        #: without a token, a server reachable from the network shows but does not command
        self.commands_need_token = not self.loopback_only and not access_token
        self.served_names = self._served_names(bind, self.allowed_origins)

    @staticmethod
    def _served_names(bind: str, allowed_origins: set[str]) -> frozenset[str]:
        """Host names a browser may use for this server (the Host check, module docstring)."""
        names = set(LOOPBACK_NAMES)
        if bind not in ("", "0.0.0.0", "::"):
            names.add(bind.lower())
        if not _is_loopback(bind):
            for name in (socket.gethostname(), socket.getfqdn()):
                if name:
                    names.add(name.lower().rstrip("."))
        for origin in allowed_origins:
            if origin == "*":
                continue
            try:
                host = urlsplit(origin).hostname
            except ValueError:
                host = None
            if host:
                names.add(host.rstrip("."))
        return frozenset(names)

    def host_allowed(self, host: str | None, local_address: str = "") -> bool:
        """The Host check: ``host`` (the request's header, ``name[:port]``) names this server.
        ``local_address``: the address the request came in on (an IP literal of it is served).
        No Host header (HTTP/1.0 tools, not a browser) passes."""
        if host is None:
            return True
        try:
            name = urlsplit("//" + host.strip()).hostname
        except ValueError:
            return False
        if not name:
            return False
        name = name.rstrip(".")
        return name in self.served_names or (bool(local_address) and name == local_address.lower())

    def token_ok(self, path: str, authorization: str | None) -> bool:
        """With ``access_token`` set: the handshake carries it (``?token=`` or ``Authorization: Bearer``)."""
        if not self.access_token:
            return True
        given = parse_qs(urlsplit(path).query).get("token", [""])[0]
        if authorization and authorization.lower().startswith("bearer "):
            given = given or authorization[7:].strip()
        return hmac.compare_digest(given.encode("utf-8"), self.access_token.encode("utf-8"))

    @property
    def port(self) -> int:
        return self._httpd.server_address[1]

    @property
    def address(self) -> str:
        return f"http://{self._httpd.server_address[0]}:{self.port}/"

    @property
    def client_count(self) -> int:
        with self._lock:
            return len(self._clients)

    def start(self) -> "HmiServer":
        self._thread = threading.Thread(target=self._httpd.serve_forever, kwargs={"poll_interval": 0.2},
                                        name="hmi-http", daemon=True)
        self._thread.start()
        return self

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close every WebSocket (close code 1001), stop accepting, join all threads."""
        with self._lock:
            clients = list(self._clients)
        for c in clients:
            c.close(CLOSE_GOING_AWAY, "server shutting down")
        deadline = time.monotonic() + timeout_s
        for c in clients:
            c.writer.join(timeout=max(0.0, min(1.0, deadline - time.monotonic())))
            c.abort()  # the reader thread ends too, even if the peer never answers the close
        if self._thread is not None:
            self._httpd.shutdown()
            self._thread.join(timeout=max(0.1, deadline - time.monotonic()))
        with self._lock:
            sockets = list(self._sockets)
        for sock in sockets:  # idle HTTP connections (browsers pre-connect) must not hold a thread
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._httpd.server_close()  # joins the request threads (block_on_close)

    def __enter__(self) -> "HmiServer":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- messages --------------------------------------------------------------------------------
    def publish(self, message: dict, retain: bool = True) -> None:
        """Send ``message`` (a dict with a ``type``) to every client; JSON-safe (NaN -> null)."""
        text = to_json(message)
        key = str(message.get("type", "")) if retain else None
        with self._lock:
            if key:
                self._retained.pop(key, None)
                self._retained[key] = text
            clients = list(self._clients)
        for c in clients:
            c.send(text, key)

    def reply(self, conn: WebSocketConnection, message: dict) -> None:
        """Send ``message`` to one client, in order with its other replies."""
        conn.send(to_json(message))

    # -- internals -------------------------------------------------------------------------------
    def _origin_allowed(self, origin: str | None, host: str | None) -> bool:
        if not origin:
            return True  # not a browser
        origin = origin.rstrip("/").lower()
        if origin in self.allowed_origins or "*" in self.allowed_origins:
            return True
        return bool(host) and urlsplit(origin).netloc == host.lower()

    def _add(self, conn: WebSocketConnection) -> None:
        with self._lock:
            self._clients.add(conn)
            retained = list(self._retained.items())
        hello = {"type": "hello", **self.hello}
        if not conn.may_command:
            hello.update(commands=[], read_only=True)
        conn.send(to_json(hello))
        for key, text in retained:
            conn.send(text, key)
        _log.info("WebSocket client %s connected (%d connected)", conn.peer, self.client_count)

    def _remove(self, conn: WebSocketConnection) -> None:
        with self._lock:
            self._clients.discard(conn)
        _log.info("WebSocket client %s disconnected (%d connected)", conn.peer, self.client_count)

    def _on_text(self, conn: WebSocketConnection, text: str) -> None:
        try:
            msg = json.loads(text)
        except ValueError:
            self.reply(conn, {"type": "reply", "ok": False, "error": "message is not JSON"})
            return
        except RecursionError:  # json_depth bounds nesting first; this is the last line of defence
            raise WebSocketError(CLOSE_POLICY, "message nests too deeply") from None
        if not isinstance(msg, dict):
            self.reply(conn, {"type": "reply", "ok": False, "error": "message is not a JSON object"})
            return
        if not conn.may_command:
            self.reply(conn, {"type": "reply", "cmd": msg.get("cmd"), "id": msg.get("id"), "ok": False,
                              "error": "view only: this HMI listens beyond loopback without an access_token, so it "
                                       "takes no commands (set access_token and open the page with ?token=...)"})
            return
        if self.on_command is None:
            self.reply(conn, {"type": "reply", "cmd": msg.get("cmd"), "id": msg.get("id"), "ok": False,
                              "error": "this server takes no commands"})
            return
        try:
            self.on_command(conn, msg)
        except Exception as exc:  # a bug in a handler must not drop the operator's connection
            _log.exception("command handler failed on %r", msg)
            self.reply(conn, {"type": "reply", "cmd": msg.get("cmd"), "id": msg.get("id"), "ok": False,
                              "error": f"internal error: {exc}"})

    def health(self) -> dict:
        return {"ok": True, "clients": self.client_count, "uptime_s": round(time.monotonic() - self._started, 1)}

    def _handler_class(self):
        server = self

        class Handler(http.server.BaseHTTPRequestHandler):
            server_version = "stud-hmi/1"
            protocol_version = "HTTP/1.0"  # one request per connection: nothing idles at shutdown
            timeout = 10  # a half-open HTTP connection cannot hold a thread forever

            def setup(self):
                super().setup()
                with server._lock:
                    server._sockets.add(self.connection)

            def finish(self):
                with server._lock:
                    server._sockets.discard(self.connection)
                try:
                    super().finish()
                except OSError:
                    pass  # the peer is gone; nothing left to flush

            def handle(self):
                try:
                    super().handle()
                except (ConnectionError, socket.timeout):
                    pass  # a browser dropping a connection is not an error

            def log_message(self, fmt, *args):  # quiet: the node logs what matters
                _log.debug("%s %s", self.address_string(), fmt % args)

            def _host_refused(self) -> bool:
                """The Host check (DNS rebinding): answer 403 and say so when the Host is not ours."""
                host = self.headers.get("Host")
                if server.host_allowed(host, self.connection.getsockname()[0]):
                    return False
                _log.warning("refused %s %s with Host %r (not an address this server serves; allowed_origins "
                             "adds names)", self.command, urlsplit(self.path).path, host)
                self._error(403, f"Host {host!r} is not served here (a DNS-rebinding page?); add the name to "
                                 "allowed_origins if it is yours")
                return True

            def do_GET(self):
                if self._host_refused():
                    return
                path = urlsplit(self.path).path
                if path == "/ws":
                    self._websocket()
                elif path == "/healthz":
                    self._send(200, to_json(server.health()).encode(), "application/json")
                else:
                    self._static(path)

            def do_HEAD(self):
                if not server.host_allowed(self.headers.get("Host"), self.connection.getsockname()[0]):
                    self.send_response(403)
                    self.end_headers()
                    return
                self.send_response(200 if urlsplit(self.path).path in ("/", "/healthz") else 404)
                self.end_headers()

            def _send(self, code: int, body: bytes, ctype: str, extra: dict | None = None) -> None:
                self.send_response(code)
                self.send_header("Content-Type", ctype)
                self.send_header("Content-Length", str(len(body)))
                self.send_header("Cache-Control", "no-store")
                for k, v in (extra or {}).items():
                    self.send_header(k, v)
                self.end_headers()
                self.wfile.write(body)

            def _error(self, code: int, text: str, extra: dict | None = None) -> None:
                self._send(code, (text + "\n").encode(), "text/plain; charset=utf-8", extra)

            def _static(self, path: str) -> None:
                rel = "index.html" if path in ("", "/") else path.lstrip("/")
                target = (server.static_dir / rel).resolve()
                if server.static_dir not in target.parents or not target.is_file():
                    self._error(404, f"not found: {path}")
                    return
                ctype = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
                if ctype.startswith("text/") or ctype in ("application/javascript", "application/json"):
                    ctype += "; charset=utf-8"
                self._send(200, target.read_bytes(), ctype)

            def _websocket(self) -> None:
                h = self.headers
                upgrade = (h.get("Upgrade") or "").lower()
                connection = [t.strip().lower() for t in (h.get("Connection") or "").split(",")]
                key = h.get("Sec-WebSocket-Key")
                if upgrade != "websocket" or "upgrade" not in connection:
                    self._error(400, "expected a WebSocket upgrade (Upgrade: websocket, Connection: Upgrade)")
                    return
                if h.get("Sec-WebSocket-Version") != "13":
                    self._error(426, "WebSocket version 13 only", {"Sec-WebSocket-Version": "13"})
                    return
                try:
                    if not key or len(base64.b64decode(key, validate=True)) != 16:
                        raise ValueError
                except ValueError:
                    self._error(400, "bad Sec-WebSocket-Key")
                    return
                if not server._origin_allowed(h.get("Origin"), h.get("Host")):
                    _log.warning("refused WebSocket from origin %s (Host %s)", h.get("Origin"), h.get("Host"))
                    self._error(403, f"origin {h.get('Origin')} not allowed (set the allowed_origins parameter)")
                    return
                if not server.token_ok(self.path, h.get("Authorization")):
                    _log.warning("refused WebSocket from %s: missing or wrong access token", self.client_address[0])
                    self._error(403, "access token missing or wrong (open the page with ?token=...)")
                    return
                self.send_response(101, "Switching Protocols")
                self.send_header("Upgrade", "websocket")
                self.send_header("Connection", "Upgrade")
                self.send_header("Sec-WebSocket-Accept", accept_key(key))
                self.end_headers()
                self.wfile.flush()
                self.connection.settimeout(None)  # a WebSocket idles between messages
                self.close_connection = True
                peer = f"{self.client_address[0]}:{self.client_address[1]}"
                conn = WebSocketConnection(self.connection, self.rfile, peer,
                                           may_command=not server.commands_need_token)
                server._add(conn)
                try:
                    conn.read_loop(server._on_text)
                finally:
                    server._remove(conn)

        return Handler


def _is_loopback(bind: str) -> bool:
    if bind == "localhost":
        return True
    try:
        return ipaddress.ip_address(bind).is_loopback
    except ValueError:
        return False


def default_static_dir() -> Path:
    """The page shipped with the package (installed as package data)."""
    return Path(os.path.dirname(os.path.abspath(__file__))) / "hmi_static"
