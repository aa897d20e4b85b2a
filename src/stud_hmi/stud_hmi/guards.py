"""What the HMI server lets in and out (ROS-free): the one file it serves besides its page (a PNG,
optionally only from one folder) and how fast a browser may send (a token bucket per WebSocket)."""
from __future__ import annotations

import time
from pathlib import Path

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Largest file the server hands out besides its page (the inspection overlay).
MAX_EXPOSED_BYTES = 64 * 1024 * 1024
#: A browser's messages (button presses, acknowledgements): a sustained rate and a burst. A page in
#: use sends a few per minute; a client beyond these is closed (1008), never queued.
MAX_MESSAGES_PER_S = 20.0
MAX_MESSAGE_BURST = 40


def inside_folder(path: Path, folder: Path) -> bool:
    """``path`` lies in ``folder`` (both resolved: no ``..`` and no link leads out)."""
    try:
        return path.resolve().is_relative_to(folder.resolve())
    except (OSError, RuntimeError):  # a link loop
        return False


def read_png(path: Path, signature_only: bool = False) -> bytes | None:
    """The bytes of ``path`` (only its first 8 with ``signature_only``) if it is a regular file of at
    most ``MAX_EXPOSED_BYTES`` that starts with the PNG signature; None otherwise (missing, a
    folder, a device, too big, not a PNG)."""
    try:
        if not path.is_file() or path.stat().st_size > MAX_EXPOSED_BYTES:
            return None
        with path.open("rb") as f:
            data = f.read(len(PNG_SIGNATURE) if signature_only else MAX_EXPOSED_BYTES)
    except (OSError, ValueError):
        return None
    return data if data.startswith(PNG_SIGNATURE) else None


class MessageRate:
    """Token bucket: :meth:`allow` is False once a client sends faster than ``per_s`` beyond a
    ``burst``. ``clock``: monotonic seconds (a parameter for tests)."""

    def __init__(self, per_s: float = MAX_MESSAGES_PER_S, burst: int = MAX_MESSAGE_BURST, clock=time.monotonic):
        self.per_s, self.burst, self._clock = float(per_s), float(burst), clock
        self._tokens, self._last = float(burst), clock()

    def allow(self) -> bool:
        now = self._clock()
        self._tokens = min(self.burst, self._tokens + (now - self._last) * self.per_s)
        self._last = now
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True
