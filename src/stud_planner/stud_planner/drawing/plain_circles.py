"""The plain CIRCLE entities of an ASCII DXF's modelspace, read with numpy: a faster path, not a second parser.

A bridge drawing holds 250,000 stud circles. ezdxf builds a Python object per tag and per entity
(about 40 us per circle); this module reads the same circles as arrays (about 2 us per circle).
It is *not* a parser with rules of its own. It only takes over the CIRCLE entities of the
ENTITIES section whose every tag it can decode exactly as ezdxf would (``ascii_tags_loader`` +
``tag_compiler`` + ``Circle.load_dxf_attribs``), cuts them out of the text and lets ezdxf load
the rest of the document -- header, tables, blocks, INSERTs, texts, objects -- as before.
:func:`stud_planner.dxf_layout.read_circles` then treats these circles the way it treats the
ones ezdxf loads (visibility, hidden layers, radius, coordinates; one code path), and the tests
check that both ways give identical results on every file of the DXF corpus.

The whole file goes through ezdxf instead (``split_plain_circles`` returns None) unless *every*
CIRCLE of the ENTITIES section is plain:

* tags: only the group codes of ``_ALLOWED`` (handle 5, owner 330, subclass markers 100, layer
  8, linetype, colour, lineweight, linetype scale, invisible 60, thickness, elevation, centre
  10/20[/30], radius 40, extrusion 210/220[/230], true colour, colour name, transparency,
  shadow, material, plot style, paperspace flag), each at most once (but the subclass markers), a
  handle and owner before the first subclass marker (where ezdxf reads them); no application data
  (102), extension dictionary, XDATA (1001...) or proxy graphics;
* values that ezdxf's ``tag_compiler`` converts (floats; ints, or floats for int codes as it
  accepts); centre y right after x and extrusion y right after x, as ``tag_compiler`` requires;
* extrusion absent or ``(0, 0, z > 0)`` -- other circles need ezdxf's OCS;
* not inside an INSERT's ATTRIB or a POLYLINE's VERTEX sequence (ezdxf links those);
* one ENTITIES section, before the EOF tag, ENDSEC-terminated.

Circles are returned in file order, the order ezdxf's modelspace iterates them in. Owners and
paperspace flags are returned too: the ENTITIES section also holds the active paperspace, and
ezdxf's rule decides (the owner ``*Model_Space`` or ``*Paper_Space``, else the flag), which
:func:`dxf_layout.read_circles` applies once it knows those block records' handles.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

__all__ = ["PlainCircles", "split_plain_circles"]

_FLOAT_CODES = (10, 20, 30, 38, 39, 40, 48, 210, 220, 230)
_INT_CODES = (60, 62, 67, 284, 370, 420, 440)
_STR_CODES = (5, 6, 8, 100, 330, 347, 390, 430)
_ALLOWED = np.array(sorted(_FLOAT_CODES + _INT_CODES + _STR_CODES))
#: Entities that open or continue a sequence ezdxf links (VERTEX -> POLYLINE, ATTRIB -> INSERT).
_IN_SEQUENCE = ("POLYLINE", "VERTEX", "ATTRIB")


@dataclass(frozen=True, eq=False)
class PlainCircles:
    """CIRCLE entities of the modelspace, in file order: values as ezdxf loads them.

    ``centers`` (n, 3) in drawing units (z 0 where the file gives none), ``radius`` (n,),
    ``invisible`` (n,) the DXF group 60 flag, ``paperspace`` (n,) the group 67 flag (0 when absent, as ezdxf treats it),
    ``layers``/``handles``/``owners`` strings (owner None when the file gives none; layer "0"
    when it gives none, as ezdxf's default)."""

    handles: list[str]
    owners: list[str | None]
    layers: list[str]
    centers: np.ndarray
    radius: np.ndarray
    invisible: np.ndarray
    paperspace: np.ndarray

    def __len__(self) -> int:
        return len(self.handles)

    def without(self, drop: np.ndarray) -> "PlainCircles":
        keep = ~np.asarray(drop, dtype=bool)
        pick = np.flatnonzero(keep).tolist()
        return PlainCircles([self.handles[i] for i in pick], [self.owners[i] for i in pick],
                            [self.layers[i] for i in pick], self.centers[keep], self.radius[keep],
                            self.invisible[keep], self.paperspace[keep])


def _floats(values: list[str]) -> np.ndarray:
    """float() of each value, as ezdxf's tag_compiler converts it; ValueError if one fails."""
    return np.fromiter(map(float, values), np.float64, len(values))


def _ints(values: list[str]) -> np.ndarray:
    """int() of each value, or int(float()) as ezdxf's tag_compiler falls back to; ValueError if neither."""
    out = []
    for v in values:
        try:
            out.append(int(v))
        except ValueError:
            out.append(int(float(v)))
    return np.array(out, dtype=np.int64)


def split_plain_circles(text: str) -> tuple[str, PlainCircles] | None:
    """``(text without the plain modelspace circles, those circles)``, or None when the file must
    go to ezdxf whole (see the module docstring). ``text`` is the decoded file with universal
    newlines, exactly what ezdxf's loader reads line by line."""
    lines = text.split("\n")
    if text.endswith("\n"):
        lines.pop()
    if len(lines) % 2:  # a last group code without a value: the loader stops before it
        lines.pop()
    code_lines = lines[0::2]
    if not code_lines:
        return None
    try:
        codes = np.fromiter(map(int, code_lines), np.int64, len(code_lines))  # int() as ezdxf's loader
    except (ValueError, OverflowError):
        return None  # not a group code: ezdxf raises its own error for it
    values = lines[1::2]
    orig = np.flatnonzero(codes != 999)  # comments are skipped by ezdxf's loader
    f_codes = codes[orig]

    zpos = np.flatnonzero(f_codes == 0)
    raw_zero = [values[i] for i in orig[zpos].tolist()]
    eof = next((k for k, v in enumerate(raw_zero) if v == "EOF"), len(raw_zero))  # the loader stops there
    zpos, names = zpos[:eof], [v.strip() for v in raw_zero[:eof]]
    n_f = len(f_codes)

    def value(j: int) -> str:
        return values[orig[j]]

    def take(at: np.ndarray) -> list[str]:
        """The values of the tags at filtered indices ``at``."""
        return [values[i] for i in orig[at].tolist()]

    sections = [k for k, t in enumerate(names) if t == "SECTION" and zpos[k] + 1 < n_f
                and f_codes[zpos[k] + 1] == 2 and value(zpos[k] + 1) == "ENTITIES"]
    if len(sections) != 1:
        return None
    start = sections[0]
    end = next((k for k in range(start + 1, len(names)) if names[k] in ("ENDSEC", "SECTION")), None)
    if end is None or names[end] != "ENDSEC":
        return None
    types = names[start + 1:end]
    ent_first = zpos[start + 1:end]       # filtered index of each entity's (0, TYPE) tag
    ent_stop = zpos[start + 2:end + 1]    # ... and of the next entity's
    is_circle = np.array([t == "CIRCLE" for t in types], dtype=bool)
    if not is_circle.any():
        return None
    circ = np.flatnonzero(is_circle)
    # Not inside a linked sequence: each run of circles follows an entity that opens none.
    for j in circ[(circ == 0) | ~is_circle[np.maximum(circ - 1, 0)]].tolist():
        if j == 0:
            continue
        prev = types[j - 1]
        if prev in _IN_SEQUENCE:
            return None
        if prev == "INSERT":
            body = range(int(ent_first[j - 1]) + 1, int(ent_stop[j - 1]))
            flags = [value(p) for p in body if f_codes[p] == 66]
            try:
                if any(_ints(flags)):
                    return None  # its ATTRIBs follow: the circle would be read as one
            except ValueError:
                return None

    first, stop = ent_first[circ], ent_stop[circ]
    count = stop - first - 1  # tags after (0, CIRCLE)
    m = circ.size
    pos = np.repeat(first + 1, count) + (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count))
    owner = np.repeat(np.arange(m), count)
    pc = f_codes[pos]
    if not np.isin(pc, _ALLOWED).all():
        return None
    for code in _ALLOWED.tolist():  # subclass markers (100) repeat by design and carry no attribute
        if code != 100 and np.bincount(owner[pc == code], minlength=m).max(initial=0) > 1:
            return None  # a repeated group code: ezdxf keeps the last; leave that to it

    def per_circle(code: int) -> np.ndarray:
        """Filtered index of each circle's tag ``code``, -1 where absent."""
        at = np.full(m, -1, np.int64)
        sel = pc == code
        at[owner[sel]] = pos[sel]
        return at

    def strings(at: np.ndarray, default: str | None) -> list:
        if (at >= 0).all():
            return take(at)
        return [default if j < 0 else values[i] for j, i in zip(at.tolist(), orig[at].tolist())]

    p10, p20, p40, p5, p330 = per_circle(10), per_circle(20), per_circle(40), per_circle(5), per_circle(330)
    if (p10 < 0).any() or (p40 < 0).any() or (p5 < 0).any() or not np.array_equal(p20, p10 + 1):
        return None  # tag_compiler needs y right after x
    first_marker = np.full(m, np.iinfo(np.int64).max, np.int64)
    markers = pc == 100
    np.minimum.at(first_marker, owner[markers], pos[markers])
    if (p5 > first_marker).any() or (p330 > first_marker).any():
        return None  # ezdxf takes handle and owner from the tags before the first subclass marker only
    p210, p220 = per_circle(210), per_circle(220)
    if not np.array_equal(p220 >= 0, p210 >= 0) or not np.array_equal(p220[p210 >= 0], p210[p210 >= 0] + 1):
        return None
    try:
        x, y, radius = _floats(take(p10)), _floats(take(p20)), _floats(take(p40))
        for code in _FLOAT_CODES:  # every other value ezdxf would convert must convert here too
            if code not in (10, 20, 40):
                _floats(take(pos[pc == code]))
        for code in _INT_CODES:
            _ints(take(pos[pc == code]))
        has_z = (p20 + 1 < n_f) & (f_codes[np.minimum(p20 + 1, n_f - 1)] == 30)
        z = np.zeros(m)
        z[has_z] = _floats(take(p20[has_z] + 1))
        with_ext = p210 >= 0
        ext = np.tile([0.0, 0.0, 1.0], (m, 1))
        if with_ext.any():
            ext[with_ext, 0] = _floats(take(p210[with_ext]))
            ext[with_ext, 1] = _floats(take(p220[with_ext]))
            ez_at = p220[with_ext] + 1
            ez_ok = (ez_at < n_f) & (f_codes[np.minimum(ez_at, n_f - 1)] == 230)
            ez = np.zeros(ez_at.size)  # a 2D extrusion is (x, y, 0), as ezdxf reads it
            ez[ez_ok] = _floats(take(ez_at[ez_ok]))
            ext[with_ext, 2] = ez
        p60 = per_circle(60)
        invisible = np.zeros(m, dtype=bool)
        invisible[p60 >= 0] = _ints(take(p60[p60 >= 0])) != 0
        p67 = per_circle(67)
        paperspace = np.zeros(m, np.int64)
        paperspace[p67 >= 0] = _ints(take(p67[p67 >= 0]))
    except (ValueError, OverflowError):
        return None
    if not ((ext[:, 0] == 0.0) & (ext[:, 1] == 0.0) & (ext[:, 2] > 0.0)).all():
        return None  # an OCS other than WCS: ezdxf's arbitrary-axis algorithm
    circles = PlainCircles(handles=strings(p5, None), owners=strings(p330, None),
                           layers=strings(per_circle(8), "0"), centers=np.column_stack([x, y, z]),
                           radius=radius, invisible=invisible, paperspace=paperspace)

    # The text without those entities (comments inside them go too; the loader skips them anyway).
    drop = np.zeros(len(codes), dtype=bool)
    orig_first = orig[first]
    orig_stop = orig[stop]  # the next entity's tag (never a circle's: ENDSEC at the latest)
    spans = orig_stop - orig_first
    drop[np.repeat(orig_first, spans) + (np.arange(int(spans.sum())) - np.repeat(np.cumsum(spans) - spans, spans))] = True
    keep_lines = np.repeat(~drop, 2)
    kept = list(itertools.compress(lines, keep_lines.tolist()))
    return "\n".join(kept) + "\n", circles
