"""stud_planner.drawing: DXF drawings -> DrawingLayout (drawing frame, metres).

Round trips through drawings written by stud_planner.drawing.dxf_writer (several DXF versions, binary,
block references, units), every error and warning the parser promises, and the real corpus in
shared/data/dxf (CAD programs' and libraries' files: each parses or fails with DrawingError).
"""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import math
import re
import time
from pathlib import Path

import ezdxf
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stud_planner.drawing import (
    DrawingError,
    DrawingLayout,
    LayoutOptions,
    close_pairs,
    read_circles,
    read_layout,
    units_to_metres,
)
from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_layout_dxf

REPO = Path(__file__).resolve().parents[2]
CORPUS = REPO.parent / "shared" / "data" / "dxf"

MARKS = {"O": (0.0, 0.0), "A": (0.6, 0.0), "B": (0.0, 0.3)}
STUDS = np.array([(0.05 + 0.1 * i, 0.05 + 0.08 * j) for j in range(3) for i in range(5)])


def expected_order(xy: np.ndarray) -> np.ndarray:
    """The documented id order for one layer: rows of y (values < 0.1 mm apart), then x."""
    xy = np.asarray(xy)
    by_y = np.argsort(xy[:, 1], kind="stable")
    row = np.empty(len(xy), dtype=np.int64)
    row[by_y] = np.cumsum(np.concatenate([[0], np.diff(xy[by_y, 1]) >= 1e-4]))
    return np.lexsort((xy[:, 0], row))


def assert_studs(layout: DrawingLayout, xy: np.ndarray, diameter_m: float = 0.019, tol: float = 1e-9) -> None:
    assert len(layout.studs) == len(xy)
    np.testing.assert_allclose(layout.studs_xy_m(), xy[expected_order(xy)], atol=tol)
    assert [s.id for s in layout.studs] == [f"S{k + 1:04d}" for k in range(len(xy))]
    np.testing.assert_allclose([s.diameter_m for s in layout.studs], diameter_m, rtol=1e-9)


def assert_marks(layout: DrawingLayout, marks=MARKS, tol: float = 1e-9) -> None:
    for name, (x, y) in marks.items():
        m = layout.marks[name]
        assert (m.name, m.layer) == (name, "MARKS")
        assert m.x_m == pytest.approx(x, abs=tol) and m.y_m == pytest.approx(y, abs=tol)


# -- round trips -------------------------------------------------------------------------------------
@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
@pytest.mark.parametrize("version", ["R12", "R2000", "R2010", "R2018"])
def test_round_trip_in_each_dxf_version(tmp_path, version, binary):
    path = write_layout_dxf(tmp_path / "plate.dxf", STUDS, MARKS, LayoutDxfOptions(dxfversion=version, binary=binary))
    layout = read_layout(path)
    assert_studs(layout, STUDS)
    assert_marks(layout)
    assert layout.dxf_release == version and layout.read_mode == "read"
    assert layout.marks_rule == "labels"
    assert layout.mark_diameter_m == pytest.approx(0.03)
    assert layout.angle_aob_deg == pytest.approx(90.0) and not layout.mirrored
    assert {s.layer for s in layout.studs} == {"STUDS"} and layout.stud_layers == ("STUDS",)
    assert layout.bbox_m == pytest.approx((0.05, 0.05, 0.45, 0.21))
    if version == "R12":  # R12 has no $INSUNITS: unitless, mm assumed, and said so
        assert layout.units_assumed and layout.source_units == "mm"
        assert any("coordinates taken as mm" in w for w in layout.warnings)
    else:
        assert (layout.source_units, layout.insunits, layout.units_assumed) == ("mm", 4, False)
        assert layout.warnings == []


@pytest.mark.parametrize(
    "flavour",
    [
        dict(as_blocks=True),
        dict(as_blocks=True, block_rotation_deg=37.0, block_scale=2.5),
        dict(as_blocks=True, block_rotation_deg=-20.0, mirror_blocks=True),
        dict(as_blocks=True, nested_blocks=True, block_rotation_deg=15.0, block_scale=0.3),
        dict(as_blocks=True, nested_blocks=True, mirror_blocks=True, block_rotation_deg=200.0),
        dict(ocs_flip=True),
        dict(ocs_flip=True, as_blocks=True, block_rotation_deg=33.0, mirror_blocks=True),
        dict(as_blocks=True, dxfversion="R12", block_rotation_deg=90.0),
        dict(as_blocks=True, binary=True, dxfversion="R2018", block_scale=4.0),
    ],
    ids=["insert", "rotated-scaled", "mirrored", "nested", "nested-mirrored", "extrusion-minus-z",
         "extrusion-minus-z-mirrored-insert", "r12-insert", "binary-insert"],
)
def test_block_references_are_expanded_with_their_full_transform(tmp_path, flavour):
    path = write_layout_dxf(tmp_path / "blocks.dxf", STUDS, MARKS,
                            LayoutDxfOptions(origin_wcs_m=(2.0, -1.0), rotation_deg=30.0, **flavour))
    layout = read_layout(path)
    assert_studs(layout, STUDS)
    assert_marks(layout)
    # block content on layer 0 takes the INSERT's layer
    assert {s.layer for s in layout.studs} == {"STUDS"}


def test_insert_matrices_match_ezdxf_for_random_references():
    from stud_planner.drawing.entities import insert_matrices, matrix_of

    rng = np.random.default_rng(3)
    doc = ezdxf.new("R2010")
    blk = doc.blocks.new("B", base_point=(3.0, -4.0, 0.5))
    blk.add_circle((1, 1), 1)
    msp = doc.modelspace()
    for _ in range(20):
        sx, sy, sz = rng.uniform(-3, 3, 3)
        ref = msp.add_blockref("B", tuple(rng.uniform(-100, 100, 3)), dxfattribs={
            "xscale": sx, "yscale": sy, "zscale": sz, "rotation": rng.uniform(-360, 360)})
        d = ref.dxf
        params = np.array([[*d.insert, d.xscale, d.yscale, d.zscale, d.rotation]])
        np.testing.assert_allclose(insert_matrices(params, np.array([3.0, -4.0, 0.5]))[0],
                                   matrix_of(ref.matrix44()), atol=1e-9)


