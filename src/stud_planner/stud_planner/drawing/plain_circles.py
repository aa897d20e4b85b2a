"""The plain CIRCLE entities of an ASCII DXF's modelspace, read with numpy: a faster path, not a second parser.

A bridge drawing holds 250,000 stud circles. ezdxf builds a Python object per tag and per entity
(about 40 us per circle); this module reads the same circles as arrays (about 2 us per circle).
It is *not* a parser with rules of its own. It only takes over the CIRCLE entities of the
ENTITIES section whose every tag it can decode exactly as ezdxf would (``ascii_tags_loader`` +
``tag_compiler`` + ``Circle.load_dxf_attribs``), cuts them out of the text and lets ezdxf load
the rest of the document -- header, tables, blocks, INSERTs, texts, objects -- as before.
:func:`stud_planner.drawing.circles.read_circles` then treats these circles the way it treats the
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
:func:`stud_planner.drawing.circles.read_circles` applies once it knows those block records' handles.
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


@dataclass(frozen=True, eq=False)
class _Tags:
    """The file's (group code, value) tags, as ezdxf's loader reads them. "Filtered" indices count
    the tags the loader keeps (comments, code 999, left out); ``orig`` maps them to all tags."""

    lines: list[str]
    codes: np.ndarray    # every tag's group code, comments included
    values: list[str]    # every tag's value
    orig: np.ndarray     # filtered index -> index into codes / values
    f_codes: np.ndarray  # the group codes of the filtered tags

    @classmethod
    def of(cls, text: str) -> "_Tags | None":
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
        orig = np.flatnonzero(codes != 999)  # comments are skipped by ezdxf's loader
        return cls(lines, codes, lines[1::2], orig, codes[orig])

    def value(self, j: int) -> str:
        return self.values[self.orig[j]]

    def take(self, at: np.ndarray) -> list[str]:
        """The values of the tags at filtered indices ``at``."""
        return [self.values[i] for i in self.orig[at].tolist()]

    def strings(self, at: np.ndarray, default: str | None) -> list:
        """:meth:`take`, with ``default`` where ``at`` is -1 (the tag is absent)."""
        if (at >= 0).all():
            return self.take(at)
        return [default if j < 0 else self.values[i] for j, i in zip(at.tolist(), self.orig[at].tolist())]


def _entities_section(tags: _Tags) -> tuple[list[str], np.ndarray, np.ndarray] | None:
    """The one ENTITIES section (before EOF, ENDSEC-terminated): the type of each entity, the
    filtered index of its (0, TYPE) tag and that of the next entity's; None if there is no such section."""
    f_codes = tags.f_codes
    zpos = np.flatnonzero(f_codes == 0)
    raw_zero = [tags.values[i] for i in tags.orig[zpos].tolist()]
    eof = next((k for k, v in enumerate(raw_zero) if v == "EOF"), len(raw_zero))  # the loader stops there
    zpos, names = zpos[:eof], [v.strip() for v in raw_zero[:eof]]
    n_f = len(f_codes)
    sections = [k for k, t in enumerate(names) if t == "SECTION" and zpos[k] + 1 < n_f
                and f_codes[zpos[k] + 1] == 2 and tags.value(zpos[k] + 1) == "ENTITIES"]
    if len(sections) != 1:
        return None
    start = sections[0]
    end = next((k for k in range(start + 1, len(names)) if names[k] in ("ENDSEC", "SECTION")), None)
    if end is None or names[end] != "ENDSEC":
        return None
    return names[start + 1:end], zpos[start + 1:end], zpos[start + 2:end + 1]


