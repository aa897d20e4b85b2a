"""The HMI's web server: HTTP (the page, static files, ``/healthz``) and one WebSocket (``/ws``).

ROS-free. The WebSocket protocol (RFC 6455: handshake, framing, fragmentation, ping/pong, close
codes, masking, UTF-8 checks, the size limit) is the ``websockets`` library's asyncio server; its
``process_request`` hook answers the plain HTTP requests and runs the security checks below before
the library accepts a handshake. No extension is negotiated (no compression); binary messages are
refused with close code 1003.

Threads: one, ``hmi-server``, runs the asyncio event loop (every connection is a task in it).
:meth:`HmiServer.publish` and :meth:`HmiServer.reply` may be called from any thread and never block
on a client: every client has an outbox that keeps only the *latest* message of each retained type
(a slow browser skips overlay frames instead of stalling the ROS executor), while replies are
queued in order; a writer task per client drains it. ``on_command`` runs on the event loop, so it
must not block (the node hands the command to its executor through a queue).
:meth:`HmiServer.stop` closes every connection (1001) and joins the thread.

Security (the page's buttons move the arm; docs/HMI.md says it for operators):

* the server binds to 127.0.0.1 by default;
* **Host check** (DNS rebinding): a request -- HTTP or WebSocket -- whose ``Host`` names anything but
  an address this server serves (the loopback names, the bind address, this computer's name when
  bound beyond loopback, the local address the request came in on) or the host of an
  ``allowed_origins`` entry is refused (403). A page on evil.example whose DNS name is re-pointed at
  127.0.0.1 still sends ``Host: evil.example:PORT``. (The library leaves this check to the
  application: ``ServerProtocol.process_request`` "doesn't check the Host header".)
* **Origin check**: browsers let any page open a WebSocket to any host, so a handshake whose
  ``Origin`` is neither this server's own (``Host``) nor in ``allowed_origins`` is refused (403).
  Clients that send no ``Origin`` (not a browser: scripts, other HMIs) are accepted;
* **access token**: with ``access_token`` set, a WebSocket handshake must carry it (``/ws?token=``,
  or ``Authorization: Bearer``), else 403. Bound beyond loopback without a token, every client is
  *view only*: commands are answered ``ok: false`` and never reach ``on_command``;
* **bounded messages**: a message over ``MAX_INCOMING_BYTES`` closes the connection with 1009 (the
  library's ``max_size``), one nested deeper than ``MAX_MESSAGE_DEPTH`` with 1008 (checked before
  it is parsed: 64 KB of brackets must not exhaust the parser's recursion), invalid UTF-8 with 1007.
"""
from __future__ import annotations

import asyncio
import hmac
import http
import ipaddress
import itertools
import json
import logging
import mimetypes
import os
import re
import socket
import threading
import time
import weakref
from collections import OrderedDict, deque
from pathlib import Path
from typing import Any, Callable
from urllib.parse import parse_qs, unquote, urlsplit

from websockets.asyncio.server import Server, ServerConnection, serve
from websockets.datastructures import Headers
from websockets.exceptions import ConnectionClosed
from websockets.frames import CloseCode
from websockets.http11 import Request, Response
from websockets.protocol import State

from stud_common.strict_json import dumps, json_safe
from stud_hmi.guards import MAX_MESSAGE_BURST, MAX_MESSAGES_PER_S, MessageRate, inside_folder, read_png

__all__ = ["HmiServer", "WebSocketConnection", "WebSocketError", "json_safe", "to_json", "json_depth"]
_log = logging.getLogger(__name__)

#: Largest message a browser may send us (commands are a few dozen bytes).
MAX_INCOMING_BYTES = 64 * 1024
#: Deepest nesting of a message's JSON (commands are flat objects).
MAX_MESSAGE_DEPTH = 16
#: Names that always mean this computer.
LOOPBACK_NAMES = ("localhost", "127.0.0.1", "::1")
#: A connection that sends no complete HTTP request in this long is dropped [s].
REQUEST_TIMEOUT_S = 10.0
#: A peer that does not answer our close frame in this long is disconnected [s] (stop() waits for it).
CLOSE_TIMEOUT_S = 2.0
SERVER_HEADER = "stud-hmi/1"
#: Where the latest inspection overlay is served (the PNG an InspectionResult names in overlay_file).
INSPECTION_OVERLAY_URL = "/inspection/overlay.png"