def test_minsert_arrays_are_expanded(tmp_path):
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 4
    blk = doc.blocks.new("STUD")
    blk.add_circle((0, 0), 9.5)
    msp = doc.modelspace()
    ref = msp.add_blockref("STUD", (100, 50), dxfattribs={"layer": "STUDS", "rotation": 90})
    ref.grid(size=(3, 4), spacing=(200, 150))  # 3 rows x 4 columns, in the rotated block frame
    for name, p in zip("OAB", [(0, 0), (1000, 0), (0, 800)]):
        msp.add_circle(p, 15, dxfattribs={"layer": "MARKS"})
        msp.add_text(name, height=20, dxfattribs={"insert": (p[0] + 20, p[1] + 20)})
    doc.saveas(tmp_path / "minsert.dxf")
    layout = read_layout(tmp_path / "minsert.dxf")
    # rotation 90: block x (columns, 150 mm) runs along WCS y, block y (rows, 200 mm) along -x
    expected = np.array([(0.1 - 0.2 * r, 0.05 + 0.15 * c) for r in range(3) for c in range(4)])
    assert_studs(layout, expected)
    assert any("outside the marks' quadrant" in w for w in layout.warnings)


@pytest.mark.parametrize("units, insunits", [("mm", 4), ("cm", 5), ("m", 6), ("in", 1), ("ft", 2), ("dm", 14)])
def test_units_are_converted_to_metres(tmp_path, units, insunits):
    path = write_layout_dxf(tmp_path / f"u_{units}.dxf", STUDS, MARKS, LayoutDxfOptions(units=units))
    layout = read_layout(path)
    assert (layout.source_units, layout.insunits, layout.units_assumed) == (units, insunits, False)
    assert_studs(layout, STUDS)
    assert_marks(layout)
    assert layout.metres_per_unit == units_to_metres(units)[2]


@pytest.mark.parametrize("written_as, read_as", [("mm", "mm"), ("cm", "cm"), ("in", "in")])
def test_unitless_drawing_uses_the_parameter_and_warns(tmp_path, written_as, read_as):
    path = write_layout_dxf(tmp_path / "unitless.dxf", STUDS, MARKS,
                            LayoutDxfOptions(units="unitless", unitless_as=written_as))
    layout = read_layout(path, units_if_unitless=read_as)
    assert layout.units_assumed and layout.insunits == 0 and layout.source_units == read_as
    assert_studs(layout, STUDS)
    assert any(f"coordinates taken as {read_as} (units_if_unitless)" in w for w in layout.warnings)


def test_units_table_covers_the_common_codes():
    for code, name, metres in [(1, "in", 0.0254), (2, "ft", 0.3048), (3, "mi", 1609.344), (4, "mm", 1e-3),
                               (5, "cm", 1e-2), (6, "m", 1.0), (10, "yd", 0.9144), (13, "um", 1e-6),
                               (14, "dm", 0.1)]:
        assert units_to_metres(code) == (code, name, metres)
        assert units_to_metres(name) == (code, name, metres)
    assert units_to_metres("µm")[0] == 13 and units_to_metres("Inches")[0] == 1
    with pytest.raises(ValueError):
        units_to_metres("furlong")


# -- the frame and the marks --------------------------------------------------------------------------
@settings(max_examples=15, deadline=None)
@given(
    rotation=st.floats(-180, 180),
    ox=st.floats(-50, 50),
    oy=st.floats(-50, 50),
    labels=st.booleans(),
    seed=st.integers(0, 2**16),
)
def test_frame_is_recovered_for_any_placement_in_the_wcs(tmp_path_factory, rotation, ox, oy, labels, seed):
    rng = np.random.default_rng(seed)
    studs = rng.uniform([0.02, 0.02], [0.58, 0.28], (12, 2))
    studs = studs[np.argsort(studs[:, 0])]
    studs = studs[np.r_[True, np.diff(studs[:, 0]) > 0.002]]  # no accidental duplicates
    path = write_layout_dxf(tmp_path_factory.mktemp("p") / "p.dxf", studs, MARKS,
                            LayoutDxfOptions(rotation_deg=rotation, origin_wcs_m=(ox, oy), labels=labels))
    layout = read_layout(path, min_spacing_m=0)
    assert layout.marks_rule == ("labels" if labels else "geometry")
    assert_studs(layout, studs, tol=1e-7)
    assert_marks(layout, tol=1e-7)
    np.testing.assert_allclose(layout.drawing_to_wcs(layout.studs_xy_m()) / 1e3,
                               layout.studs_xy_m() @ np.array([[math.cos(math.radians(rotation)),
                                                                 math.sin(math.radians(rotation))],
                                                                [-math.sin(math.radians(rotation)),
                                                                 math.cos(math.radians(rotation))]])
                               + (ox, oy), atol=1e-7)


def test_unlabelled_marks_use_the_geometry_rule(tmp_path):
    # a right angle at O and B counter-clockwise from A: nothing else to go on
    path = write_layout_dxf(tmp_path / "g.dxf", STUDS, MARKS, LayoutDxfOptions(labels=False, rotation_deg=-70.0))
    layout = read_layout(path)
    assert layout.marks_rule == "geometry"
    assert_marks(layout)
    assert_studs(layout, STUDS)


def test_geometry_rule_picks_the_right_handed_frame_when_the_drawing_is_mirrored(tmp_path):
    # WCS mirrored: B lies clockwise from A. Without labels, the rule (OA x OB > 0) swaps A and B.
    path = write_layout_dxf(tmp_path / "m.dxf", STUDS, MARKS, LayoutDxfOptions(labels=False, mirror_frame=True))
    layout = read_layout(path)
    assert layout.marks_rule == "geometry" and not layout.mirrored
    assert_marks(layout, {"O": (0, 0), "A": (0.3, 0), "B": (0, 0.6)})
    assert_studs(layout, STUDS[:, ::-1])


def test_labels_win_over_handedness_and_the_mirrored_frame_is_reported(tmp_path):
    path = write_layout_dxf(tmp_path / "m.dxf", STUDS, MARKS, LayoutDxfOptions(mirror_frame=True))
    layout = read_layout(path)
    assert layout.marks_rule == "labels" and layout.mirrored
    assert_marks(layout)
    assert_studs(layout, STUDS)
    assert any("B is clockwise from A" in w and "mirrored" in w for w in layout.warnings)


