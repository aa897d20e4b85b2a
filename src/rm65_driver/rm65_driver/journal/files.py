"""Durable file writes for the weld journal: every byte written, fsync'ed, renamed atomically.

POSIX only (``os.fsync`` on a directory makes a new entry durable); no journal logic here.
"""
from __future__ import annotations

import os
from pathlib import Path


def free_name(path: Path, tag: str) -> Path:
    """``<path>.<tag>``, or ``<path>.<tag>.2`` ... if taken (two repairs within a second)."""
    out, n = path.with_name(f"{path.name}.{tag}"), 1
    while out.exists():
        n += 1
        out = path.with_name(f"{path.name}.{tag}.{n}")
    return out


def write_all(fd: int, data: bytes) -> None:
    """``os.write`` until all of ``data`` is written (a write may take only part of it)."""
    view = memoryview(data)
    while view:
        n = os.write(fd, view)
        view = view[n:]


def atomic_write(path: Path, data: bytes, fsync: bool = True) -> None:
    """Replace ``path`` by ``data`` (write a temporary file, fsync, rename, fsync the directory)."""
    tmp = path.with_name(path.name + ".tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        write_all(fd, data)
        if fsync:
            os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)
    if fsync:
        fsync_dir(path.parent)




def fsync_dir(path: Path) -> None:
    """Make a newly created file's directory entry durable (POSIX)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
