"""Reference marks in the drawing: circles on the mark layer labelled M1, M2, ... beside O, A, B, read
in label order into DrawingLayout and carried by the StudLayout message."""
from __future__ import annotations

import ezdxf
import numpy as np
import pytest

from stud_planner.drawing import DrawingError, DrawingLayout, read_layout
from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_layout_dxf

BOARD = {"O": (0.0, 0.0), "A": (0.13, 0.0), "B": (0.0, 0.1)}
REFS = {f"M{k}": (0.4 + 0.5 * k, 0.22 if k % 2 else 0.48) for k in range(1, 7)}
STUDS = np.array([(0.3 + 0.2 * i, 0.3 + 0.1 * j) for i in range(25) for j in range(3)])


@pytest.mark.parametrize("kwargs", [
    {},
    {"rotation_deg": 37.0, "origin_wcs_m": (12.0, -3.0), "units": "m"},
    {"label_kind": "mtext", "as_blocks": True},
    {"ocs_flip": True, "dxfversion": "R12"},
], ids=["plain", "rotated_metres", "mtext_blocks", "r12_ocs_flip"])
def test_board_and_six_reference_marks_read_back_in_label_order(tmp_path, kwargs):
    shuffled = {k: REFS[k] for k in ("M4", "M1", "M6", "M2", "M5", "M3")}  # file order is not label order
    path = write_layout_dxf(tmp_path / "girder.dxf", STUDS, {**BOARD, **shuffled},
                            LayoutDxfOptions(mark_diameter_m=0.02, **kwargs))
    layout = read_layout(path)
    assert list(layout.reference_marks_xy_m()) == ["M1", "M2", "M3", "M4", "M5", "M6"]
    for label, (x, y) in layout.reference_marks_xy_m().items():
        assert (x, y) == pytest.approx(REFS[label], abs=1e-9)
    assert layout.marks_xy_m() == pytest.approx(np.array(list(BOARD.values())), abs=1e-9)
    assert len(layout.studs) == len(STUDS)  # no mark became a stud
    assert all(m.diameter_m == pytest.approx(0.02) and m.layer == "MARKS" for m in layout.reference_marks)
    assert layout.marks_rule == "labels" and not [w for w in layout.warnings if "INSUNITS" not in w]
    back = DrawingLayout.from_dict(layout.to_dict())
    assert back.reference_marks == layout.reference_marks


def test_reference_marks_on_a_stud_layer_are_not_studs(tmp_path):
    path = write_layout_dxf(tmp_path / "one_layer.dxf", STUDS, {**BOARD, **REFS},
                            LayoutDxfOptions(stud_layer="PLATE", mark_layer="PLATE", mark_diameter_m=0.02))
    layout = read_layout(path, stud_layers=["PLATE"], mark_layer="PLATE")
    assert len(layout.studs) == len(STUDS) and len(layout.reference_marks) == 6


def _add_text(path, text: str, at_m, layer: str = "TEXT") -> None:
    doc = ezdxf.readfile(path)
    doc.modelspace().add_text(text, height=20.0, dxfattribs={"layer": layer, "insert": (at_m[0] * 1e3, at_m[1] * 1e3)})
    doc.saveas(path)


def _add_circle(path, at_m, r_m: float = 0.01, layer: str = "MARKS") -> None:
    doc = ezdxf.readfile(path)
    doc.modelspace().add_circle((at_m[0] * 1e3, at_m[1] * 1e3), r_m * 1e3, dxfattribs={"layer": layer})
    doc.saveas(path)


def test_an_unlabelled_mark_circle_beside_reference_marks_is_an_error_naming_where(tmp_path):
    path = write_layout_dxf(tmp_path / "g.dxf", STUDS, {**BOARD, **REFS}, LayoutDxfOptions(mark_diameter_m=0.02))
    _add_circle(path, (3.9, 0.22))  # an M7 painted but not labelled
    with pytest.raises(DrawingError, match=r"1 unlabelled circle\(s\) on layer MARKS at \(3900, 220\).*M1, M2"):
        read_layout(path)