class WebSocketError(Exception):
    """A message the server refuses; ``code`` is the close code to answer with."""

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


# -- one WebSocket client -------------------------------------------------------------------------
class WebSocketConnection:
    """A connected browser: :meth:`send` queues (from any thread, never blocks), :meth:`write_loop`
    (a task on the server's event loop) sends."""

    def __init__(self, ws: ServerConnection, may_command: bool = True, max_fifo: int = 200):
        self.ws = ws
        self.peer = _address_text(ws.remote_address)
        self.may_command = may_command  # False: view only (bound beyond loopback without a token)
        self.rate = MessageRate()       # how fast this browser may send
        self._loop = asyncio.get_running_loop()
        self._lock = threading.Lock()
        self._latest: OrderedDict[str, str] = OrderedDict()  # retained type -> newest text
        self._fifo: deque[str] = deque(maxlen=max_fifo)       # in-order messages (replies, ...); a
        self._ready = asyncio.Event()                          # client this far behind lost the old ones
        self._closed = False

    def send(self, text: str, key: str | None = None) -> None:
        """Queue a text message. With ``key``, an unsent older message of that key is replaced."""
        with self._lock:
            if self._closed:
                return
            if key is None:
                self._fifo.append(text)
            else:
                self._latest.pop(key, None)
                self._latest[key] = text
        try:
            self._loop.call_soon_threadsafe(self._ready.set)
        except RuntimeError:
            pass  # the server's loop has ended: nobody to send to

    async def write_loop(self) -> None:
        """Send what is queued until the connection closes (ConnectionClosed ends it)."""
        while True:
            await self._ready.wait()
            self._ready.clear()
            with self._lock:
                texts = [*self._fifo, *self._latest.values()]
                self._fifo.clear()
                self._latest.clear()
            for text in texts:
                await self.ws.send(text)

    def mark_closed(self) -> None:
        with self._lock:
            self._closed = True

    @property
    def closed(self) -> bool:
        return self._closed


class _Connection(ServerConnection):
    """The library's connection, with its ``close_timeout`` applied to closes the peer starts too.

    After a close handshake the *client* began, websockets half-closes the TCP connection and waits
    for the client's end with no deadline (``close_timeout`` bounds only closes this side starts):
    a client that never closes its socket would keep its connection. Here it is dropped at the
    deadline the library sets (``close_deadline``) when the close frame arrives."""

    _drop_at: asyncio.TimerHandle | None = None

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        if self.close_deadline is not None and self._drop_at is None:
            self._drop_at = self.loop.call_at(self.close_deadline, self.transport.abort)

    def connection_lost(self, exc: Exception | None) -> None:
        if self._drop_at is not None:
            self._drop_at.cancel()
        super().connection_lost(exc)


# -- the server -----------------------------------------------------------------------------------
CommandHandler = Callable[[WebSocketConnection, dict], None]