def test_mtext_labels_identify_the_marks(tmp_path):
    # O/A/B positions chosen so that geometry alone would name them differently (right angle at "A")
    marks = {"O": (0.0, 0.0), "A": (0.5, 0.5), "B": (0.0, 0.6)}
    path = write_layout_dxf(tmp_path / "mt.dxf", STUDS, marks, LayoutDxfOptions(label_kind="mtext", dxfversion="R2018"))
    layout = read_layout(path)
    assert layout.marks_rule == "labels"
    assert layout.mark_a.x_m == pytest.approx(math.hypot(0.5, 0.5))
    assert any("not perpendicular" in w and "45.00" in w for w in layout.warnings)


def test_attrib_labels_and_concentric_mark_rings(tmp_path):
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 4
    blk = doc.blocks.new("MARK")
    blk.add_circle((0, 0), 15)
    blk.add_circle((0, 0), 8)  # a target drawn as two rings is one mark
    blk.add_attdef("NAME", (20, 20), dxfattribs={"height": 20})
    msp = doc.modelspace()
    for name, p in zip("BOA", [(100, 500), (100, 100), (700, 100)]):
        ref = msp.add_blockref("MARK", p, dxfattribs={"layer": "MARKS"})
        ref.add_auto_attribs({"NAME": name})
    msp.add_circle((300, 300), 9.5, dxfattribs={"layer": "STUDS"})
    doc.saveas(tmp_path / "attrib.dxf")
    layout = read_layout(tmp_path / "attrib.dxf")
    assert layout.marks_rule == "labels"
    assert layout.mark_diameter_m == pytest.approx(0.03)
    assert_marks(layout, {"O": (0, 0), "A": (0.6, 0), "B": (0, 0.4)})
    assert layout.studs[0].x_m == pytest.approx(0.2) and layout.studs[0].y_m == pytest.approx(0.2)
    assert len(read_layout(tmp_path / "attrib.dxf", stud_layers="*").studs) == 1  # rings are not studs


def test_partial_labels_fall_back_to_geometry_and_say_so(tmp_path):
    doc = _plain_doc(STUDS * 1e3, marks=None)
    msp = doc.modelspace()
    for p in [(0, 0), (600, 0), (0, 300)]:
        msp.add_circle(p, 15, dxfattribs={"layer": "MARKS"})
    msp.add_text("O", height=20, dxfattribs={"insert": (20, 20)})
    doc.saveas(tmp_path / "partial.dxf")
    layout = read_layout(tmp_path / "partial.dxf")
    assert layout.marks_rule == "geometry"
    assert any("only label(s) O found" in w for w in layout.warnings)
    assert_marks(layout)


def test_frame_with_non_perpendicular_marks_keeps_x_along_oa(tmp_path):
    marks = {"O": (0.0, 0.0), "A": (0.6, 0.0), "B": (0.02, 0.3)}  # 86.2 deg
    layout = read_layout(write_layout_dxf(tmp_path / "np.dxf", STUDS, marks, LayoutDxfOptions(rotation_deg=10)))
    assert layout.angle_aob_deg == pytest.approx(math.degrees(math.atan2(0.3, 0.02)))
    assert layout.mark_b.x_m == pytest.approx(0.02) and layout.mark_b.y_m == pytest.approx(0.3)
    assert_studs(layout, STUDS)
    assert any("not perpendicular" in w for w in layout.warnings)


# -- ids, layers, filters -----------------------------------------------------------------------------
def _plain_doc(studs_mm, layers=None, marks=MARKS, diameters=None, version="R2010"):
    doc = ezdxf.new(version)
    doc.header["$INSUNITS"] = 4
    msp = doc.modelspace()
    for k, p in enumerate(studs_mm):
        msp.add_circle(tuple(p), (diameters[k] if diameters is not None else 19.0) / 2,
                       dxfattribs={"layer": layers[k] if layers else "STUDS"})
    if marks:
        for name, (x, y) in marks.items():
            msp.add_circle((x * 1e3, y * 1e3), 15, dxfattribs={"layer": "MARKS"})
            msp.add_text(name, height=20, dxfattribs={"insert": (x * 1e3 + 20, y * 1e3 + 20)})
    return doc


def test_ids_do_not_depend_on_entity_order_in_the_file(tmp_path):
    rng = np.random.default_rng(7)
    layers = ["STUDS_B" if k % 3 else "studs_a" for k in range(len(STUDS))]
    results = []
    for trial in range(3):
        perm = rng.permutation(len(STUDS)) if trial else np.arange(len(STUDS))
        doc = _plain_doc(STUDS[perm] * 1e3, [layers[k] for k in perm])
        doc.saveas(tmp_path / f"o{trial}.dxf")
        layout = read_layout(tmp_path / f"o{trial}.dxf", stud_layers=["STUDS*"])
        results.append([(s.id, round(s.x_m, 9), round(s.y_m, 9), s.layer) for s in layout.studs])
    assert results[0] == results[1] == results[2]
    # layer first (case-folded), then y, then x
    assert [r[3] for r in results[0]] == sorted((r[3] for r in results[0]), key=str.casefold)
    a = [r for r in results[0] if r[3] == "studs_a"]
    assert [r[1:3] for r in a] == sorted((r[1:3] for r in a), key=lambda p: (p[1], p[0]))


def test_ids_order_uses_a_tenth_of_a_millimetre_grid(tmp_path):
    # two studs in "one row" whose y differs by 0.02 mm: ordered by x
    studs = np.array([[300.0, 100.02], [200.0, 100.0], [100.0, 100.04]])
    doc = _plain_doc(studs)
    doc.saveas(tmp_path / "row.dxf")
    layout = read_layout(tmp_path / "row.dxf")
    assert [round(s.x_m, 3) for s in layout.studs] == [0.1, 0.2, 0.3]


