"""What protects the HMI's buttons (they move the arm): the Host check against DNS rebinding, the
Origin check, the access token, view-only beyond loopback, bounded messages. No ROS."""
from __future__ import annotations

import http.client
import json

import pytest

from stud_hmi import server as hmi_server
from stud_hmi.server import HmiServer, json_depth
from ws_client import HandshakeRefused, WsClient


def make_server(tmp_path, **kw) -> HmiServer:
    tmp_path.mkdir(parents=True, exist_ok=True)
    (tmp_path / "index.html").write_text("<!DOCTYPE html><title>test page</title>")
    commands = []

    def on_command(conn, msg):
        commands.append(msg)
        srv.reply(conn, {"type": "reply", "id": msg.get("id"), "ok": True})

    srv = HmiServer(tmp_path, "127.0.0.1", 0, on_command=on_command, hello={"version": 1, "commands": ["stop"]}, **kw)
    srv.commands = commands
    return srv.start()


@pytest.fixture()
def server(tmp_path):
    srv = make_server(tmp_path)
    yield srv
    srv.stop()


def http_get(port: int, path: str, host: str | None) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.putrequest("GET", path, skip_host=True)
    if host is not None:
        conn.putheader("Host", host)
    conn.endheaders()
    resp = conn.getresponse()
    body = resp.read()
    conn.close()
    return resp.status, body


# -- DNS rebinding: the Host header ------------------------------------------------------------------
def test_a_dns_rebinding_handshake_is_refused_and_no_command_reaches_the_cell(server, caplog):
    # evil.example re-pointed at 127.0.0.1: the browser calls it same-origin, but sends its own name
    evil = f"evil.example:{server.port}"
    with pytest.raises(HandshakeRefused) as exc:
        WsClient("127.0.0.1", server.port, origin=f"http://{evil}", extra_headers={"Host": evil})
    assert exc.value.status == 403
    assert any("evil.example" in r.getMessage() and "refused" in r.getMessage() for r in caplog.records)
    assert server.client_count == 0 and server.commands == []


@pytest.mark.parametrize("path", ["/", "/healthz", "/app.js"])
def test_http_with_a_foreign_host_is_refused(server, path):
    status, body = http_get(server.port, path, f"evil.example:{server.port}")
    assert status == 403 and b"not served here" in body
    assert http_get(server.port, path if path != "/app.js" else "/", f"127.0.0.1:{server.port}")[0] == 200


@pytest.mark.parametrize("host", ["127.0.0.1:{port}", "localhost:{port}", "LOCALHOST.:{port}", "[::1]:{port}",
                                  "127.0.0.1", None])
def test_the_names_of_this_computer_pass_the_host_check(server, host):
    host = None if host is None else host.format(port=server.port)
    assert http_get(server.port, "/healthz", host)[0] == 200  # no Host at all: HTTP/1.0 tools, not a browser
    if host is not None:
        WsClient("127.0.0.1", server.port, extra_headers={"Host": host}).close()


def test_an_allowed_origin_adds_its_host_name(tmp_path):
    srv = make_server(tmp_path, allowed_origins=["https://cell-pc.plant.example"])
    try:
        host = "cell-pc.plant.example"
        c = WsClient("127.0.0.1", srv.port, origin=f"https://{host}", extra_headers={"Host": host})
        assert c.recv_message()["type"] == "hello"
        c.close()
        with pytest.raises(HandshakeRefused):
            WsClient("127.0.0.1", srv.port, extra_headers={"Host": "other.plant.example"})
    finally:
        srv.stop()


def test_served_names_beyond_loopback_include_the_bind_address_and_this_computer():
    import socket

    names = HmiServer._served_names("192.0.2.7", set())
    assert {"localhost", "127.0.0.1", "::1", "192.0.2.7", socket.gethostname().lower()} <= names
    assert "evil.example" not in names
    assert socket.gethostname().lower() not in HmiServer._served_names("127.0.0.1", set()) or \
        socket.gethostname().lower() in hmi_server.LOOPBACK_NAMES


