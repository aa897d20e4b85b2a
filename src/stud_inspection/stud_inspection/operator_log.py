"""The operator's entries on the QA record -- rework decisions (stud_inspection.rework) and bend-test
results (stud_inspection.bend) -- as JSON-lines logs: one line per entry, appended and forced to disk
before it is confirmed, the newest line of a stud its entry. And who the operator is.

A last line without its newline is an append cut short (a power cut, a kill): never confirmed to the
operator, so not an entry. No ROS here.
"""
from __future__ import annotations

import os
import unicodedata
from collections.abc import Iterator
from pathlib import Path

MAX_OPERATOR_CHARS = 100


class OperatorError(ValueError):
    """An operator name that cannot sign an entry; the message says why."""


def operator_name(name: str) -> str:
    """``name`` checked as who signs an entry: a few printable words, no control characters."""
    name = " ".join(str(name).split())
    if not name:
        raise OperatorError("no operator name given: every decision and bend result is signed by a person")
    if len(name) > MAX_OPERATOR_CHARS:
        raise OperatorError(f"the operator name has {len(name)} characters; at most {MAX_OPERATOR_CHARS}")
    if any(unicodedata.category(c).startswith("C") for c in name):
        raise OperatorError(f"the operator name {name!r} holds control characters")
    return name


def append_line(path: str | os.PathLike[str], line: str) -> Path:
    """Append ``line`` (one JSON document, no newline) and its newline, flushed and fsynced (and the
    folder too when the file is new): an entry must survive a power cut once confirmed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    new = not path.exists()
    with open(path, "a", encoding="utf-8") as f:
        f.write(line + "\n")
        f.flush()
        os.fsync(f.fileno())
    if new:
        fsync_dir(path.parent)
    return path


def fsync_dir(folder: str | os.PathLike[str]) -> None:
    """Force a folder's entries (a new or renamed file) to disk."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def complete_lines(path: str | os.PathLike[str]) -> Iterator[tuple[int, str]]:
    """(line number, text) of every complete, non-blank line of ``path`` (none when it does not exist);
    OSError / UnicodeDecodeError from reading it."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        return
    # split("\n")'s last piece is "" after a complete file, else an append cut short: not an entry
    for number, line in enumerate(text.split("\n")[:-1], start=1):
        if line.strip():
            yield number, line


__all__ = ["MAX_OPERATOR_CHARS", "OperatorError", "append_line", "complete_lines", "fsync_dir", "operator_name"]