@pytest.mark.parametrize("shift_mm", [0.0, 0.05])
def test_ids_do_not_change_with_the_placement_of_the_drawing(tmp_path, shift_mm):
    # Rows on odd quarter inches sit on half of a 0.1 mm grid (2.25 in = 571.5 x 0.1 mm): a
    # rotated copy's float noise must not move a stud across a row or column boundary.
    rows_in = np.array([2.25, 5.25, 8.25])
    local = np.array([(x, y) for y in rows_in for x in (5.5, 1.0, 4.0, 2.5)]) * 25.4 + shift_mm  # mm
    marks = {"O": (0.0, 0.0), "A": (0.4, 0.0), "B": (0.0, 0.3)}
    ids = []
    rng = np.random.default_rng(11)
    placements = [(0.0, (0, 0))] + [(a, tuple(o))
                                    for a, o in zip(rng.uniform(-180, 180, 9), rng.uniform(-3e5, 3e5, (9, 2)))]
    for k, (angle, off) in enumerate(placements):
        c, sn = math.cos(math.radians(angle)), math.sin(math.radians(angle))
        R = np.array([[c, -sn], [sn, c]])
        doc = ezdxf.new("R2010")
        doc.header["$INSUNITS"] = 4
        msp = doc.modelspace()
        for p in local @ R.T + off:
            msp.add_circle(tuple(p), 6.35, dxfattribs={"layer": "STUDS"})
        for name, (x, y) in marks.items():
            q = R @ (np.array([x, y]) * 1e3) + off
            msp.add_circle(tuple(q), 15, dxfattribs={"layer": "MARKS"})
            msp.add_text(name, height=20, dxfattribs={"insert": tuple(q + R @ (20.0, 20.0))})
        doc.saveas(tmp_path / f"p{k}.dxf")
        layout = read_layout(tmp_path / f"p{k}.dxf")
        ids.append([(s.id, round(s.x_m * 1e3, 3), round(s.y_m * 1e3, 3)) for s in layout.studs])
    assert all(placed == ids[0] for placed in ids[1:])
    xs = [x for _, x, _ in ids[0]]
    assert xs[:4] == sorted(xs[:4]) and xs[4:8] == sorted(xs[4:8])  # along x within each row


def test_what_cad_does_not_show_is_skipped_and_said(tmp_path):
    doc = _plain_doc(STUDS * 1e3)
    msp = doc.modelspace()
    msp.add_circle((400, 400), 9.5, dxfattribs={"layer": "STUDS", "invisible": 1})
    doc.layers.add("STUDS_OLD").freeze()
    doc.layers.add("STUDS_OFF").off()
    msp.add_circle((410, 500), 9.5, dxfattribs={"layer": "STUDS_OLD"})
    msp.add_circle((420, 600), 9.5, dxfattribs={"layer": "STUDS_OFF"})
    block = doc.blocks.new("STUD")
    block.add_circle((0, 0), 9.5)  # layer 0: takes the INSERT's layer
    block.add_circle((0, 50), 9.5, dxfattribs={"layer": "STUDS"})
    msp.add_blockref("STUD", (700, 100), dxfattribs={"layer": "STUDS_OLD"})  # frozen: both circles hidden
    msp.add_blockref("STUD", (800, 100), dxfattribs={"layer": "STUDS_OFF"})  # off: only the layer-0 circle
    doc.saveas(tmp_path / "hidden.dxf")
    layout = read_layout(tmp_path / "hidden.dxf", stud_layers=["STUDS*"])
    assert len(layout.studs) == len(STUDS) + 1
    assert [round(s.x_m, 3) for s in layout.studs if s.y_m > 0.1 and s.x_m > 0.75] == [0.8]
    text = " | ".join(layout.warnings)
    assert "invisible entities (DXF group 60) skipped" in text and "1 CIRCLE" in text
    assert "STUDS_OFF (off): 2 CIRCLE" in text and "STUDS_OLD (frozen): 1 CIRCLE, 1 INSERT" in text
    everything = read_layout(tmp_path / "hidden.dxf", stud_layers=["STUDS*"], include_hidden_layers=True)
    assert len(everything.studs) == len(STUDS) + 6  # the invisible circle stays out


def test_a_hidden_stud_layer_is_named_in_the_error(tmp_path):
    doc = _plain_doc(STUDS * 1e3)
    doc.layers.add("STUDS").off()
    doc.saveas(tmp_path / "off.dxf")
    message = _error(tmp_path / "off.dxf")
    assert "no studs found" in message and f"{len(STUDS)} circles (frozen or off layer)" in message
    assert len(read_layout(tmp_path / "off.dxf", include_hidden_layers=True).studs) == len(STUDS)


def test_the_exact_layer_name_wins_over_its_glob_reading(tmp_path):
    doc = _plain_doc(STUDS * 1e3, ["STUDS[M16]"] * len(STUDS))
    doc.saveas(tmp_path / "brackets.dxf")
    assert len(read_layout(tmp_path / "brackets.dxf", stud_layers=["studs[m16]"]).studs) == len(STUDS)


def test_no_studs_error_says_why_circles_were_skipped(tmp_path):
    doc = _plain_doc([])
    block = doc.blocks.new("STUD")
    block.add_circle((0, 0), 9.5)
    for k in range(5):
        doc.modelspace().add_blockref("STUD", (100 + 150 * k, 100), dxfattribs={"layer": "STUDS", "yscale": 1.2})
    doc.saveas(tmp_path / "ellipses.dxf")
    message = _error(tmp_path / "ellipses.dxf")
    assert "no studs found" in message and "skipped while reading: 5 circles (non-uniform scale)" in message


def test_a_long_formatted_mtext_label_names_its_mark(tmp_path):
    doc = _plain_doc(STUDS * 1e3, marks=None)
    msp = doc.modelspace()
    for name, (x, y) in {**MARKS, "X": (0.5, 0.5)}.items():
        msp.add_circle((x * 1e3, y * 1e3), 15, dxfattribs={"layer": "MARKS"})
    raw = "{\\fArial Unicode MS|b1|i0|c0|p34;\\C1;\\H1.5x;\\W0.9;\\T1.1;\\Q0;\\pxqc;O}"
    assert len(raw) > 64
    msp.add_mtext(raw, dxfattribs={"insert": (20, 20), "char_height": 20})
    for name in "AB":
        x, y = MARKS[name]
        msp.add_text(name, height=20, dxfattribs={"insert": (x * 1e3 + 20, y * 1e3 + 20)})
    doc.saveas(tmp_path / "mtext.dxf")
    layout = read_layout(tmp_path / "mtext.dxf")
    assert layout.marks_rule == "labels"
    assert_marks(layout)


