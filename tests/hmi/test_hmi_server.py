"""hmi_server without ROS: the RFC 6455 handshake and framing (the websockets library's, behind our
HTTP routes and checks) against an independent raw-socket client, several clients, retained
messages, strict JSON, HTTP routes, origin check, clean stop."""
from __future__ import annotations

import json
import math
import socket
import struct
import threading
import time
import urllib.error
import urllib.request

import pytest

from stud_hmi import server as hmi_server
from stud_hmi.server import HmiServer, to_json
from ws_client import HandshakeRefused, WsClient


@pytest.fixture()
def server(tmp_path):
    (tmp_path / "index.html").write_text("<!DOCTYPE html><title>test page</title>")
    (tmp_path / "app.js").write_text("console.log('hi');")
    (tmp_path.parent / "secret.txt").write_text("not for the browser")
    commands = []

    def on_command(conn, msg):
        commands.append(msg)
        srv.reply(conn, {"type": "reply", "id": msg.get("id"), "echo": msg})

    srv = HmiServer(tmp_path, "127.0.0.1", 0, on_command=on_command, hello={"version": 1})
    srv.commands = commands
    srv.start()
    yield srv
    srv.stop()


def connect(srv, **kw) -> WsClient:
    c = WsClient("127.0.0.1", srv.port, **kw)
    hello = c.recv_message()
    assert hello == {"type": "hello", "version": 1}
    return c


def wait_until(cond, timeout_s=5.0, what="condition"):
    deadline = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.01)


# -- framing ---------------------------------------------------------------------------------------
def test_accept_key_is_the_rfc_6455_example(server):
    key = "dGhlIHNhbXBsZSBub25jZQ=="  # RFC 6455 Sec. 1.3
    with socket.create_connection(("127.0.0.1", server.port), timeout=5) as s:
        s.sendall((f"GET /ws HTTP/1.1\r\nHost: 127.0.0.1:{server.port}\r\nUpgrade: websocket\r\n"
                   f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n").encode())
        head = b""
        while b"\r\n\r\n" not in head:
            chunk = s.recv(4096)
            assert chunk, head
            head += chunk
    lines = head.split(b"\r\n\r\n")[0].decode("latin-1").split("\r\n")
    assert lines[0].split()[1] == "101"
    headers = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:])}
    assert headers["sec-websocket-accept"] == "s3pPLMBiTxaQ9kYGzzhZRbK+xOo="


def _exactly(n: int, shell: dict, key: str) -> dict:
    """``shell`` with ``key`` padded so that its compact JSON text is ``n`` bytes (at least its own length)."""
    base = len(json.dumps({**shell, key: ""}, separators=(",", ":")))
    return {**shell, key: "x" * max(0, n - base)}


@pytest.mark.parametrize("n", [0, 5, 125, 126, 65535, 65536, 300_000])
def test_frames_of_every_length_encoding_round_trip_masked_and_unmasked(server, n):
    # 7-bit, 16-bit and 64-bit payload lengths (RFC 6455 Sec. 5.2), at and around each boundary.
    # Unmasked: server -> client, any length (n below the smallest message's length: the smallest).
    c = connect(server)
    published = _exactly(n, {"type": "pad"}, "p")
    server.publish(published)
    fin, op, payload = c.recv_frame()
    assert (fin, op) == (True, 0x1) and len(payload) == max(n, 21) and json.loads(payload) == published
    # Masked: client -> server, up to the size limit; beyond it the server closes with 1009.
    if n == 0:
        c.send_frame(0x1, b"")  # an empty text message
        assert c.recv_message() == {"type": "reply", "ok": False, "error": "message is not JSON"}
    elif n <= hmi_server.MAX_INCOMING_BYTES:
        sent = _exactly(n, {"id": 1}, "p")
        text = json.dumps(sent, separators=(",", ":")).encode()
        assert len(text) == max(n, 15)
        c.send_frame(0x1, text)
        assert c.recv_message() == {"type": "reply", "id": 1, "echo": sent}
    else:
        c.send_frame(0x1, b"x" * n)
        assert c.recv_message() is None and c.closed_with == 1009
    c.close()


def test_json_has_no_nan_tokens():
    text = to_json({"a": math.nan, "b": [1.0, math.inf, -math.inf], "c": (2, "x"), "d": None})
    assert json.loads(text) == {"a": None, "b": [1.0, None, None], "c": [2, "x"], "d": None}
    assert "NaN" not in text and "Infinity" not in text


# -- handshake -------------------------------------------------------------------------------------
def test_handshake_answers_101_with_the_accept_key_and_a_hello(server):
    c = connect(server)  # WsClient asserts Sec-WebSocket-Accept
    assert c.response_headers["upgrade"].lower() == "websocket"
    c.close()


