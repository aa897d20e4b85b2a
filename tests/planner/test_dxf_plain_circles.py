"""stud_planner.drawing.plain_circles is a faster path, not a second parser: on every file -- the DXF corpus, the
writer's variants and hand-made oddities -- read_circles gives exactly the same result with it
as with ezdxf alone, and it declines whatever it cannot decode as ezdxf does."""
from __future__ import annotations

from pathlib import Path

import ezdxf
import numpy as np
import pytest

from stud_planner.drawing import DrawingError, read_circles, read_layout
from stud_planner.drawing.dxf_file import check_file, load_with_plain_circles
from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_layout_dxf
from stud_planner.drawing.plain_circles import split_plain_circles

REPO = Path(__file__).resolve().parents[2]
CORPUS = REPO.parent / "shared" / "data" / "dxf"
MARKS = {"O": (0.0, 0.0), "A": (0.6, 0.0), "B": (0.0, 0.3)}
STUDS = np.array([(0.05 + 0.1 * i, 0.05 + 0.08 * j) for j in range(3) for i in range(5)])


def both(path: Path, **kw):
    """read_circles with and without the plain-circle path (a DrawingError message stands for the result)."""
    out = []
    for plain in (True, False):
        try:
            out.append(read_circles(path, plain_circles=plain, **kw))
        except DrawingError as exc:
            out.append(str(exc))
    return out


def assert_same(a, b) -> None:
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
        return
    np.testing.assert_array_equal(a.centers_wcs, b.centers_wcs)
    np.testing.assert_array_equal(a.radii, b.radii)
    assert (a.layers, a.labels, a.layer_entities, a.skipped, a.warnings, a.invalid_entities) == \
           (b.layers, b.labels, b.layer_entities, b.skipped, b.warnings, b.invalid_entities)
    assert (a.dxf_version, a.read_mode, a.insunits, a.source_units, a.units_assumed) == \
           (b.dxf_version, b.read_mode, b.insunits, b.source_units, b.units_assumed)


def used_plain(path: Path) -> bool:
    data, _ = check_file(path)
    return load_with_plain_circles(path, data)[1] is not None


CORPUS_FILES = sorted(p for p in CORPUS.rglob("*") if p.suffix.lower() == ".dxf") if CORPUS.is_dir() else []


@pytest.mark.parametrize("path", CORPUS_FILES or [None], ids=[p.name for p in CORPUS_FILES] or ["no-corpus"])
@pytest.mark.parametrize("hidden", [False, True])
def test_corpus_files_read_the_same_with_and_without_the_plain_path(path, hidden, require_shared_data):
    require_shared_data(CORPUS)
    try:
        check_file(path)
    except DrawingError:
        pass  # refused before any reading: both paths share that check
    a, b = both(path, include_hidden_layers=hidden)
    assert_same(a, b)


def test_the_plain_path_serves_a_fair_part_of_the_corpus(require_shared_data):
    require_shared_data(CORPUS)
    served = [p.name for p in CORPUS_FILES if p.parent == CORPUS and used_plain(p)]
    assert len(served) >= 5, served


@pytest.mark.parametrize("options", [
    {}, {"dxfversion": "R12"}, {"dxfversion": "R2000"}, {"dxfversion": "R2018"}, {"units": "in"},
    {"units": "unitless"}, {"label_kind": "mtext"}, {"as_blocks": True}, {"as_blocks": True, "nested_blocks": True},
    {"ocs_flip": True}, {"binary": True}, {"rotation_deg": 33.0, "origin_wcs_m": (2.5, -1.0)},
    {"stud_layer": ["STUDS", "studs", "STUDS_B"] * 5},
])
def test_writer_variants_read_the_same(tmp_path, options):
    path = write_layout_dxf(tmp_path / "v.dxf", STUDS, MARKS, LayoutDxfOptions(**options))
    a, b = both(path)
    assert_same(a, b)
    assert read_layout(path).studs == read_layout(path).studs
    plain = used_plain(path)
    assert plain == (not options.get("ocs_flip") and not options.get("binary")), "plain path used: " + str(plain)