class HmiServer:
    """HTTP + WebSocket server for the HMI page, on a background thread.

    ``on_command(conn, message)`` is called (on the server's event loop: it must not block) for
    every JSON object a browser sends; answer with :meth:`reply`. Messages published with
    ``retain=True`` (the default) are also sent to clients that connect later, newest per ``type``.
    The socket is bound in the constructor (a busy port raises ``OSError`` there).
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
        self._connections: weakref.WeakSet[ServerConnection] = weakref.WeakSet()  # every TCP connection
        self._exposed: dict[str, Path] = {}  # URL path -> the one file served there (expose_png)
        self._exposed_version = itertools.count(1)
        self._started = time.monotonic()
        self._sock = socket.create_server((host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._server: Server | None = None
        self._thread: threading.Thread | None = None
        self.access_token = access_token
        bind = self._sock.getsockname()[0]
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
        return self._sock.getsockname()[1]

    @property
    def address(self) -> str:
        return f"http://{self._sock.getsockname()[0]}:{self.port}/"

    @property
    def client_count(self) -> int:
        """Browsers connected now (a WebSocket whose closing handshake has begun no longer counts)."""
        with self._lock:
            return sum(c.ws.protocol.state is State.OPEN for c in self._clients)

    def start(self) -> "HmiServer":
        ready = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(ready,), name="hmi-server", daemon=True)
        self._thread.start()
        if not ready.wait(10.0) or self._server is None:
            raise RuntimeError("the HMI server's event loop did not start")
        return self

    def _run(self, ready: threading.Event) -> None:
        loop = self._loop = asyncio.new_event_loop()
        try:
            self._server = loop.run_until_complete(self._open())
        finally:
            ready.set()
        try:
            if self._server is not None:
                loop.run_until_complete(self._server.wait_closed())
        finally:
            loop.run_until_complete(loop.shutdown_default_executor())
            loop.close()

    async def _open(self) -> Server:
        return await serve(
            self._serve_client, sock=self._sock, process_request=self._process_request,
            server_header=SERVER_HEADER, compression=None, max_size=MAX_INCOMING_BYTES,
            open_timeout=REQUEST_TIMEOUT_S, close_timeout=CLOSE_TIMEOUT_S,
            create_connection=self._new_connection)  # type: ignore[arg-type]  # called like the class it defaults to

    def _new_connection(self, *args, **kwargs) -> ServerConnection:
        conn = _Connection(*args, **kwargs)
        self._connections.add(conn)
        return conn

    def stop(self, timeout_s: float = 5.0) -> None:
        """Close every WebSocket (close code 1001), stop accepting, end the server's thread."""
        if self._thread is None or self._loop is None:
            self._sock.close()
            return
        deadline = time.monotonic() + timeout_s
        if not self._loop.is_closed():
            future = asyncio.run_coroutine_threadsafe(self._shutdown(), self._loop)
            try:
                future.result(timeout=timeout_s)
            except Exception:  # (timeout) a peer holds on: drop every connection
                _log.warning("HMI server: connections did not close in %.1f s, dropping them", timeout_s)
                try:
                    self._loop.call_soon_threadsafe(self._abort_all)
                except RuntimeError:
                    pass
        self._thread.join(timeout=max(0.5, deadline - time.monotonic()))

    async def _shutdown(self) -> None:
        assert self._server is not None
        self._server.close()  # 1001 to open WebSockets, 503 to handshakes under way
        for conn in list(self._connections):
            if conn.protocol.state is State.CONNECTING and conn.request is None:
                conn.transport.abort()  # connected, but no request yet (browsers pre-connect)
        await self._server.wait_closed()

    def _abort_all(self) -> None:
        for conn in list(self._connections):
            conn.transport.abort()

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

    def expose_png(self, url_path: str, file: str | Path, within: str | Path | None = None) -> str | None:
        """Serve the PNG ``file`` at ``url_path`` from now on, in place of the one served there before.

        The URL names no file: a request is matched to ``url_path`` exactly and gets ``file``, so no
        part of a URL reaches the file system (no traversal). Only a regular, readable file of at
        most ``MAX_EXPOSED_BYTES`` that starts with the PNG signature is served (checked here and at
        every request); anything else withdraws ``url_path`` (404) and returns None. With
        ``access_token`` set the request must carry it, as the WebSocket does (the image shows the
        part, as the camera overlay does). Returns the URL to give the page: ``url_path?v=<n>``, a
        new ``n`` each call, so that the browser fetches the new image. ``within``: the file must
        lie in this folder once links are resolved (a message naming any other PNG is refused).
        """
        path = Path(file)
        with self._lock:
            self._exposed.pop(url_path, None)
        if within is not None and not inside_folder(path, Path(within)):
            return None
        if read_png(path, signature_only=True) is None:
            return None
        with self._lock:
            self._exposed[url_path] = path
            return f"{url_path}?v={next(self._exposed_version)}"

    def health(self) -> dict:
        return {"ok": True, "clients": self.client_count, "uptime_s": round(time.monotonic() - self._started, 1)}

    # -- WebSocket connections -------------------------------------------------------------------
    async def _serve_client(self, ws: ServerConnection) -> None:
        """One accepted WebSocket, from hello to close. Protocol violations (unmasked frames,
        invalid UTF-8, over ``max_size``) are closed by the library with their RFC codes."""
        conn = WebSocketConnection(ws, may_command=not self.commands_need_token)
        self._add(conn)
        writer = asyncio.create_task(conn.write_loop(), name=f"hmi-ws-writer {conn.peer}")
        try:
            async for message in ws:
                try:
                    if isinstance(message, bytes):
                        raise WebSocketError(CloseCode.UNSUPPORTED_DATA, "binary messages are not supported")
                    if not conn.rate.allow():
                        raise WebSocketError(CloseCode.POLICY_VIOLATION, f"more than {MAX_MESSAGES_PER_S:g} "
                                             f"messages a second (burst {MAX_MESSAGE_BURST})")
                    self._on_text(conn, message)
                except WebSocketError as exc:
                    _log.warning("WebSocket %s: %s", conn.peer, exc)
                    await ws.close(exc.code, str(exc))
                    break
        except ConnectionClosed:
            pass
        finally:
            conn.mark_closed()
            writer.cancel()
            try:
                await writer
            except (asyncio.CancelledError, ConnectionClosed):
                pass
            self._remove(conn)

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
        if len(text) > 2 * MAX_MESSAGE_DEPTH and json_depth(text) > MAX_MESSAGE_DEPTH:
            raise WebSocketError(CloseCode.POLICY_VIOLATION, f"message nests deeper than {MAX_MESSAGE_DEPTH}")
        try:
            msg = json.loads(text)
        except ValueError:
            self.reply(conn, {"type": "reply", "ok": False, "error": "message is not JSON"})
            return
        except RecursionError:  # json_depth bounds nesting first; this is the last line of defence
            raise WebSocketError(CloseCode.POLICY_VIOLATION, "message nests too deeply") from None
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

    # -- HTTP: every request passes here first ---------------------------------------------------
    def _process_request(self, ws: ServerConnection, request: Request) -> Response | None:
        """The ``process_request`` hook: the Host check for every request, then the HTTP routes;
        for ``/ws`` the handshake checks (``None``: the library accepts the handshake)."""
        hosts = request.headers.get_all("Host")
        path = urlsplit(request.path).path
        if len(hosts) > 1 or not self.host_allowed(hosts[0] if hosts else None, _address_text(ws.local_address, False)):
            _log.warning("refused %s %s with Host %r (not an address this server serves; allowed_origins "
                         "adds names)", request.method, path, ", ".join(hosts))
            return _text_response(403, f"Host {', '.join(hosts)!r} is not served here (a DNS-rebinding page?); "
                                       "add the name to allowed_origins if it is yours")
        if request.method not in ("GET", "HEAD"):
            return _text_response(405, f"{request.method} is not served here", [("Allow", "GET, HEAD")])
        if path == "/ws" and request.method == "GET":
            return self._check_handshake(ws, request)
        with self._lock:
            exposed = self._exposed.get(path)
        if path == "/healthz":
            response = _response(200, to_json(self.health()).encode(), "application/json")
        elif exposed is not None:
            response = self._exposed_file(ws, request, path, exposed)
        else:
            response = self._static(path)
        if request.method == "HEAD":
            response.body = b""  # Content-Length still says what a GET would get
        return response

    def _check_handshake(self, ws: ServerConnection, request: Request) -> Response | None:
        h = request.headers
        upgrade = _header(h, "Upgrade").lower()
        connection = [t.strip().lower() for t in _header(h, "Connection").split(",")]
        if upgrade != "websocket" or "upgrade" not in connection:
            return _text_response(400, "expected a WebSocket upgrade (Upgrade: websocket, Connection: Upgrade)")
        if _header(h, "Sec-WebSocket-Version") != "13":  # RFC 6455 Sec. 4.4: 426 and the versions we speak
            return _text_response(426, "WebSocket version 13 only", [("Sec-WebSocket-Version", "13")])
        origin, host = h.get_all("Origin"), _header(h, "Host")
        if len(origin) > 1 or not self._origin_allowed(origin[0] if origin else None, host):
            _log.warning("refused WebSocket from origin %s (Host %s)", ", ".join(origin), host)
            return _text_response(403, f"origin {', '.join(origin)} not allowed (set the allowed_origins parameter)")
        if not self.token_ok(request.path, _header(h, "Authorization") or None):
            _log.warning("refused WebSocket from %s: missing or wrong access token", _address_text(ws.remote_address))
            return _text_response(403, "access token missing or wrong (open the page with ?token=...)")
        return None  # the library checks the rest (Sec-WebSocket-Key: 400) and answers 101

    def _exposed_file(self, ws: ServerConnection, request: Request, path: str, file: Path) -> Response:
        if not self.token_ok(request.path, _header(request.headers, "Authorization") or None):
            _log.warning("refused %s from %s: missing or wrong access token", path, _address_text(ws.remote_address))
            return _text_response(403, "access token missing or wrong (open the page with ?token=...)")
        data = read_png(file)
        if data is None:  # replaced or removed since it was exposed
            return _text_response(404, f"not found: {path} (its file is gone or no longer a PNG)")
        return _response(200, data, "image/png")

    def _origin_allowed(self, origin: str | None, host: str | None) -> bool:
        if not origin:
            return True  # not a browser
        origin = origin.rstrip("/").lower()
        if origin in self.allowed_origins or "*" in self.allowed_origins:
            return True
        return bool(host) and urlsplit(origin).netloc == (host or "").lower()

    def _static(self, path: str) -> Response:
        rel = "index.html" if path in ("", "/") else unquote(path).lstrip("/")
        try:
            target = (self.static_dir / rel).resolve()
            found = self.static_dir in target.parents and target.is_file()
        except (OSError, ValueError):  # a NUL byte, a name too long
            found = False
        if not found:
            return _text_response(404, f"not found: {path}")
        ctype = mimetypes.guess_type(target.name)[0] or "application/octet-stream"
        if ctype.startswith("text/") or ctype in ("application/javascript", "application/json"):
            ctype += "; charset=utf-8"
        return _response(200, target.read_bytes(), ctype)