@pytest.mark.parametrize("headers, status", [
    ({"Sec-WebSocket-Version": "8"}, 426),
    ({"Sec-WebSocket-Key": "too-short"}, 400),
    ({"Upgrade": "h2c"}, 400),
])
def test_bad_handshakes_are_refused_with_the_right_status(server, headers, status):
    with pytest.raises(HandshakeRefused) as exc:
        WsClient("127.0.0.1", server.port, extra_headers=headers)
    assert exc.value.status == status


def test_a_foreign_origin_is_refused_and_the_pages_own_origin_accepted(server):
    with pytest.raises(HandshakeRefused) as exc:
        WsClient("127.0.0.1", server.port, origin="http://evil.example")
    assert exc.value.status == 403
    connect(server, origin=f"http://127.0.0.1:{server.port}").close()
    connect(server).close()  # no Origin: not a browser


# -- messages --------------------------------------------------------------------------------------
def test_a_masked_text_command_reaches_the_handler_and_its_reply_comes_back(server):
    c = connect(server)
    c.send_json({"cmd": "stop", "id": 7})
    assert c.recv_message() == {"type": "reply", "id": 7, "echo": {"cmd": "stop", "id": 7}}
    assert server.commands == [{"cmd": "stop", "id": 7}]
    c.close()


def test_a_fragmented_text_message_is_reassembled(server):
    c = connect(server)
    text = json.dumps({"cmd": "pause", "id": 3, "pad": "é" * 100}).encode()
    c.send_frame(0x1, text[:10], fin=False)
    c.send_frame(0x9, b"in-between ping")  # control frames may come between fragments
    c.send_frame(0x0, text[10:50], fin=False)
    c.send_frame(0x0, text[50:], fin=True)
    fin, op, payload = c.recv_frame()
    assert (op, payload) == (0xA, b"in-between ping")
    assert c.recv_message()["echo"]["pad"] == "é" * 100
    c.close()


def test_not_json_gets_an_error_reply_not_a_disconnect(server):
    c = connect(server)
    c.send_text("stop please")
    assert c.recv_message() == {"type": "reply", "ok": False, "error": "message is not JSON"}
    c.send_json({"cmd": "start", "id": 1})
    assert c.recv_message()["id"] == 1
    c.close()


def test_ping_is_answered_with_a_pong_carrying_the_same_payload(server):
    c = connect(server)
    c.send_frame(0x9, b"are you there")
    assert c.recv_frame() == (True, 0xA, b"are you there")
    c.close()


def test_a_close_frame_is_echoed_and_the_connection_ends(server):
    c = connect(server)
    wait_until(lambda: server.client_count == 1, what="client registered")
    c.send_frame(0x8, struct.pack("!H", 1000) + b"bye")
    fin, op, payload = c.recv_frame()
    assert op == 0x8 and struct.unpack("!H", payload[:2])[0] == 1000
    with pytest.raises(ConnectionError):
        c.recv_frame(2.0)  # the server closes the TCP connection after the handshake
    wait_until(lambda: server.client_count == 0, what="client removed")


@pytest.mark.parametrize("send, code", [
    (lambda c: c.send_frame(0x1, b'{"cmd":"stop"}', masked=False), 1002),   # clients must mask
    (lambda c: c.send_frame(0x2, b"\x00\x01"), 1003),                       # binary: unsupported
    (lambda c: c.send_frame(0x1, b"\xff\xfe"), 1007),                       # not UTF-8
    (lambda c: c.send_frame(0x0, b"orphan continuation"), 1002),
    (lambda c: c.send_frame(0x1, b"x" * (hmi_server.MAX_INCOMING_BYTES + 1)), 1009),
])
def test_protocol_violations_close_with_the_rfc_code(server, send, code):
    c = connect(server)
    send(c)
    assert c.recv_message() is None and c.closed_with == code
    assert server.commands == []
    c.close()


def test_several_clients_get_every_broadcast_and_a_late_client_gets_the_newest_per_type(server):
    clients = [connect(server) for _ in range(3)]
    wait_until(lambda: server.client_count == 3, what="three clients")
    server.publish({"type": "arm", "mode": "idle", "x": math.nan})
    for c in clients:
        assert c.recv_message() == {"type": "arm", "mode": "idle", "x": None}
    server.publish({"type": "cell", "state": "welding"})
    server.publish({"type": "arm", "mode": "welding", "x": 1.5})
    for c in clients:
        got = []
        wait_until(lambda: got.extend(c.poll(0.05)) or {"type": "arm", "mode": "welding", "x": 1.5} in got,
                   what="the second arm message")
        assert {"type": "cell", "state": "welding"} in got
    late = connect(server)
    got = late.poll(0.5)
    assert sorted(got, key=lambda m: m["type"]) == [{"type": "arm", "mode": "welding", "x": 1.5},
                                                    {"type": "cell", "state": "welding"}]
    for c in clients + [late]:
        c.close()