# -- access token and view-only ------------------------------------------------------------------------
def test_with_an_access_token_the_handshake_needs_it(tmp_path):
    srv = make_server(tmp_path, access_token="4711")
    try:
        for kw in ({}, {"path": "/ws?token=0000"}, {"extra_headers": {"Authorization": "Bearer 0000"}}):
            with pytest.raises(HandshakeRefused) as exc:
                WsClient("127.0.0.1", srv.port, **kw)
            assert exc.value.status == 403
        for kw in ({"path": "/ws?token=4711"}, {"extra_headers": {"Authorization": "Bearer 4711"}}):
            c = WsClient("127.0.0.1", srv.port, **kw)
            assert c.recv_message() == {"type": "hello", "version": 1, "commands": ["stop"]}
            c.send_json({"cmd": "stop", "id": 1})
            assert c.recv_message() == {"type": "reply", "id": 1, "ok": True}
            c.close()
        assert srv.commands == [{"cmd": "stop", "id": 1}] * 2
    finally:
        srv.stop()


def test_beyond_loopback_without_a_token_clients_are_view_only(tmp_path):
    srv = make_server(tmp_path)
    try:
        assert srv.loopback_only and not srv.commands_need_token
        srv.commands_need_token = True  # what binding 0.0.0.0 without access_token sets (not bound here)
        c = WsClient("127.0.0.1", srv.port)
        assert c.recv_message() == {"type": "hello", "version": 1, "commands": [], "read_only": True}
        c.send_json({"cmd": "stop", "id": 9})
        reply = c.recv_message()
        assert reply["ok"] is False and reply["id"] == 9 and "view only" in reply["error"]
        srv.publish({"type": "cell", "state": "idle"})
        assert c.recv_message() == {"type": "cell", "state": "idle"}  # it still shows everything
        assert srv.commands == []
        c.close()
    finally:
        srv.stop()


def test_loopback_detection():
    assert hmi_server._is_loopback("127.0.0.1") and hmi_server._is_loopback("127.0.0.2")
    assert hmi_server._is_loopback("::1") and hmi_server._is_loopback("localhost")
    assert not hmi_server._is_loopback("0.0.0.0") and not hmi_server._is_loopback("192.0.2.7")
    assert not hmi_server._is_loopback("")


# -- bounded messages ----------------------------------------------------------------------------------
def test_json_depth_counts_brackets_outside_strings():
    assert json_depth('{"cmd": "stop"}') == 1
    assert json_depth('{"a": [1, {"b": [2]}]}') == 4
    assert json_depth('{"s": "[[[[{{{{"}') == 1
    assert json_depth('{"s": "a \\" [[["}') == 1
    assert json_depth("[" * 30000 + "]" * 30000) == 30000
    assert json_depth("7") == 0


