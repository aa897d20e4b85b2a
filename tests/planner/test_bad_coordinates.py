"""Non-finite and absurd coordinates are no stud: left out with a warning naming handle and layer,
by the parser, drawing_inspect and plan, and nothing the project writes carries NaN/Infinity."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import ezdxf
import pytest

from stud_planner.drawing import DrawingError, DrawingLayout, read_circles, read_layout
from stud_planner.drawing import inspect_cli as drawing_inspect

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf"
BAG = REPO / "bags" / "dome_demo"
#: sentinel x coordinates written by ezdxf, then replaced by what a broken export writes
BAD = {"777001.5": "nan", "777002.5": "inf", "777003.5": "-1e300", "777004.5": "NaN"}


def strict_loads(text: str):
    def refuse(token):
        raise AssertionError(f"not RFC 8259 JSON: {token}")
    return json.loads(text, parse_constant=refuse)


def demo_with_bad_studs(tmp_path: Path, radius_inf: bool = True) -> tuple[Path, dict[str, str]]:
    """The demo drawing plus four stud circles at NaN / inf / -1e300 / NaN x, one of radius inf,
    and one INSERT placing a stud block at 1e300: ``(path, {handle: what})``."""
    doc = ezdxf.readfile(DEMO)
    msp = doc.modelspace()
    handles = {}
    for sentinel, value in BAD.items():
        handles[msp.add_circle((float(sentinel), 10.0, 0.0), 8.0, dxfattribs={"layer": "STUDS"}).dxf.handle] = value
    if radius_inf:
        handles[msp.add_circle((50.0, 60.0, 0.0), 7770.5, dxfattribs={"layer": "STUDS"}).dxf.handle] = "radius inf"
    block = doc.blocks.new("BADSTUD")
    block.add_circle((0.0, 0.0), 8.0, dxfattribs={"layer": "0"})
    handles[msp.add_blockref("BADSTUD", (777005.5, 0.0), dxfattribs={"layer": "STUDS"}).dxf.handle] = "insert 1e300"
    path = tmp_path / "bad.dxf"
    doc.saveas(path)
    text = path.read_text()
    for sentinel, value in {**BAD, "7770.5": "inf", "777005.5": "1e300"}.items():
        assert f"\n{sentinel}\n" in text
        text = text.replace(f"\n{sentinel}\n", f"\n{value}\n")
    path.write_text(text)
    return path, handles


@pytest.mark.parametrize("plain_circles", [True, False])
def test_non_finite_and_absurd_circles_are_left_out_and_named(tmp_path, plain_circles):
    path, handles = demo_with_bad_studs(tmp_path)
    circles = read_circles(path, plain_circles=plain_circles)
    assert circles.skipped["non-finite or out of range"] == len(handles) == 6
    for handle in handles:
        assert any(f"handle {handle} on layer STUDS" in line for line in circles.invalid_entities), handle
    layout = read_layout(path)
    good = read_layout(DEMO)
    assert layout.studs == good.studs  # the real studs, same ids
    assert len(layout.invalid_entities) == 6 and all("STUDS" in line for line in layout.invalid_entities)
    warning = next(w for w in layout.warnings if "left out" in w)
    assert "6 circles with non-finite or out-of-range values" in warning and "nan" in warning
    assert "\n" not in warning


def test_both_readers_give_the_same_invalid_entities(tmp_path):
    path, _ = demo_with_bad_studs(tmp_path)
    a, b = read_circles(path, plain_circles=True), read_circles(path, plain_circles=False)
    assert a.invalid_entities == b.invalid_entities and a.warnings == b.warnings and a.skipped == b.skipped


def test_a_mark_at_nan_is_a_missing_mark_and_the_error_says_why(tmp_path):
    text = DEMO.read_text()
    doc = ezdxf.readfile(DEMO)
    o = next(e for e in doc.modelspace().query("CIRCLE[layer=='MARKS']"))
    x = f"{o.dxf.center.x:g}"
    entity = text.index(f"\n  5\n{o.dxf.handle}\n")
    at = text.index("\n 10\n", entity) + len("\n 10\n")
    end = text.index("\n", at)
    assert float(text[at:end]) == float(x)
    (tmp_path / "nan_mark.dxf").write_text(text[:at] + "nan" + text[end:])
    with pytest.raises(DrawingError) as exc:
        read_layout(tmp_path / "nan_mark.dxf")
    message = str(exc.value)
    assert "marks missing" in message and "1 circle (non-finite or out of range)" in message


def test_drawing_inspect_reports_finite_extents_and_strict_json(tmp_path, capsys):
    path, handles = demo_with_bad_studs(tmp_path)
    out = tmp_path / "layout.json"
    assert drawing_inspect.main([str(path), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    extent = next(line for line in printed.splitlines() if line.startswith("stud extent:"))
    assert "nan" not in extent.lower() and "inf" not in extent.lower()
    assert "left out" in printed
    data = strict_loads(out.read_text())
    assert len(data["studs"]) == len(read_layout(DEMO).studs) and len(data["invalid_entities"]) == len(handles)
    assert DrawingLayout.from_dict(data).invalid_entities == tuple(data["invalid_entities"])


def test_plan_warns_about_left_out_circles_and_writes_strict_json(tmp_path):
    path, handles = demo_with_bad_studs(tmp_path)
    report = tmp_path / "report.json"
    done = subprocess.run([sys.executable, "-c", "import sys; from stud_planner.offline_plan import main; "
                           "sys.exit(main(sys.argv[1:]))", "--drawing", str(path), "--bag", str(BAG),
                           "--out", str(report), "--quiet"], capture_output=True, text=True, timeout=300,
                          env={**__import__("os").environ, "PYTHONPATH": ":".join(sys.path)})
    assert done.returncode == 0, done.stderr
    assert "Traceback" not in done.stderr
    lines = [ln for ln in done.stderr.splitlines() if "left out" in ln]
    assert len(lines) == 1 and lines[0].startswith("plan: warning: ") and "6 circles" in lines[0]
    text = report.read_text()
    assert "NaN" not in text and "Infinity" not in text
    data = strict_loads(text)
    assert len(data["targets"]) == len(read_layout(DEMO).studs)  # one per drawing stud; the broken circles are none
    assert any("left out" in w for w in data["warnings"])
    # a target without a value says null (missing), never NaN
    assert all(v is None or isinstance(v, (int, float)) for t in data["targets"] for v in t.get("position_m") or [])
