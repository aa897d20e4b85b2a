"""Reading the file: checks (binary, truncated, not a DXF), ezdxf (recover when damaged), and the
fast reader of plain CIRCLE entities for large ASCII drawings.

:func:`open_drawing` is the entry (what :func:`~stud_planner.drawing.circles.read_circles` uses);
:func:`load_document` opens a file with ezdxf alone. Every failure is a one-line
:class:`~stud_planner.drawing.layout_types.DrawingError` naming the file."""
from __future__ import annotations

import io
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ezdxf
import numpy as np
from ezdxf import recover

from stud_planner.drawing.layout_types import DrawingError, one_line
from stud_planner.drawing.plain_circles import PlainCircles, split_plain_circles

# -- reading the file ------------------------------------------------------------------------------
_BINARY_SENTINEL = b"AutoCAD Binary DXF\r\n\x1a\x00"
# Line ends: CR LF (DOS), LF (Unix) and a lone CR (classic Mac OS), all of which ezdxf reads.
_EOL = rb"(?:\r\n|\r|\n)"
_ASCII_EOF = re.compile(rb"(?:^|[\r\n])[ \t]*0[ \t]*" + _EOL + rb"[ \t]*EOF[ \t]*(?:[\r\n]|$)")
_ASCII_HEAD = re.compile(rb"^(?:\xef\xbb\xbf)?\s*(?:999\s*" + _EOL + rb"[^\r\n]*" + _EOL + rb"\s*)*0\s*" + _EOL
                         + rb"\s*SECTION\b")
_ASCII_TAIL_ENDSEC = re.compile(rb"[\r\n][ \t]*0[ \t]*" + _EOL + rb"[ \t]*ENDSEC\s*$")


def check_file(path: Path) -> tuple[bytes, list[str]]:
    """Raise DrawingError for a missing, empty, non-DXF or truncated file; return its bytes and warnings."""
    if not path.exists():
        raise DrawingError(f"{path}: file not found")
    if path.is_dir():
        raise DrawingError(f"{path}: is a directory, not a DXF file")
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DrawingError(f"{path}: cannot read ({one_line(exc.strerror or exc)})") from exc
    if not data.strip():
        raise DrawingError(f"{path}: empty file, not a DXF")
    if data.startswith(_BINARY_SENTINEL):
        if b"EOF\x00" not in data[-64:]:
            raise DrawingError(f"{path}: truncated or corrupt binary DXF (no EOF at the end of the file)")
        return data, []
    if re.match(rb"AC[0-9.]{4}", data[:6]):
        raise DrawingError(f"{path}: not a DXF file (this looks like a DWG; export it as DXF)")
    if not _ASCII_HEAD.match(data[:4096]):
        head = one_line(data[:24].decode("latin-1"))[:24]
        raise DrawingError(f"{path}: not a DXF file (starts with {head!r}, expected '0 / SECTION')")
    if _ASCII_EOF.search(data, max(0, len(data) - 65536)) or _ASCII_EOF.search(data):  # the end first: 30 MB
        return data, []
    if not _ASCII_TAIL_ENDSEC.search(data[-256:]):
        raise DrawingError(f"{path}: truncated or corrupt DXF (the file ends inside a section, no EOF)")
    return data, [f"{path.name}: no EOF marker after the last section: the file may be incomplete"]


def load_document(path: str | Path) -> tuple[Any, str, list[str]]:
    """Open a DXF with ezdxf: ``(doc, read_mode, warnings)``; read_mode ``"read"`` or ``"recover"``.

    Raises DrawingError (one line, naming the file) for anything ezdxf cannot read.
    """
    path = Path(path)
    data, file_warns = check_file(path)
    return load_checked_document(path, data, file_warns)


