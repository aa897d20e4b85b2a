"""stud_planner.drawing.inspect_cli: summary, --json, --png, and one-line errors with exit code 2."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from stud_planner.drawing import inspect_cli as drawing_inspect
from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_layout_dxf
from stud_planner.drawing.inspect_cli import main

REPO = Path(__file__).resolve().parents[2]
CORPUS = REPO.parent / "shared" / "data" / "dxf"
MARKS = {"O": (0.0, 0.0), "A": (0.6, 0.0), "B": (0.0, 0.3)}
STUDS = np.array([(0.05 + 0.1 * i, 0.05 + 0.08 * j) for j in range(3) for i in range(5)])


@pytest.fixture
def plate(tmp_path) -> Path:
    return write_layout_dxf(tmp_path / "plate.dxf", STUDS, MARKS,
                            LayoutDxfOptions(rotation_deg=20.0, origin_wcs_m=(1.0, 2.0)))


def one_error_line(capsys, code: int) -> str:
    assert code == 2
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("drawing_inspect: error: "), err
    assert "Traceback" not in err
    return lines[0]


def test_summary_names_version_units_layers_marks_frame_and_warnings(plate, capsys):
    assert main([str(plate)]) == 0
    out = capsys.readouterr().out
    assert "AC1024 (R2010)" in out
    assert "units:        mm ($INSUNITS 4)" in out
    assert "stud layers:  STUDS (15)" in out
    assert "studs:        15, diameter 19.00 mm" in out and "S0001 .. S0015" in out
    assert "[marks_rule=labels]" in out
    assert "  A  WCS (1563.816, 2205.212) mm  ->  drawing (0.6000, 0.0000) m" in out
    assert "heading 20.00 deg in WCS" in out and "angle AOB 90.000 deg, right-handed" in out
    assert "warnings:     none" in out


def test_geometry_rule_and_warnings_are_reported(tmp_path, capsys):
    studs = np.vstack([STUDS, [[-0.05, 0.1]]])
    path = write_layout_dxf(tmp_path / "g.dxf", studs, MARKS,
                            LayoutDxfOptions(labels=False, units="unitless", unitless_as="cm"))
    assert main([str(path), "--units-if-unitless", "cm"]) == 0
    out = capsys.readouterr().out
    assert "marks_rule=geometry" in out and "right angle at O, B counter-clockwise from A" in out
    assert "units:        cm (assumed: the drawing is unitless)" in out
    assert "warnings:     2" in out and "outside the marks' quadrant" in out and "taken as cm" in out


def test_json_output_is_the_layout(plate, tmp_path, capsys):
    out_json = tmp_path / "out" / "layout.json"
    assert main([str(plate), "--json", str(out_json)]) == 0
    d = json.loads(out_json.read_text())
    assert d["frame_id"] == "drawing" and d["marks_rule"] == "labels" and d["source_units"] == "mm"
    assert [s["id"] for s in d["studs"]] == [f"S{k:04d}" for k in range(1, 16)]
    assert d["studs"][0]["x_m"] == pytest.approx(0.05) and d["studs"][0]["diameter_m"] == pytest.approx(0.019)
    assert d["marks"]["B"]["y_m"] == pytest.approx(0.3)


def test_png_preview_is_written(plate, tmp_path, capsys):
    cv2 = pytest.importorskip("cv2")
    out_png = tmp_path / "preview.png"
    assert main([str(plate), "--png", str(out_png)]) == 0
    img = cv2.imread(str(out_png))
    assert img is not None and img.ndim == 3 and max(img.shape[:2]) >= 1000
    assert (img < 250).any()  # something was drawn
    assert "png:" in capsys.readouterr().out


def test_stud_and_mark_layer_options(tmp_path, capsys):
    path = write_layout_dxf(tmp_path / "l.dxf", STUDS, MARKS,
                            LayoutDxfOptions(stud_layer="Shear-Studs-M19", mark_layer="Datum"))
    assert "no studs found" in one_error_line(capsys, main([str(path)]))
    assert main([str(path), "--stud-layers", "shear-*", "--mark-layer", "DATUM"]) == 0
    assert "stud layers:  Shear-Studs-M19 (15)" in capsys.readouterr().out
    # an option before the file takes one value, not the file name too; repeat it for more
    assert main(["--stud-layers", "nothing", "--stud-layers", "shear-*", "--mark-layer", "datum", str(path)]) == 0
    assert "stud layers:  Shear-Studs-M19 (15)" in capsys.readouterr().out


def test_drawing_errors_are_one_line_with_exit_code_2(tmp_path, capsys):
    line = one_error_line(capsys, main([str(tmp_path / "missing.dxf")]))
    assert "missing.dxf: file not found" in line
    (tmp_path / "text.dxf").write_text("not a drawing\n")
    assert "not a DXF file" in one_error_line(capsys, main([str(tmp_path / "text.dxf")]))


@pytest.mark.parametrize("argv, expected", [
    ([], "the following arguments are required: file"),
    (["x.dxf", "--bogus"], "unrecognized arguments: --bogus"),
    (["x.dxf", "--min-spacing-mm", "lots"], "argument --min-spacing-mm: invalid float value: 'lots'"),
    (["x.dxf", "--units-if-unitless", "furlong"], "argument --units-if-unitless: unknown unit 'furlong'"),
    (["x.dxf", "--png", "out/preview"], "argument --png: out/preview: the preview is a PNG, name it *.png"),
])
def test_usage_errors_are_one_line_with_exit_code_2(capsys, argv, expected):
    assert expected in one_error_line(capsys, main(argv))


def test_help_exits_0(capsys):
    assert main(["--help"]) == 0
    assert "--stud-layers" in capsys.readouterr().out


def test_unexpected_exceptions_are_caught_at_the_boundary(plate, monkeypatch, capsys):
    def boom(*args, **kwargs):
        raise RuntimeError("ezdxf had a bad day\nsecond line")

    monkeypatch.setattr(drawing_inspect, "read_layout", boom)
    line = one_error_line(capsys, main([str(plate)]))
    assert "unexpected RuntimeError: ezdxf had a bad day second line" in line


def test_unwritable_outputs_are_errors(plate, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    line = one_error_line(capsys, main([str(plate), "--json", str(blocker / "sub" / "out.json")]))
    assert "cannot write JSON" in line


@pytest.mark.parametrize("name", ["broken/libredwg_r1.4_entities.dxf", "broken/dxfparser_blocks_fragment.dxf",
                                  "netdxf_sample_2004.dxf"])
def test_corpus_files_fail_cleanly(capsys, name, require_shared_data):
    require_shared_data(CORPUS / name)
    line = one_error_line(capsys, main([str(CORPUS / name)]))
    assert name.split("/")[-1] in line


def _run_module(*args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src" / "stud_planner"), env.get("PYTHONPATH", "")])
    return subprocess.run([sys.executable, "-m", "stud_planner.drawing.inspect_cli", *args], env=env,
                          capture_output=True, text=True, timeout=60)


def test_runs_as_a_module_in_a_subprocess(plate, tmp_path):
    ok = _run_module(str(plate))
    assert ok.returncode == 0, ok.stderr
    assert "stud layers:  STUDS (15)" in ok.stdout
    bad = _run_module(str(tmp_path / "nope.dxf"))
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.splitlines() == [f"drawing_inspect: error: {tmp_path / 'nope.dxf'}: file not found"]