def test_deeply_nested_json_closes_with_1008_and_the_server_keeps_serving(server):
    c = WsClient("127.0.0.1", server.port)
    assert c.recv_message()["type"] == "hello"
    c.send_text("[" * (hmi_server.MAX_INCOMING_BYTES // 2) + "]" * (hmi_server.MAX_INCOMING_BYTES // 2))  # 64 KB
    assert c.recv_message() is None and c.closed_with == 1008
    c.close()
    c = WsClient("127.0.0.1", server.port)  # still serving, nothing reached the handler
    assert c.recv_message()["type"] == "hello"
    nested = {"cmd": "stop", "id": 1}
    for _ in range(hmi_server.MAX_MESSAGE_DEPTH - 1):
        nested = {"x": nested}
    c.send_text(json.dumps(nested))  # exactly at the limit: an ordinary message
    assert c.recv_message() == {"type": "reply", "id": None, "ok": True}
    c.close()
    assert server.commands == [nested]


def test_a_message_over_the_size_limit_closes_with_1009(server):
    c = WsClient("127.0.0.1", server.port)
    assert c.recv_message()["type"] == "hello"
    c.send_text(json.dumps({"cmd": "stop", "pad": "x" * hmi_server.MAX_INCOMING_BYTES}))
    assert c.recv_message() is None and c.closed_with == 1009
    c.close()
    assert server.commands == []


# -- the inspection overlay: one file named by the inspection result, nothing else -------------------
def _png(path, width=8, height=4) -> bytes:
    import cv2
    import numpy as np

    ok, data = cv2.imencode(".png", np.full((height, width, 3), (0, 200, 0), np.uint8))
    assert ok
    path.write_bytes(data.tobytes())
    return data.tobytes()


def test_the_inspection_overlay_is_served_and_no_url_reaches_another_file(tmp_path):
    srv = make_server(tmp_path / "page")  # static folder tmp/page; the overlay and a secret beside it
    try:
        overlay = _png(tmp_path / "inspection_station_01.png")
        (tmp_path / "secret.txt").write_text("not for the browser")
        (tmp_path / "page" / "inspection").mkdir()
        url = srv.expose_png(hmi_server.INSPECTION_OVERLAY_URL, tmp_path / "inspection_station_01.png")
        assert url.startswith("/inspection/overlay.png?v=")
        status, body = http_get(srv.port, url, f"127.0.0.1:{srv.port}")
        assert status == 200 and body == overlay
        for attempt in ("/inspection/overlay.png/../../secret.txt", "/inspection/../../secret.txt",
                        "/inspection/%2e%2e/%2e%2e/secret.txt", "/inspection/..%2f..%2fsecret.txt",
                        "/%2e%2e/secret.txt", "/inspection/overlay.png%00/../../secret.txt",
                        "/inspection/inspection_station_01.png", "/inspection_station_01.png"):
            status, body = http_get(srv.port, attempt, f"127.0.0.1:{srv.port}")
            assert status == 404 and b"not for the browser" not in body and body != overlay, attempt
        # a query names no file: it still gets the overlay
        assert http_get(srv.port, "/inspection/overlay.png?file=../secret.txt", None)[1] == overlay
        # the Host check applies here too
        assert http_get(srv.port, url, f"evil.example:{srv.port}")[0] == 403
    finally:
        srv.stop()


def test_an_inspection_result_naming_a_file_that_is_no_png_withdraws_the_overlay(tmp_path):
    srv = make_server(tmp_path / "page")
    try:
        _png(tmp_path / "good.png")
        (tmp_path / "secret.png").write_text("not for the browser")  # named .png, is no PNG
        assert srv.expose_png(hmi_server.INSPECTION_OVERLAY_URL, tmp_path / "good.png") is not None
        for bad in (tmp_path / "secret.png", tmp_path / "missing.png", tmp_path, "/etc/passwd", ""):
            assert srv.expose_png(hmi_server.INSPECTION_OVERLAY_URL, bad) is None, bad
            status, body = http_get(srv.port, hmi_server.INSPECTION_OVERLAY_URL, None)
            assert status == 404 and b"not for the browser" not in body and b"root:" not in body
        # exposed, then replaced on disk by something that is not a PNG: not served either
        assert srv.expose_png(hmi_server.INSPECTION_OVERLAY_URL, tmp_path / "good.png") is not None
        (tmp_path / "good.png").write_text("not for the browser")
        assert http_get(srv.port, hmi_server.INSPECTION_OVERLAY_URL, None)[0] == 404
    finally:
        srv.stop()


def test_with_an_access_token_the_inspection_overlay_needs_it_too(tmp_path):
    srv = make_server(tmp_path / "page", access_token="4711")
    try:
        overlay = _png(tmp_path / "o.png")
        url = srv.expose_png(hmi_server.INSPECTION_OVERLAY_URL, tmp_path / "o.png")
        assert http_get(srv.port, url, None)[0] == 403
        assert http_get(srv.port, url + "&token=0000", None)[0] == 403
        assert http_get(srv.port, url + "&token=4711", None) == (200, overlay)
    finally:
        srv.stop()


def test_an_overlay_outside_the_inspection_folder_is_refused_even_through_a_link(tmp_path):
    srv = make_server(tmp_path / "page")
    try:
        qa = tmp_path / "out" / "qa"
        qa.mkdir(parents=True)
        _png(qa / "inspection_station_01.png")
        elsewhere = _png(tmp_path / "private.png")  # a PNG, but not the inspector's
        (qa / "link.png").symlink_to(tmp_path / "private.png")
        assert srv.expose_png(hmi_server.INSPECTION_OVERLAY_URL, qa / "inspection_station_01.png", within=qa)
        for bad in (tmp_path / "private.png", qa / ".." / ".." / "private.png", qa / "link.png"):
            assert srv.expose_png(hmi_server.INSPECTION_OVERLAY_URL, bad, within=qa) is None, bad
            status, body = http_get(srv.port, hmi_server.INSPECTION_OVERLAY_URL, None)
            assert status == 404 and body != elsewhere
    finally:
        srv.stop()