def test_classic_mac_line_ends_are_read(tmp_path):
    _plain_doc(STUDS * 1e3).saveas(tmp_path / "lf.dxf")
    data = (tmp_path / "lf.dxf").read_bytes().replace(b"\r\n", b"\n").replace(b"\n", b"\r")
    (tmp_path / "cr.dxf").write_bytes(data)
    assert_studs(read_layout(tmp_path / "cr.dxf"), STUDS)
    (tmp_path / "cut.dxf").write_bytes(data[: len(data) // 2])
    assert "truncated or corrupt" in _error(tmp_path / "cut.dxf")


def test_a_stud_on_a_mark_is_reported(tmp_path):
    doc = _plain_doc(STUDS * 1e3)
    doc.modelspace().add_circle((600, 0), 25, dxfattribs={"layer": "STUDS"})  # a ring around mark A
    doc.saveas(tmp_path / "ring.dxf")
    layout = read_layout(tmp_path / "ring.dxf")
    assert any("lie(s) on mark A" in w for w in layout.warnings), layout.warnings


def test_stud_layers_are_case_insensitive_glob_patterns(tmp_path):
    layers = ["Studs-M16", "STUDS-M19", "other", "studs"] * 3 + ["x", "y", "z"]
    doc = _plain_doc(STUDS * 1e3, layers)
    doc.saveas(tmp_path / "layers.dxf")
    assert len(read_layout(tmp_path / "layers.dxf").studs) == 3
    assert len(read_layout(tmp_path / "layers.dxf", stud_layers=["studs-*"]).studs) == 6
    assert len(read_layout(tmp_path / "layers.dxf", stud_layers=["studs-m16", "OTHER"]).studs) == 6
    everything = read_layout(tmp_path / "layers.dxf", stud_layers="*")
    assert len(everything.studs) == 15  # the three mark circles are never studs
    assert set(everything.stud_layers) == set(layers)


def test_the_options_object_and_the_keywords_read_the_same(tmp_path):
    layers = ["Studs-M16", "STUDS-M19", "other", "studs"] * 3 + ["x", "y", "z"]
    _plain_doc(STUDS * 1e3, layers).saveas(tmp_path / "layers.dxf")
    options = LayoutOptions(stud_layers=["studs-*"], min_spacing_m=0.0)
    by_options = read_layout(tmp_path / "layers.dxf", options)
    assert len(by_options.studs) == 6
    assert by_options == read_layout(tmp_path / "layers.dxf", stud_layers=["studs-*"], min_spacing_m=0.0)
    wider = options.with_changes(stud_layers="*")   # a copy: the options are frozen
    assert options.stud_layers == ("studs-*",) and len(read_layout(tmp_path / "layers.dxf", wider).studs) == 15
    assert len(read_layout(tmp_path / "layers.dxf", options, stud_layers="*").studs) == 15   # keywords change it
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.min_spacing_m = 1.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        read_layout(tmp_path / "layers.dxf", stud_layer="*")   # a misspelt option is not silently ignored


def test_diameter_filter_keeps_only_studs_in_range(tmp_path):
    diameters = [16.0, 19.0, 22.0, 5.0, 19.0] * 3
    doc = _plain_doc(STUDS * 1e3, diameters=diameters)
    doc.saveas(tmp_path / "d.dxf")
    layout = read_layout(tmp_path / "d.dxf", min_diameter_m=0.015, max_diameter_m=0.020)
    assert sorted({round(s.diameter_m * 1e3, 6) for s in layout.studs}) == [16.0, 19.0]
    assert len(layout.studs) == 9
    assert any("6 circles on stud layers outside the diameter filter [15, 20] mm" in w for w in layout.warnings)
    with pytest.raises(DrawingError, match="pass the diameter filter"):
        read_layout(tmp_path / "d.dxf", min_diameter_m=0.1)


# -- warnings ---------------------------------------------------------------------------------------
def test_duplicates_within_1_mm_are_merged_with_a_warning(tmp_path):
    studs = np.vstack([STUDS * 1e3, STUDS[:4] * 1e3 + [0.4, -0.3]])
    layers = ["STUDS"] * len(STUDS) + ["STUDS2"] * 4
    doc = _plain_doc(studs, layers)
    doc.saveas(tmp_path / "dup.dxf")
    layout = read_layout(tmp_path / "dup.dxf", stud_layers=["STUDS", "STUDS2"])
    assert_studs(layout, STUDS)  # the first in id order (layer STUDS) is kept
    assert any("4 duplicate studs within 1 mm removed" in w for w in layout.warnings)


def test_spacing_outlier_and_quadrant_warnings(tmp_path):
    studs = np.vstack([STUDS, [[0.062, 0.05], [-0.05, 0.1], [0.3, -0.02]]]) * 1e3
    diameters = [19.0] * len(STUDS) + [19.0, 40.0, 19.0]
    doc = _plain_doc(studs, diameters=diameters)
    doc.saveas(tmp_path / "w.dxf")
    layout = read_layout(tmp_path / "w.dxf")
    w = "\n".join(layout.warnings)
    assert "1 stud pairs closer than min spacing 47.5 mm" in w and "12.0 mm" in w  # 2.5 x 19 mm
    assert "1 studs with unusual diameter (median 19.00 mm)" in w and "40.00 mm" in w
    assert "2 studs outside the marks' quadrant" in w
    assert not any("closer than" in x for x in read_layout(tmp_path / "w.dxf", min_spacing_m=0).warnings)
    assert "pairs closer than min spacing 100.0 mm" in "\n".join(
        read_layout(tmp_path / "w.dxf", min_spacing_m=0.1).warnings)


def test_pairs_closer_than_the_gun_allows_are_warned_with_what_the_driver_will_do(tmp_path):
    """The standard's spacing (2.5 d) passes a pair 30 mm apart; the gun's foot needing 35 mm does not."""
    studs = np.vstack([STUDS, [[0.09, 0.09], [0.12, 0.09]]]) * 1e3  # the added pair: 30 mm apart, 50 mm from others
    doc = _plain_doc(studs, diameters=[10.0] * len(studs))
    doc.saveas(tmp_path / "g.dxf")
    assert not any("closer than" in x for x in read_layout(tmp_path / "g.dxf").warnings)  # 25 mm: none
    layout = read_layout(tmp_path / "g.dxf", gun_spacing_m=0.035)
    gun = [x for x in layout.warnings if "gun" in x]
    assert len(gun) == 1 and "closer than the weld gun's foot allows (gun_spacing_m) 35.0 mm" in gun[0], gun
    a, b = (layout.studs[k].id for k in np.flatnonzero(np.isin(np.round(layout.studs_xy_m()[:, 0], 6), [0.09, 0.12])
                                                       & np.isclose(layout.studs_xy_m()[:, 1], 0.09)))
    assert f"{a}-{b} 30.0 mm" in gun[0] and "refuses the other" in gun[0], gun
    pairs_under = int(gun[0].split(": ")[1].split()[0])  # every pair under 35 mm, the drawing's own ones too
    xy = layout.studs_xy_m()
    dist = np.linalg.norm(xy[:, None] - xy[None], axis=2)[np.triu_indices(len(xy), 1)]
    assert pairs_under == int(np.sum(dist < 0.035))


def test_radius_le_0_nonuniform_and_degenerate_inserts_are_skipped_with_warnings(tmp_path):
    doc = _plain_doc(STUDS * 1e3)
    msp = doc.modelspace()
    msp.add_circle((250, 150), 0, dxfattribs={"layer": "STUDS"})
    msp.add_circle((260, 150), -3, dxfattribs={"layer": "STUDS"})
    blk = doc.blocks.new("S")
    blk.add_circle((0, 0), 9.5)
    msp.add_blockref("S", (250, 250), dxfattribs={"layer": "STUDS", "xscale": 2, "yscale": 1})  # ellipse
    msp.add_blockref("S", (250, 260), dxfattribs={"layer": "STUDS", "xscale": 7.77, "yscale": 7.77})
    doc.saveas(tmp_path / "skip.dxf")
    text = (tmp_path / "skip.dxf").read_text()
    (tmp_path / "skip.dxf").write_text(text.replace("\n7.77\n", "\n0.0\n"))  # ezdxf refuses to write scale 0
    layout = read_layout(tmp_path / "skip.dxf")
    assert_studs(layout, STUDS)
    w = "\n".join(layout.warnings)
    assert "2 circles with radius <= 0 skipped" in w
    assert "1 circles in non-uniformly scaled block references are ellipses and were skipped" in w
    assert "INSERT of block 'S': degenerate transform (zero scale); 1 reference skipped" in w


def test_rounding_level_scale_differences_keep_circles(tmp_path):
    doc = _plain_doc(STUDS * 1e3)
    blk = doc.blocks.new("S")
    blk.add_circle((0, 0), 9.5)
    doc.modelspace().add_blockref("S", (550, 280), dxfattribs={"layer": "STUDS", "xscale": 1.0, "yscale": 1.000001})
    doc.saveas(tmp_path / "round.dxf")
    layout = read_layout(tmp_path / "round.dxf")
    assert len(layout.studs) == len(STUDS) + 1 and layout.warnings == []


def test_missing_eof_after_a_closed_section_is_read_with_a_warning(tmp_path):
    text = write_layout_dxf(tmp_path / "ok.dxf", STUDS, MARKS).read_text()
    path = tmp_path / "no_eof.dxf"
    path.write_text(text[: text.rindex("  0\nEOF")])
    layout = read_layout(path)
    assert_studs(layout, STUDS)
    assert any("no EOF marker" in w for w in layout.warnings)


def test_recoverable_damage_is_read_with_a_warning(tmp_path):
    path = write_layout_dxf(tmp_path / "ok.dxf", STUDS, MARKS)
    text = path.read_text()
    i = text.index("  0\nSECTION\n  2\nENTITIES")
    damaged = tmp_path / "damaged.dxf"
    damaged.write_text(text[:i] + "  0\nENDSEC\n" + text[i:])
    layout = read_layout(damaged)
    assert layout.read_mode == "recover"
    assert_studs(layout, STUDS)
    assert any("damaged DXF" in w and "ezdxf.recover" in w for w in layout.warnings)


# -- errors ------------------------------------------------------------------------------------------
def _error(path, **kwargs) -> str:
    with pytest.raises(DrawingError) as info:
        read_layout(path, **kwargs)
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    return message


def test_error_missing_file_and_directory(tmp_path):
    assert "file not found" in _error(tmp_path / "nope.dxf")
    assert "is a directory" in _error(tmp_path)


def test_error_not_a_dxf(tmp_path):
    (tmp_path / "notes.dxf").write_text("hello, this is not a drawing\n")
    assert "not a DXF file" in _error(tmp_path / "notes.dxf")
    (tmp_path / "empty.dxf").write_bytes(b"")
    assert "empty file" in _error(tmp_path / "empty.dxf")
    (tmp_path / "plan.dxf").write_bytes(b"AC1032\x00\x00\x00\x00\x00\x03\x00")
    assert "looks like a DWG" in _error(tmp_path / "plan.dxf")
    (tmp_path / "blob.dxf").write_bytes(bytes(range(256)) * 4)
    assert "not a DXF file" in _error(tmp_path / "blob.dxf")


@pytest.mark.parametrize("binary", [False, True], ids=["ascii", "binary"])
@pytest.mark.parametrize("fraction", [0.3, 0.6, 0.95])
def test_error_truncated_file(tmp_path, fraction, binary):
    data = write_layout_dxf(tmp_path / "full.dxf", STUDS, MARKS, LayoutDxfOptions(binary=binary)).read_bytes()
    cut = tmp_path / "cut.dxf"
    cut.write_bytes(data[: int(len(data) * fraction)])
    assert "truncated or corrupt" in _error(cut)


def test_error_corrupt_dxf(tmp_path):
    text = write_layout_dxf(tmp_path / "full.dxf", STUDS, MARKS).read_text()
    bad = tmp_path / "bad.dxf"
    i = text.index("ENTITIES") + 200
    bad.write_text(text[:i] + "garbage\n" * 5 + text[i:])
    assert "truncated or corrupt DXF" in _error(bad)


def test_error_no_studs_lists_the_layers_with_counts(tmp_path):
    doc = _plain_doc(STUDS * 1e3, ["Holes"] * len(STUDS))
    doc.modelspace().add_line((0, 0), (1, 1), dxfattribs={"layer": "Walls"})
    doc.saveas(tmp_path / "holes.dxf")
    message = _error(tmp_path / "holes.dxf")
    assert re.search(r"no studs found: no circles on layer\(s\) STUDS; layers: Holes \(15 entities, 15 circles\), "
                     r"MARKS \(3 entities, 3 circles\), 0 \(3 entities\), Walls \(1 entities\)", message) or (
        "no studs found" in message and "Holes (15 entities, 15 circles)" in message
        and "Walls (1 entities)" in message), message


def test_error_marks_missing(tmp_path):
    doc = _plain_doc(STUDS * 1e3, marks={"O": (0, 0), "A": (0.6, 0)})
    doc.saveas(tmp_path / "two.dxf")
    assert "marks missing: found 2 mark circles on layer MARKS, need 3 (O, A, B)" in _error(tmp_path / "two.dxf")
    assert "found 0 mark circles on layer TARGETS" in _error(tmp_path / "two.dxf", mark_layer="TARGETS")


def test_error_marks_ambiguous(tmp_path):
    doc = _plain_doc(STUDS * 1e3, marks=None)
    for p in [(0, 0), (600, 0), (0, 300), (600, 300)]:
        doc.modelspace().add_circle(p, 15, dxfattribs={"layer": "MARKS"})
    doc.saveas(tmp_path / "four.dxf")
    assert "marks ambiguous: found 4 mark circles on layer MARKS" in _error(tmp_path / "four.dxf")

    doc = _plain_doc(STUDS * 1e3, marks=None)  # isosceles, 80/80/20 deg: no clear right angle
    for p in [(0, 0), (600, 0), (300, 300 * math.tan(math.radians(80)))]:
        doc.modelspace().add_circle(p, 15, dxfattribs={"layer": "MARKS"})
    doc.saveas(tmp_path / "iso.dxf")
    assert "no clear right angle" in _error(tmp_path / "iso.dxf")

    doc = _plain_doc(STUDS * 1e3, marks=None)  # two circles both labelled O
    for p, name in zip([(0, 0), (600, 0), (0, 300)], "OOB"):
        doc.modelspace().add_circle(p, 15, dxfattribs={"layer": "MARKS"})
        doc.modelspace().add_text(name, height=20, dxfattribs={"insert": (p[0] + 20, p[1] + 20)})
    doc.saveas(tmp_path / "oo.dxf")
    assert "label 'O' is nearest to 2 mark circles" in _error(tmp_path / "oo.dxf")


def test_error_collinear_and_coincident_marks(tmp_path):
    for labels in (True, False):
        line = {"O": (0.0, 0.0), "A": (0.6, 0.0), "B": (0.3, 0.001)}
        path = write_layout_dxf(tmp_path / f"line{labels}.dxf", STUDS, line, LayoutDxfOptions(labels=labels))
        assert "marks collinear" in _error(path)
    close = {"O": (0.0, 0.0), "A": (0.02, 0.0), "B": (0.0, 0.3)}  # 30 mm marks overlap
    path = write_layout_dxf(tmp_path / "close.dxf", STUDS, close, LayoutDxfOptions(labels=False))
    assert "marks coincident" in _error(path)
    doc = _plain_doc(STUDS * 1e3, marks=None)
    for name, p, label in [("O", (0, 0), (-40, -40)), ("A", (20, 0), (60, 0)), ("B", (0, 300), (20, 320))]:
        doc.modelspace().add_circle(p, 15, dxfattribs={"layer": "MARKS"})
        doc.modelspace().add_text(name, height=20, dxfattribs={"insert": label})
    doc.saveas(tmp_path / "close_labelled.dxf")
    assert "marks coincident: O and A are 20.000 mm apart" in _error(tmp_path / "close_labelled.dxf")


def test_unexpected_ezdxf_failures_become_drawing_errors(tmp_path, monkeypatch):
    from stud_planner.drawing.entities import EntityCollector

    path = write_layout_dxf(tmp_path / "ok.dxf", STUDS, MARKS)

    def boom(*args, **kwargs):
        raise KeyError("weird entity")

    monkeypatch.setattr(EntityCollector, "scan", boom)
    assert "cannot interpret the drawing (KeyError" in _error(path)


# -- performance and the neighbour search -------------------------------------------------------------
def _fast_r12(path: Path, xy_mm: np.ndarray, d_mm: float = 19.0) -> None:
    """A minimal R12 file written as text (ezdxf would take seconds to write 50 000 circles)."""
    parts = ["  0\nSECTION\n  2\nENTITIES\n"]
    parts += [f"  0\nCIRCLE\n  8\nSTUDS\n 10\n{x:.4f}\n 20\n{y:.4f}\n 30\n0.0\n 40\n{d_mm / 2}\n" for x, y in xy_mm]
    for name, (x, y) in {"O": (-50, -50), "A": (30000, -50), "B": (-50, 25000)}.items():
        parts.append(f"  0\nCIRCLE\n  8\nMARKS\n 10\n{x}\n 20\n{y}\n 30\n0.0\n 40\n15.0\n")
        parts.append(f"  0\nTEXT\n  8\nTEXT\n 10\n{x + 20}\n 20\n{y + 20}\n 30\n0.0\n 40\n20.0\n  1\n{name}\n")
    parts.append("  0\nENDSEC\n  0\nEOF\n")
    path.write_text("".join(parts))


def test_50000_studs_parse_in_seconds(tmp_path):
    g = np.stack(np.meshgrid(np.arange(250), np.arange(200)), -1).reshape(-1, 2) * 100.0 + 50.0
    _fast_r12(tmp_path / "big.dxf", g)  # no HEADER: unitless, read as mm
    t0 = time.perf_counter()
    layout = read_layout(tmp_path / "big.dxf")
    elapsed = time.perf_counter() - t0
    print(f"\n50 000 studs parsed in {elapsed:.2f} s")
    assert len(layout.studs) == 50_000 and layout.studs[-1].id == "S50000"
    assert layout.units_assumed and layout.source_units == "mm"  # not ezdxf's default $INSUNITS 6
    assert layout.studs[1].x_m == pytest.approx(0.2) and layout.studs[250].y_m == pytest.approx(0.2)
    assert elapsed < 20.0  # ~3 s on a laptop, mostly ezdxf loading; generous for shared CI


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 200), radius=st.floats(0.01, 0.5), seed=st.integers(0, 2**16))
def test_close_pairs_matches_brute_force(n, radius, seed):
    xy = np.random.default_rng(seed).uniform(-1, 1, (n, 2))
    i, j, d = close_pairs(xy, radius)
    got = sorted(zip(i.tolist(), j.tolist()))
    dist = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1)) if n else np.zeros((0, 0))
    want = [(a, b) for a in range(n) for b in range(a + 1, n) if dist[a, b] < radius]
    assert got == want
    np.testing.assert_allclose(d[np.lexsort((j, i))], [dist[a, b] for a, b in want])