def test_each_client_gets_its_own_replies_only(server):
    a, b = connect(server), connect(server)
    a.send_json({"cmd": "start", "id": "a1"})
    b.send_json({"cmd": "stop", "id": "b1"})
    assert a.recv_message()["id"] == "a1"
    assert b.recv_message()["id"] == "b1"
    assert a.poll(0.2) == [] and b.poll(0.2) == []
    a.close()
    b.close()


def test_a_client_that_never_reads_does_not_block_publishing(server):
    stalled = WsClient("127.0.0.1", server.port)
    stalled.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    reader = connect(server)
    wait_until(lambda: server.client_count == 2, what="two clients")
    big = "x" * 1_000_000
    t0 = time.monotonic()
    for i in range(100):  # 100 MB for a client that reads nothing
        server.publish({"type": "overlay", "i": i, "data": big})
    assert time.monotonic() - t0 < 5.0
    got = []
    wait_until(lambda: got.extend(reader.poll(0.1)) or any(m.get("i") == 99 for m in got), 10, "the newest overlay")
    assert len(got) < 100  # stale frames were dropped, not queued
    stalled.close()
    reader.close()


# -- HTTP ------------------------------------------------------------------------------------------
def test_http_serves_the_page_static_files_and_health(server):
    base = f"http://127.0.0.1:{server.port}"
    page = urllib.request.urlopen(base + "/")
    assert b"test page" in page.read() and page.headers["Content-Type"].startswith("text/html")
    assert b"console.log" in urllib.request.urlopen(base + "/app.js").read()
    health = json.loads(urllib.request.urlopen(base + "/healthz").read())
    assert health["ok"] is True and health["clients"] == 0
    for bad in ("/missing.css", "/../secret.txt", "/%2e%2e/secret.txt"):
        with pytest.raises(urllib.error.HTTPError) as exc:
            urllib.request.urlopen(base + bad)
        assert exc.value.code == 404


def test_stop_closes_clients_with_going_away_and_joins_every_thread(tmp_path):
    (tmp_path / "index.html").write_text("x")
    before = set(threading.enumerate())
    srv = HmiServer(tmp_path, port=0).start()
    clients = [WsClient("127.0.0.1", srv.port) for _ in range(2)]
    idle_http = socket.create_connection(("127.0.0.1", srv.port))  # a connection that never sends a request
    wait_until(lambda: srv.client_count == 2, what="clients")
    t0 = time.monotonic()
    srv.stop()
    assert time.monotonic() - t0 < 12.0
    for c in clients:
        msgs = []
        try:
            while (m := c.recv_message(2.0)) is not None:
                msgs.append(m)
        except ConnectionError:
            pass
        assert c.closed_with == 1001
        c.close()
    idle_http.close()
    wait_until(lambda: set(threading.enumerate()) <= before, 5, "server threads to end")
    with pytest.raises(OSError):
        socket.create_connection(("127.0.0.1", srv.port), timeout=1)


def test_a_client_flooding_messages_is_closed_for_policy_and_its_burst_never_all_reaches_the_cell(server):
    c = connect(server)
    wait_until(lambda: server.client_count == 1, what="client registered")
    n = 5 * hmi_server.MAX_MESSAGE_BURST
    for i in range(n):
        try:
            c.send_json({"cmd": "ack", "alarm": "all", "id": i})
        except OSError:  # the server has closed the connection
            break
    while c.recv_message(5.0) is not None:  # replies, then the close frame
        pass
    assert c.closed_with == 1008
    assert hmi_server.MAX_MESSAGE_BURST <= len(server.commands) < n
    c.close()
    # a client at a person's pace is not affected
    d = connect(server)
    d.send_json({"cmd": "start", "id": 1})
    assert d.recv_message()["id"] == 1
    d.close()


def test_the_message_rate_refills_at_its_rate_up_to_its_burst():
    from stud_hmi.guards import MessageRate

    now = [0.0]
    rate = MessageRate(per_s=2.0, burst=3, clock=lambda: now[0])
    assert [rate.allow() for _ in range(4)] == [True, True, True, False]
    now[0] += 0.5  # one token back
    assert [rate.allow(), rate.allow()] == [True, False]
    now[0] += 100.0  # never more than the burst
    assert sum(rate.allow() for _ in range(10)) == 3