def _in_linked_sequence(tags: _Tags, types: list[str], ent_first: np.ndarray, ent_stop: np.ndarray,
                        is_circle: np.ndarray) -> bool:
    """Whether a circle may belong to a sequence ezdxf links (a POLYLINE's VERTEXes, an INSERT's
    ATTRIBs): each run of circles must follow an entity that opens none."""
    circ = np.flatnonzero(is_circle)
    for j in circ[(circ == 0) | ~is_circle[np.maximum(circ - 1, 0)]].tolist():
        if j == 0:
            continue
        prev = types[j - 1]
        if prev in _IN_SEQUENCE:
            return True
        if prev == "INSERT":
            body = range(int(ent_first[j - 1]) + 1, int(ent_stop[j - 1]))
            flags = [tags.value(p) for p in body if tags.f_codes[p] == 66]
            try:
                if any(_ints(flags)):
                    return True  # its ATTRIBs follow: the circle would be read as one
            except ValueError:
                return True
    return False


@dataclass(frozen=True, eq=False)
class _CircleTags:
    """The tags of the circles (after their (0, CIRCLE)): filtered index, owning circle, group code."""

    pos: np.ndarray
    owner: np.ndarray
    codes: np.ndarray
    m: int  # circles

    @classmethod
    def of(cls, tags: _Tags, first: np.ndarray, stop: np.ndarray) -> "_CircleTags | None":
        """None when a circle has a tag outside ``_ALLOWED``, or one of them twice."""
        count = stop - first - 1  # tags after (0, CIRCLE)
        m = first.size
        pos = np.repeat(first + 1, count) + (np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count))
        owner = np.repeat(np.arange(m), count)
        pc = tags.f_codes[pos]
        if not np.isin(pc, _ALLOWED).all():
            return None
        for code in _ALLOWED.tolist():  # subclass markers (100) repeat by design and carry no attribute
            if code != 100 and np.bincount(owner[pc == code], minlength=m).max(initial=0) > 1:
                return None  # a repeated group code: ezdxf keeps the last; leave that to it
        return cls(pos, owner, pc, m)

    def at(self, code: int) -> np.ndarray:
        """Filtered index of each circle's tag ``code``, -1 where absent."""
        at = np.full(self.m, -1, np.int64)
        sel = self.codes == code
        at[self.owner[sel]] = self.pos[sel]
        return at

    def all_of(self, code: int) -> np.ndarray:
        """Filtered indices of every circle's tags ``code``."""
        return self.pos[self.codes == code]


def _extrusions(tags: _Tags, p210: np.ndarray, p220: np.ndarray) -> np.ndarray:
    """(m, 3) extrusion vectors, (0, 0, 1) where the file gives none (ValueError: not a float)."""
    n_f = len(tags.f_codes)
    with_ext = p210 >= 0
    ext = np.tile([0.0, 0.0, 1.0], (p210.size, 1))
    if with_ext.any():
        ext[with_ext, 0] = _floats(tags.take(p210[with_ext]))
        ext[with_ext, 1] = _floats(tags.take(p220[with_ext]))
        ez_at = p220[with_ext] + 1
        ez_ok = (ez_at < n_f) & (tags.f_codes[np.minimum(ez_at, n_f - 1)] == 230)
        ez = np.zeros(ez_at.size)  # a 2D extrusion is (x, y, 0), as ezdxf reads it
        ez[ez_ok] = _floats(tags.take(ez_at[ez_ok]))
        ext[with_ext, 2] = ez
    return ext