def test_layout_dict_round_trip_is_json(tmp_path):
    layout = read_layout(write_layout_dxf(tmp_path / "j.dxf", STUDS, MARKS, LayoutDxfOptions(rotation_deg=12)))
    d = json.loads(json.dumps(layout.to_dict()))
    assert d["frame_id"] == "drawing" and d["studs"][0]["id"] == "S0001"
    again = DrawingLayout.from_dict(d)
    assert again.studs == layout.studs and again.marks == layout.marks
    assert again.wcs_to_drawing == layout.wcs_to_drawing and again.warnings == layout.warnings


def test_demo_script_writes_a_small_drawing_that_parses(tmp_path):
    spec = importlib.util.spec_from_file_location("make_demo_drawings", REPO / "tools" / "make_demo_drawings.py")
    demo = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(demo)
    assert demo.main(["--out", str(tmp_path)]) == 0
    path = tmp_path / "flat_plate_demo.dxf"
    assert path.stat().st_size < 50_000
    layout = read_layout(path)
    assert layout.warnings == [] and layout.marks_rule == "labels"
    assert_studs(layout, demo.FLAT_PLATE_STUDS)
    committed = REPO / "src" / "stud_planner" / "data" / "flat_plate_demo.dxf"
    if committed.exists():
        assert read_layout(committed).studs == layout.studs


