"""Strict JSON (RFC 8259) for everything the project writes: reports, summaries, HMI messages.

Python's ``json`` writes ``NaN``, ``Infinity`` and ``-Infinity`` by default, which are not JSON:
browsers' ``JSON.parse``, ``jq`` and most other readers refuse the whole document. Here a value
that is not a finite number is *missing*, and a missing value is ``null``. Every writer in the
project goes through :func:`dumps`, :func:`dumps_document` or :func:`write_json` (one rule, one
place); the encoder runs with ``allow_nan=False``, so a non-finite number that slipped past
:func:`json_safe` is an error, never an invalid file.

Also converted: numpy scalars and arrays (to Python numbers and lists), tuples (lists),
``pathlib`` paths (strings). Dict keys become strings, as JSON requires.
"""
from __future__ import annotations

import json
import math
import os
import threading
from pathlib import Path, PurePath
from typing import Any

__all__ = ["json_safe", "dumps", "dumps_document", "write_json", "write_text_atomic"]


def json_safe(obj: Any) -> Any:
    """A copy of ``obj`` that strict JSON can carry: NaN/inf -> None, tuples -> lists, numpy
    scalars/arrays -> Python values/lists, paths -> str. Raises TypeError for anything else."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (str, int, bool)) or obj is None:  # bool is an int; both pass unchanged
        return obj
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, PurePath):
        return str(obj)
    if hasattr(obj, "tolist"):  # numpy array or scalar (without importing numpy here)
        return json_safe(obj.tolist())
    if hasattr(obj, "item"):
        return json_safe(obj.item())
    raise TypeError(f"{type(obj).__name__} is not JSON serialisable")


_ENCODER = json.JSONEncoder(allow_nan=False, separators=(", ", ": "))
_COMPACT = json.JSONEncoder(allow_nan=False, separators=(",", ":"))


def _encode(encoder: json.JSONEncoder, obj: Any) -> str:
    """The common case -- plain Python values, all finite -- is encoded directly (C encoder); only
    a value that holds NaN/inf or numpy types is copied through :func:`json_safe` first."""
    try:
        return encoder.encode(obj)
    except (ValueError, TypeError):
        return encoder.encode(json_safe(obj))


def dumps(obj: Any, *, compact: bool = False) -> str:
    """Strict JSON text of ``obj`` on one line (see the module docstring); ``compact``: without
    spaces (messages on a socket)."""
    return _encode(_COMPACT if compact else _ENCODER, obj)


def dumps_document(obj: Any) -> str:
    """Strict JSON text of ``obj`` for a file a person may read: a dict has one line per key, a
    list directly under it (a report's 250,000 targets) one line per element. Encoded by the C
    encoder element by element (``json.dumps(indent=...)`` is pure Python)."""
    if not isinstance(obj, dict) or not obj:
        return dumps(obj)
    lines = []
    for key, value in obj.items():
        name = _ENCODER.encode(str(key))
        if isinstance(value, (list, tuple)) and value:
            body = ",\n  ".join(_encode(_ENCODER, v) for v in value)
            lines.append(f"{name}: [\n  {body}\n ]")
        else:
            lines.append(f"{name}: {_encode(_ENCODER, value)}")
    return "{\n " + ",\n ".join(lines) + "\n}"


def write_json(path: str | os.PathLike, obj: Any, durable: bool = False) -> Path:
    """Write ``obj`` as strict JSON (:func:`dumps_document`) to ``path``, parent folders created,
    newline-terminated, through a temporary file renamed into place: a reader never sees half a
    document (``durable``: see :func:`write_text_atomic`)."""
    return write_text_atomic(path, dumps_document(obj) + "\n", durable=durable)


def write_text_atomic(path: str | os.PathLike, text: str, durable: bool = False) -> Path:
    """Write ``text`` to ``path`` (parent folders created) through a temporary file renamed into
    place: a reader, or a process writing the same file, never sees half of it. ``durable``: the
    temporary file is forced to disk before the rename and the folder after it, so a power cut or a
    kill leaves either the old file whole or the new one (a record someone signs)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}.{threading.get_ident()}")
    try:
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
            if durable:
                f.flush()
                os.fsync(f.fileno())
        os.replace(tmp, path)
        if durable:
            fd = os.open(path.parent, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path