def test_a_label_on_two_mark_circles_is_an_error_naming_it(tmp_path):
    refs = dict(REFS)
    path = write_layout_dxf(tmp_path / "g.dxf", STUDS, {**BOARD, **refs}, LayoutDxfOptions(mark_diameter_m=0.02))
    _add_circle(path, (3.9, 0.22))
    _add_text(path, "M2", (3.912, 0.232))  # the new circle labelled M2 as well
    with pytest.raises(DrawingError, match="label 'M2' is nearest to 2 mark circles"):
        read_layout(path)
    # two circles each labelled M3 by its own text
    path = write_layout_dxf(tmp_path / "h.dxf", STUDS, {**BOARD, **refs}, LayoutDxfOptions(mark_diameter_m=0.02))
    _add_circle(path, (3.9, 0.22))
    _add_text(path, "M3", (3.912, 0.232))
    with pytest.raises(DrawingError, match="label 'M3' is nearest to 2 mark circles"):
        read_layout(path)


def test_label_spellings_and_a_thread_size_elsewhere(tmp_path):
    path = write_layout_dxf(tmp_path / "g.dxf", STUDS, {**BOARD, **REFS},
                            LayoutDxfOptions(mark_diameter_m=0.02, labels=True))
    _add_circle(path, (3.9, 0.22))
    _add_text(path, "m07", (3.912, 0.232))  # M07, lower case: M7
    _add_text(path, "M16", (1.0, 1.5), layer="NOTES")  # a thread size far from every mark
    layout = read_layout(path)
    assert list(layout.reference_marks_xy_m())[-1] == "M7"
    assert any("M16 name no mark circle" in w for w in layout.warnings)
    # without reference marks an M-text means nothing and changes nothing
    plain = write_layout_dxf(tmp_path / "plain.dxf", STUDS, BOARD, LayoutDxfOptions(mark_diameter_m=0.02))
    before = read_layout(plain)
    _add_text(plain, "M16", (1.0, 1.5), layer="NOTES")
    after = read_layout(plain)
    assert after.reference_marks == () and after.warnings == before.warnings
    assert after.studs == before.studs


def test_layout_message_carries_the_reference_marks(tmp_path):
    from stud_perception.registration import layout_reference_marks_m
    from stud_planner.msg_convert import layout_from_msg, layout_to_msg

    path = write_layout_dxf(tmp_path / "g.dxf", STUDS, {**BOARD, **REFS}, LayoutDxfOptions(mark_diameter_m=0.02))
    msg = layout_to_msg(read_layout(path))
    assert list(msg.reference_mark_labels) == [f"M{k}" for k in range(1, 7)]
    view = layout_from_msg(msg)
    assert list(view.reference_marks_m) == list(msg.reference_mark_labels)
    for label, xy in layout_reference_marks_m(msg).items():
        assert xy == pytest.approx(REFS[label], abs=1e-9)
        assert view.reference_marks_m[label] == pytest.approx(REFS[label], abs=1e-9)
    plain = layout_to_msg(read_layout(write_layout_dxf(tmp_path / "p.dxf", STUDS, BOARD)))
    assert list(plain.reference_mark_labels) == [] and layout_from_msg(plain).reference_marks_m == {}


def test_inspect_lists_and_draws_the_reference_marks(tmp_path):
    import cv2

    from stud_planner.drawing.inspect_cli import render_preview, summary

    layout = read_layout(write_layout_dxf(tmp_path / "g.dxf", STUDS, {**BOARD, **REFS},
                                          LayoutDxfOptions(mark_diameter_m=0.02)))
    text = summary(layout)
    assert "reference marks: 6 (M1 .. M6)" in text and "  M6  (3.4000, 0.4800) m" in text
    d = layout.to_dict()
    d["reference_marks"] = []
    red = []
    for name, lay in (("with", layout), ("without", DrawingLayout.from_dict(d))):
        render_preview(lay, tmp_path / f"{name}.png", size_px=800)
        img = cv2.imread(str(tmp_path / f"{name}.png"))
        red.append(int(((img[..., 2] > 180) & (img[..., 0] < 60) & (img[..., 1] < 60)).sum()))
    assert red[0] > 2 * red[1] > 0  # six more marks drawn (and named) in red besides O, A, B