def _doc_with_extras(tmp_path: Path, edit) -> Path:
    doc = ezdxf.new("R2010", setup=False)
    doc.header["$INSUNITS"] = 4
    for name in ("STUDS", "MARKS", "FROZEN", "OFF"):
        doc.layers.add(name)
    doc.layers.get("FROZEN").freeze()
    doc.layers.get("OFF").off()
    msp = doc.modelspace()
    for x, y in STUDS * 1000:
        msp.add_circle((x, y), 9.5, dxfattribs={"layer": "STUDS"})
    for name, (x, y) in MARKS.items():
        msp.add_circle((x * 1000, y * 1000), 15, dxfattribs={"layer": "MARKS"})
        msp.add_text(name, dxfattribs={"insert": (x * 1000 + 18, y * 1000 + 18), "height": 20})
    msp.add_circle((5, 5), 9.5, dxfattribs={"layer": "FROZEN"})
    msp.add_circle((6, 6), 9.5, dxfattribs={"layer": "OFF"})
    msp.add_circle((7, 7), 9.5, dxfattribs={"layer": "STUDS", "invisible": 1})
    msp.add_circle((8, 8), 0.0, dxfattribs={"layer": "STUDS"})
    doc.paperspace().add_circle((9, 9), 9.5, dxfattribs={"layer": "STUDS"})  # not the modelspace
    path = tmp_path / "x.dxf"
    doc.saveas(path)
    text = edit(path.read_text())
    path.write_bytes(text.encode("utf-8"))
    return path


def _after_first_circle_handle(text: str, insert: str) -> str:
    at = text.index("\nCIRCLE\n")
    end = text.index("\n100\nAcDbCircle\n", at)
    return text[:end] + insert.rstrip("\n") + text[end:]


@pytest.mark.parametrize("edit, plain", [
    (lambda t: t, True),
    (lambda t: t.replace("\n", "\r\n"), True),                                        # DOS line ends
    (lambda t: t.replace("\n", "\r"), True),                                          # classic Mac
    (lambda t: _after_first_circle_handle(t, "\n999\na comment\n"), True),           # comments are skipped
    (lambda t: _after_first_circle_handle(t, "\n 62\n1\n370\n-1\n"), True),          # colour, lineweight
    (lambda t: _after_first_circle_handle(t, "\n 62\n1.0\n"), True),                  # an int written as float
    (lambda t: _after_first_circle_handle(t, "\n 62\nred\n"), False),                 # ezdxf refuses: recover
    (lambda t: _after_first_circle_handle(t, "\n  8\nOTHER\n"), False),               # repeated layer: last wins
    (lambda t: _after_first_circle_handle(t, "\n 67\n1\n"), True),                    # flag, owner *Model_Space
    (lambda t: _after_first_circle_handle(t, "\n 67\n1\n").replace("\n330\n17\n", "\n330\n99\n", 1), True),
    (lambda t: _after_first_circle_handle(t, "\n102\n{ACAD_REACTORS\n330\n1F\n102\n}\n"), False),
    (lambda t: t.replace("\nAcDbCircle\n", "\nAcDbCircle\n1001\nACAD\n1000\nxdata\n", 1), False),
    (lambda t: t + "trash beyond EOF\n", True),
])
def test_oddities_read_the_same_and_the_plain_path_declines_what_it_cannot_decode(tmp_path, edit, plain):
    path = _doc_with_extras(tmp_path, edit)
    for hidden in (False, True):
        a, b = both(path, include_hidden_layers=hidden)
        assert_same(a, b)
    assert used_plain(path) == plain


def test_a_circle_between_an_insert_and_its_attribs_is_left_to_ezdxf():
    text = ("  0\nSECTION\n  2\nENTITIES\n  0\nINSERT\n  5\n20\n  8\n0\n 66\n1\n  2\nB\n 10\n0\n 20\n0\n"
            "  0\nCIRCLE\n  5\n21\n  8\nSTUDS\n 10\n1\n 20\n2\n 40\n3\n  0\nSEQEND\n  5\n22\n  0\nENDSEC\n  0\nEOF\n")
    assert split_plain_circles(text) is None
    ok = text.replace(" 66\n1\n", " 66\n0\n")
    rest, circles = split_plain_circles(ok)
    assert circles.handles == ["21"] and circles.layers == ["STUDS"] and "CIRCLE" not in rest
    np.testing.assert_array_equal(circles.centers, [[1.0, 2.0, 0.0]])