def _circle_values(tags: _Tags, ct: _CircleTags) -> PlainCircles | None:
    """The circles' values, converted as ezdxf's ``tag_compiler`` does; None when one of them is
    not plain (tag order, a value that does not convert, an extrusion other than +Z)."""
    f_codes, n_f, m = tags.f_codes, len(tags.f_codes), ct.m
    p10, p20, p40, p5, p330 = ct.at(10), ct.at(20), ct.at(40), ct.at(5), ct.at(330)
    if (p10 < 0).any() or (p40 < 0).any() or (p5 < 0).any() or not np.array_equal(p20, p10 + 1):
        return None  # tag_compiler needs y right after x
    first_marker = np.full(m, np.iinfo(np.int64).max, np.int64)
    markers = ct.codes == 100
    np.minimum.at(first_marker, ct.owner[markers], ct.pos[markers])
    if (p5 > first_marker).any() or (p330 > first_marker).any():
        return None  # ezdxf takes handle and owner from the tags before the first subclass marker only
    p210, p220 = ct.at(210), ct.at(220)
    if not np.array_equal(p220 >= 0, p210 >= 0) or not np.array_equal(p220[p210 >= 0], p210[p210 >= 0] + 1):
        return None
    try:
        x, y, radius = _floats(tags.take(p10)), _floats(tags.take(p20)), _floats(tags.take(p40))
        for code in _FLOAT_CODES:  # every other value ezdxf would convert must convert here too
            if code not in (10, 20, 40):
                _floats(tags.take(ct.all_of(code)))
        for code in _INT_CODES:
            _ints(tags.take(ct.all_of(code)))
        has_z = (p20 + 1 < n_f) & (f_codes[np.minimum(p20 + 1, n_f - 1)] == 30)
        z = np.zeros(m)
        z[has_z] = _floats(tags.take(p20[has_z] + 1))
        ext = _extrusions(tags, p210, p220)
        p60 = ct.at(60)
        invisible = np.zeros(m, dtype=bool)
        invisible[p60 >= 0] = _ints(tags.take(p60[p60 >= 0])) != 0
        p67 = ct.at(67)
        paperspace = np.zeros(m, np.int64)
        paperspace[p67 >= 0] = _ints(tags.take(p67[p67 >= 0]))
    except (ValueError, OverflowError):
        return None
    if not ((ext[:, 0] == 0.0) & (ext[:, 1] == 0.0) & (ext[:, 2] > 0.0)).all():
        return None  # an OCS other than WCS: ezdxf's arbitrary-axis algorithm
    return PlainCircles(handles=tags.strings(p5, None), owners=tags.strings(p330, None),
                        layers=tags.strings(ct.at(8), "0"), centers=np.column_stack([x, y, z]),
                        radius=radius, invisible=invisible, paperspace=paperspace)


def _without_entities(tags: _Tags, first: np.ndarray, stop: np.ndarray) -> str:
    """The text without the entities from filtered index ``first`` up to ``stop`` (comments inside
    them go too; the loader skips them anyway)."""
    drop = np.zeros(len(tags.codes), dtype=bool)
    orig_first = tags.orig[first]
    orig_stop = tags.orig[stop]  # the next entity's tag (never a circle's: ENDSEC at the latest)
    spans = orig_stop - orig_first
    drop[np.repeat(orig_first, spans)
         + (np.arange(int(spans.sum())) - np.repeat(np.cumsum(spans) - spans, spans))] = True
    keep_lines = np.repeat(~drop, 2)
    kept = list(itertools.compress(tags.lines, keep_lines.tolist()))
    return "\n".join(kept) + "\n"


def split_plain_circles(text: str) -> tuple[str, PlainCircles] | None:
    """``(text without the plain modelspace circles, those circles)``, or None when the file must
    go to ezdxf whole (see the module docstring). ``text`` is the decoded file with universal
    newlines, exactly what ezdxf's loader reads line by line."""
    tags = _Tags.of(text)
    section = _entities_section(tags) if tags is not None else None
    if tags is None or section is None:
        return None
    types, ent_first, ent_stop = section
    is_circle = np.array([t == "CIRCLE" for t in types], dtype=bool)
    if not is_circle.any() or _in_linked_sequence(tags, types, ent_first, ent_stop, is_circle):
        return None
    circ = np.flatnonzero(is_circle)
    first, stop = ent_first[circ], ent_stop[circ]
    ctags = _CircleTags.of(tags, first, stop)
    circles = _circle_values(tags, ctags) if ctags is not None else None
    if circles is None:
        return None
    return _without_entities(tags, first, stop), circles