def _response(status: int, body: bytes, ctype: str, extra: list[tuple[str, str]] | None = None) -> Response:
    """A plain HTTP response; the connection closes after it (one request per connection)."""
    status = http.HTTPStatus(status)
    headers = Headers([("Content-Type", ctype), ("Content-Length", str(len(body))), ("Cache-Control", "no-store"),
                       ("Connection", "close"), *(extra or [])])
    return Response(status.value, status.phrase, headers, body)


def _text_response(status: int, text: str, extra: list[tuple[str, str]] | None = None) -> Response:
    return _response(status, (text + "\n").encode(), "text/plain; charset=utf-8", extra)


def _header(headers: Headers, name: str) -> str:
    """A header's value; repeated headers joined with ", " (RFC 9110 Sec. 5.3), "" when absent."""
    return ", ".join(headers.get_all(name))


def _address_text(address: Any, with_port: bool = True) -> str:
    """``host:port`` (or ``host``) of a socket address tuple; "" when unknown."""
    if not address:
        return ""
    return f"{address[0]}:{address[1]}" if with_port else str(address[0])


def _is_loopback(bind: str) -> bool:
    if bind == "localhost":
        return True
    try:
        return ipaddress.ip_address(bind).is_loopback
    except ValueError:
        return False


def default_static_dir() -> Path:
    """The page shipped with the package (installed as package data)."""
    return Path(os.path.dirname(os.path.abspath(__file__))) / "static"
