"""A small WebSocket client for the tests, written independently of the server's framing code
(so a symmetric encode/decode bug cannot hide): handshake, masked frames, text messages."""
from __future__ import annotations

import base64
import hashlib
import json
import os
import socket
import struct
import time

GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"


class HandshakeRefused(Exception):
    def __init__(self, status: int, response: bytes):
        super().__init__(f"HTTP {status}: {response[:200]!r}")
        self.status = status
        self.response = response


class WsClient:
    def __init__(self, host: str, port: int, path: str = "/ws", origin: str | None = None,
                 timeout_s: float = 5.0, extra_headers: dict | None = None):
        self.sock = socket.create_connection((host, port), timeout=timeout_s)
        self.buf = b""
        key = base64.b64encode(os.urandom(16)).decode()
        headers = {"Host": f"{host}:{port}", "Upgrade": "websocket", "Connection": "Upgrade",
                   "Sec-WebSocket-Key": key, "Sec-WebSocket-Version": "13"}
        if origin:
            headers["Origin"] = origin
        headers.update(extra_headers or {})
        request = f"GET {path} HTTP/1.1\r\n" + "".join(f"{k}: {v}\r\n" for k, v in headers.items()) + "\r\n"
        self.sock.sendall(request.encode())
        while b"\r\n\r\n" not in self.buf:
            chunk = self.sock.recv(4096)
            if not chunk:
                raise HandshakeRefused(0, self.buf)
            self.buf += chunk
        head, self.buf = self.buf.split(b"\r\n\r\n", 1)
        lines = head.decode("latin-1").split("\r\n")
        status = int(lines[0].split()[1])
        if status != 101:
            raise HandshakeRefused(status, head + b"\r\n\r\n" + self.buf)
        self.response_headers = {k.strip().lower(): v.strip() for k, v in (ln.split(":", 1) for ln in lines[1:])}
        expected = base64.b64encode(hashlib.sha1((key + GUID).encode()).digest()).decode()
        assert self.response_headers["sec-websocket-accept"] == expected, self.response_headers
        self.closed_with: int | None = None

    # -- frames --------------------------------------------------------------------------------------
    def send_frame(self, opcode: int, payload: bytes, fin: bool = True, masked: bool = True) -> None:
        b0 = (0x80 if fin else 0) | opcode
        n = len(payload)
        mbit = 0x80 if masked else 0
        if n < 126:
            head = struct.pack("!BB", b0, mbit | n)
        elif n < 65536:
            head = struct.pack("!BBH", b0, mbit | 126, n)
        else:
            head = struct.pack("!BBQ", b0, mbit | 127, n)
        if masked:
            mask = os.urandom(4)
            payload = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
            head += mask
        self.sock.sendall(head + payload)

    def send_text(self, text: str) -> None:
        self.send_frame(0x1, text.encode())

    def send_json(self, obj) -> None:
        self.send_text(json.dumps(obj))

    def _parse(self) -> tuple[bool, int, bytes] | None:
        """A complete frame from the front of the buffer, or None (nothing consumed)."""
        b = self.buf
        if len(b) < 2:
            return None
        assert not b[1] & 0x80, "server frames must not be masked"
        n, off = b[1] & 0x7F, 2
        if n == 126:
            if len(b) < 4:
                return None
            n, off = struct.unpack("!H", b[2:4])[0], 4
        elif n == 127:
            if len(b) < 10:
                return None
            n, off = struct.unpack("!Q", b[2:10])[0], 10
        if len(b) < off + n:
            return None
        self.buf = b[off + n:]
        return bool(b[0] & 0x80), b[0] & 0x0F, b[off:off + n]

    def recv_frame(self, timeout_s: float = 5.0) -> tuple[bool, int, bytes]:
        """(fin, opcode, payload). TimeoutError if no complete frame arrives in time."""
        deadline = time.monotonic() + timeout_s
        while (frame := self._parse()) is None:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimeoutError
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(262144)
            except socket.timeout:
                raise TimeoutError from None
            if not chunk:
                raise ConnectionError("connection closed by the server")
            self.buf += chunk
        return frame

    def recv_message(self, timeout_s: float = 5.0):
        """Next text message as JSON (a close frame -> None, recorded in closed_with)."""
        parts = []
        while True:
            fin, op, payload = self.recv_frame(timeout_s)
            if op == 0x8:
                self.closed_with = struct.unpack("!H", payload[:2])[0] if len(payload) >= 2 else 1005
                return None
            if op in (0x9, 0xA):
                continue
            parts.append(payload)
            if fin:
                return json.loads(b"".join(parts).decode())

    def poll(self, timeout_s: float = 0.05) -> list:
        """Every message that arrives within ``timeout_s``."""
        out = []
        try:
            while True:
                msg = self.recv_message(timeout_s)
                if msg is None:
                    break
                out.append(msg)
                timeout_s = 0.001
        except (TimeoutError, ConnectionError):
            pass  # nothing more now, or the server is gone (see closed_with)
        return out

    def close(self) -> None:
        try:
            self.sock.close()
        except OSError:
            pass