# -- the real corpus ---------------------------------------------------------------------------------
def _corpus_table() -> dict[str, dict]:
    """README rows: file -> {version, mode, units, direct, expanded, inserts}."""
    rows = {}
    readme = CORPUS / "README.md"
    if not readme.exists():
        return rows
    for line in readme.read_text(encoding="utf-8").splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 4 or not cells[0].lower().endswith(".dxf"):
            continue
        fields = cells[3].split("/")
        entry = {"mode": fields[1].split()[0]}
        if len(fields) >= 6:
            entry.update(version=fields[0], units=fields[2], direct=int(fields[3]), expanded=int(fields[4]),
                         inserts=int(fields[5]))
        rows[cells[0]] = entry
    return rows


CORPUS_ROWS = _corpus_table()


@pytest.fixture()
def dxf_corpus(prerequisite):
    """The shared DXF corpus and its README table (skips, or fails under CI=true, without them)."""
    prerequisite(bool(CORPUS_ROWS), f"DXF corpus not found at {CORPUS} (its README.md lists the files)")


corpus = pytest.mark.usefixtures("dxf_corpus")


@corpus
@pytest.mark.parametrize("name", sorted(CORPUS_ROWS) or ["<none>"])
def test_corpus_file_parses_or_fails_with_a_clear_message(name):
    row = CORPUS_ROWS[name]
    path = CORPUS / name
    with pytest.raises(DrawingError) as info:
        read_layout(path)  # none of them is a stud layout
    message = str(info.value)
    assert "\n" not in message and str(path) in message
    if row["mode"] == "unreadable":
        assert "not a DXF" in message or "truncated or corrupt" in message
        with pytest.raises(DrawingError):
            read_circles(path)
        return
    assert re.search(r"no studs found: no circles on layer\(s\) STUDS(; skipped while reading: [^;]+)?; layers: ",
                     message), message
    circles = read_circles(path, include_hidden_layers=True)
    assert circles.dxf_version == row["version"]
    assert circles.read_mode == row["mode"]
    # ezdxf counts CIRCLE entities with radius <= 0 too; we skip (and report) them
    assert len(circles) + circles.skipped["radius<=0"] == row["expanded"], circles.warnings
    # by default what CAD hides is skipped, and said
    shown = read_circles(path)
    hidden = shown.skipped["frozen or off layer"] + shown.skipped["invisible"]
    assert len(shown) + hidden == len(circles)
    assert (hidden > 0) == any("frozen or off layers skipped" in w or "invisible" in w for w in shown.warnings)
    circles = shown
    if row["units"] in ("–", "-", "0") or b"$INSUNITS" not in path.read_bytes():
        # header-less files: ezdxf reports its default $INSUNITS 6 (m); the file says nothing, so unitless
        assert circles.units_assumed
    else:
        assert circles.insunits == int(row["units"]) and not circles.units_assumed
    if row["mode"] == "recover":
        assert any("ezdxf.recover" in w for w in circles.warnings)


@corpus
def test_corpus_degenerate_insert_is_skipped_and_the_rest_kept():
    circles = read_circles(CORPUS / "netdxf_sample_2004.dxf")
    assert len(circles) == 4
    assert any("'*T12'" in w and "skipped" in w for w in circles.warnings)


@corpus
def test_corpus_real_drawing_as_a_layout_with_globbed_layers():
    # Prusa's frame plate: M3 holes as "studs", the four marks on layers znaceniA/B (ambiguous: 4 circles)
    path = CORPUS / "prusa_MK3v8b.dxf"
    message = _error(path, stud_layers=["m3"], mark_layer=["znaceni*"], include_hidden_layers=True)
    assert "found 4 mark circles on layer znaceni*" in message
    # ... and both znaceni layers are frozen: by default they are not read at all, and the error says so
    message = _error(path, stud_layers=["m3"], mark_layer=["znaceni*"])
    assert "marks missing: found 0 mark circles" in message and "4 circles (frozen or off layer)" in message