def load_checked_document(path: Path, data: bytes, file_warns: list[str]) -> tuple[Any, str, list[str]]:
    """:func:`load_document` for a file :func:`check_file` has read (``data``, ``file_warns``)."""
    try:
        doc, mode, warns = ezdxf.readfile(path), "read", []
    except Exception as exc:  # ezdxf raises DXFStructureError, IOError, IndexError, struct.error ...
        first = f"{type(exc).__name__}: {one_line(exc)}"
        if data.startswith(_BINARY_SENTINEL):  # ezdxf.recover reads ASCII only
            raise DrawingError(f"{path}: truncated or corrupt binary DXF ({first})") from exc
        try:
            doc, auditor = recover.readfile(path)
        except Exception as exc2:
            raise DrawingError(f"{path}: truncated or corrupt DXF, ezdxf cannot read or recover it "
                               f"({type(exc2).__name__}: {one_line(exc2)})") from exc2
        mode = "recover"
        warns = [f"{path.name}: damaged DXF ({first}); read with ezdxf.recover ({len(auditor.errors)} errors, "
                 f"{len(auditor.fixes)} fixes): check the layout against the drawing"]
    _drop_default_insunits(doc, data)
    return doc, mode, file_warns + warns


def _drop_default_insunits(doc: Any, data: bytes) -> None:
    """ezdxf fills a missing HEADER with defaults ($INSUNITS 6 = metres): keep only what the file says."""
    end = data.find(b"ENTITIES")
    if b"$INSUNITS" not in data[: end if end > 0 else len(data)] and "$INSUNITS" in doc.header:
        del doc.header["$INSUNITS"]


def load_with_plain_circles(path: Path, data: bytes) -> tuple[Any, PlainCircles | None]:
    """``(doc, circles)``: ezdxf's document of ``path`` without its plain modelspace circles, and
    those circles (:mod:`~stud_planner.drawing.plain_circles`); ``(None, None)`` when that does not apply (binary
    file, no plain circles, any doubt) or ezdxf cannot read the rest: then ezdxf reads the file
    whole, as :func:`load_document` does, with its errors and its recovery."""
    if data.startswith(_BINARY_SENTINEL):
        return None, None
    try:
        from ezdxf.filemanagement import dxf_file_info
        from ezdxf.lldxf.validator import is_dxf_file

        if not is_dxf_file(str(path)):
            return None, None
        encoding = dxf_file_info(str(path)).encoding
        # what ezdxf.readfile reads: the file decoded as it detects, universal newlines
        text = io.TextIOWrapper(io.BytesIO(data), encoding=encoding, errors="surrogateescape", newline=None).read()
        split = split_plain_circles(text)
        if split is None:
            return None, None
        rest, plain = split
        del text, split
        doc = ezdxf.read(io.StringIO(rest))
        doc.filename = str(path)
    except Exception:  # whatever goes wrong here, the whole-file path gives the user's error
        return None, None
    # ezdxf's rule for an entity of the ENTITIES section (EntitySection._build): owned by
    # *Model_Space -> modelspace, by *Paper_Space -> paperspace, else its paperspace flag (67)
    keys = [None if br is None else br.dxf.handle
            for br in (doc.block_records.get("*Model_Space"), doc.block_records.get("*Paper_Space"))]
    in_paperspace = np.array([o != keys[0] and (o == keys[1] or flag != 0)
                              for o, flag in zip(plain.owners, plain.paperspace.tolist())], dtype=bool)
    if in_paperspace.any():
        plain = plain.without(in_paperspace)
    _drop_default_insunits(doc, data)
    return doc, plain


@dataclass(frozen=True, eq=False)
class OpenedDrawing:
    """A DXF file opened for reading: ezdxf's ``doc``, how it was read (``read_mode`` "read" or
    "recover"), the file's warnings, and ``plain``: the modelspace's plain CIRCLE entities when
    :mod:`~stud_planner.drawing.plain_circles` read them (then cut out of ``doc``), else None."""

    doc: Any
    read_mode: str
    warnings: list[str]
    plain: PlainCircles | None


def open_drawing(path: Path, *, plain_circles: bool = True) -> OpenedDrawing:
    """Check and open ``path``: its plain circles as arrays when ``plain_circles`` and the file allows
    it (:func:`load_with_plain_circles`), everything else with ezdxf (recovering a damaged file)."""
    data, file_warns = check_file(path)
    if plain_circles:
        doc, plain = load_with_plain_circles(path, data)
        if plain is not None:
            return OpenedDrawing(doc, "read", file_warns, plain)
    doc, mode, warns = load_checked_document(path, data, file_warns)
    return OpenedDrawing(doc, mode, warns, None)
