"""The drawing's work budget (stud_planner.drawing.limits): a DXF that asks for unbounded block
expansion -- ten nested levels of ten INSERTs (10^10 circles in a few KB), a MINSERT of 10^6 x 10^6
cells -- ends in seconds with exit code 2 and one line naming the block, its level and the count,
in bounded memory, for ``drawing_inspect`` and ``plan``; the limits count exactly and can be raised.

The bombs are built here with ezdxf. The CLIs run as real subprocesses, each measured on its own
(``os.wait4``: that child's peak RSS and CPU time, whatever other children the test process had).
The time asserted is the child's CPU time (user + system): the 2-core CI machine is shared, and its
wall clock says more about the neighbours than about the reader. Each child also runs under a 4 GB
address-space limit, so a regression fails the test with a MemoryError instead of taking the
machine's memory (the unbudgeted reader took 23 GB and 80 s on the INSERT bomb before being killed).
"""
from __future__ import annotations

import os
import resource
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import ezdxf
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stud_planner.drawing import DrawingError, DrawingLimitError, DrawingLimits, read_circles, read_layout

REPO = Path(__file__).resolve().parents[2]
BAG = REPO / "bags" / "dome_demo"
MARKS = {"O": (0.0, 0.0), "A": (400.0, 0.0), "B": (0.0, 300.0)}  # mm

ADDRESS_SPACE_LIMIT = 4 << 30
MAX_RSS_MB = 500.0
MAX_CPU_S = 10.0


# -- drawings ------------------------------------------------------------------------------------
def _new_doc():
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = 4  # mm
    doc.layers.add("STUDS")
    doc.layers.add("MARKS")
    msp = doc.modelspace()
    for name, xy in MARKS.items():
        msp.add_circle(xy, 15.0, dxfattribs={"layer": "MARKS"})
        msp.add_text(name, dxfattribs={"layer": "MARKS", "insert": (xy[0] + 20.0, xy[1] + 20.0), "height": 10.0})
    return doc, msp


def insert_bomb(path: Path, levels: int = 10, fan_out: int = 10, top: int = 1) -> Path:
    """Block L1 holds one stud circle; block Lk inserts L(k-1) ``fan_out`` times; modelspace inserts
    L``levels`` ``top`` times: ``top * fan_out ** (levels - 1)`` circles."""
    doc, msp = _new_doc()
    prev = None
    for level in range(1, levels + 1):
        block = doc.blocks.new(f"L{level}")
        if prev is None:
            block.add_circle((0.0, 0.0), 8.0, dxfattribs={"layer": "STUDS"})
        else:
            for i in range(fan_out):  # spread so that the studs stay apart at every level
                block.add_blockref(prev, (40.0 * fan_out ** (level - 2) * i, 0.0) if level % 2 else
                                   (0.0, 40.0 * fan_out ** (level - 2) * i))
        prev = f"L{level}"
    for i in range(top):
        msp.add_blockref(prev, (50.0, 50.0 + 1e6 * i))
    doc.saveas(path)
    return path


def minsert_bomb(path: Path, rows: int = 10 ** 6, cols: int = 10 ** 6) -> Path:
    doc, msp = _new_doc()
    doc.blocks.new("STUD").add_circle((0.0, 0.0), 8.0, dxfattribs={"layer": "STUDS"})
    msp.add_blockref("STUD", (50.0, 50.0)).grid(size=(rows, cols), spacing=(40.0, 40.0))
    doc.saveas(path)
    return path


# -- the CLIs as measured subprocesses --------------------------------------------------------------
@dataclass
class Run:
    returncode: int
    stdout: str
    stderr: str
    wall_s: float
    cpu_s: float
    max_rss_mb: float


def _limit_address_space() -> None:  # in the child, before exec
    resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE_LIMIT, ADDRESS_SPACE_LIMIT))


def run_measured(cmd: list[str], tmp_path: Path, timeout_s: float = 120.0) -> Run:
    """Run ``cmd``; its exit code, output, wall and CPU time and peak RSS (its own and its children's,
    from ``wait4``). Killed after ``timeout_s`` (a hang fails the test, never the suite)."""
    out, err = tmp_path / "stdout.txt", tmp_path / "stderr.txt"
    with open(out, "w") as fo, open(err, "w") as fe:
        t0 = time.monotonic()
        proc = subprocess.Popen(cmd, stdout=fo, stderr=fe, preexec_fn=_limit_address_space, start_new_session=True)
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() - t0 > timeout_s:
                os.killpg(proc.pid, 9)
                _, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.02)
        wall = time.monotonic() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
    return Run(proc.returncode, out.read_text(), err.read_text(), wall, usage.ru_utime + usage.ru_stime,
               usage.ru_maxrss / 1024.0)


def drawing_inspect(path: Path, *args: str) -> list[str]:
    return ["ros2", "run", "stud_planner", "drawing_inspect", str(path), *args]


def plan(path: Path, *args: str) -> list[str]:
    return ["ros2", "run", "stud_planner", "plan", "--drawing", str(path), "--bag", str(BAG), "--quiet", *args]


def assert_bounded_refusal(run: Run, prog: str, *parts: str) -> str:
    """Exit code 2, one line ``<prog>: error: ...`` holding ``parts``, in bounded time and memory."""
    lines = run.stderr.splitlines()
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), run.stderr[-2000:]
    for part in parts:
        assert part in lines[0], lines[0]
    assert run.cpu_s < MAX_CPU_S, f"{run.cpu_s:.1f} s of CPU"
    assert run.max_rss_mb < MAX_RSS_MB, f"peak RSS {run.max_rss_mb:.0f} MB"
    print(f"{prog}: {run.wall_s:.2f} s wall, {run.cpu_s:.2f} s CPU, peak RSS {run.max_rss_mb:.0f} MB")
    return lines[0]


# -- the bombs -------------------------------------------------------------------------------------
@pytest.mark.parametrize("cli,prog", [(drawing_inspect, "drawing_inspect"), (plan, "plan")])
def test_a_ten_level_insert_bomb_stops_at_the_expansion_limit_naming_block_level_and_count(tmp_path, cli, prog):
    bomb = insert_bomb(tmp_path / "bomb.dxf", top=10)  # the issue's: ten levels of ten, 10^10 circles
    assert bomb.stat().st_size < 64_000
    line = assert_bounded_refusal(run_measured(cli(bomb), tmp_path), prog)
    # L10 is level 1 in modelspace ... L7 (10^6 circles, placed 10 times in L8) is level 4
    assert ("block 'L7' (nesting level 4) placed 10 times in block 'L8' would expand 10,000,000 entities "
            "(10 x 1,000,000; 1,111,110 expanded before), beyond the limit max_expanded_entities = 2,000,000") in line
    assert "--max-expanded-entities" in line  # how a genuine drawing gets through


@pytest.mark.parametrize("cli,prog", [(drawing_inspect, "drawing_inspect"), (plan, "plan")])
def test_a_minsert_of_a_million_by_a_million_cells_is_refused_before_a_cell_is_made(tmp_path, cli, prog):
    bomb = minsert_bomb(tmp_path / "minsert.dxf")
    line = assert_bounded_refusal(run_measured(cli(bomb), tmp_path), prog)
    assert ("MINSERT (handle " in line and "of block 'STUD' in modelspace has 1,000,000 x 1,000,000 = "
            "1,000,000,000,000 cells (0 in MINSERTs before), beyond the limit max_minsert_cells = 1,000,000") in line
    assert "--max-minsert-cells" in line


def test_raising_the_limit_on_the_command_line_reads_the_drawing(tmp_path):
    bomb = insert_bomb(tmp_path / "small_bomb.dxf", levels=4)  # 1,000 studs
    # L2: 10, L3: 100, L4: 1,000, and L4 placed once in modelspace: 1,000 more
    refused = run_measured(drawing_inspect(bomb, "--max-expanded-entities", "2109"), tmp_path)
    assert refused.returncode == 2 and "would expand 1,000 entities (1 x 1,000; 1,110 expanded before)" \
        in refused.stderr, refused.stderr
    read = run_measured(drawing_inspect(bomb, "--max-expanded-entities", "2110"), tmp_path)
    assert read.returncode == 0, read.stderr
    assert "stud layers:  STUDS (1000)" in read.stdout
    bad = run_measured(drawing_inspect(bomb, "--max-expanded-entities", "0"), tmp_path)
    assert bad.returncode == 2 and "max_expanded_entities=0: expected an integer >= 1" in bad.stderr


# -- the limits, in process -------------------------------------------------------------------------
@pytest.mark.parametrize("levels,fan_out", [(3, 7), (4, 5), (5, 3)])
def test_the_expansion_count_is_exact_a_drawing_reads_at_its_count_and_is_refused_one_below(tmp_path, levels, fan_out):
    path = insert_bomb(tmp_path / "nested.dxf", levels=levels, fan_out=fan_out)
    # every level's placements are counted: fan_out^1 + ... + fan_out^(levels-1) to build the blocks,
    # and the top block's fan_out^(levels-1) once more, placed in modelspace
    needed = sum(fan_out ** k for k in range(1, levels)) + fan_out ** (levels - 1)
    layout = read_layout(path, limits=DrawingLimits(max_expanded_entities=needed))
    assert len(layout.studs) == fan_out ** (levels - 1)
    with pytest.raises(DrawingLimitError) as refused:
        read_layout(path, limits=DrawingLimits(max_expanded_entities=needed - 1))
    assert refused.value.limit == "max_expanded_entities" and refused.value.count == needed
    assert f"block 'L{levels}' (nesting level 1) placed 1 time in modelspace" in str(refused.value)


def test_block_nesting_deeper_than_the_limit_is_refused_naming_the_chain(tmp_path):
    path = insert_bomb(tmp_path / "deep.dxf", levels=40, fan_out=1)
    with pytest.raises(DrawingLimitError, match=r"block 'L8' is nested 33 levels deep \(modelspace > L40 > L39 > "
                       r"L38 > \.\.\. > L9 > L8\), beyond the limit max_block_depth = 32"):
        read_layout(path)
    assert len(read_layout(path, limits=DrawingLimits(max_block_depth=40)).studs) == 1


def test_a_block_that_inserts_itself_is_still_skipped_with_a_warning_not_refused(tmp_path):
    doc, msp = _new_doc()
    block = doc.blocks.new("LOOP")
    block.add_circle((0.0, 0.0), 8.0, dxfattribs={"layer": "STUDS"})
    block.add_blockref("LOOP", (40.0, 0.0))
    msp.add_blockref("LOOP", (50.0, 50.0))
    doc.saveas(tmp_path / "loop.dxf")
    layout = read_layout(tmp_path / "loop.dxf")
    assert len(layout.studs) == 1 and any("recursive block reference" in w for w in layout.warnings)


def test_minsert_cells_are_counted_over_all_minserts_of_the_drawing(tmp_path):
    doc, msp = _new_doc()
    doc.blocks.new("STUD").add_circle((0.0, 0.0), 8.0, dxfattribs={"layer": "STUDS"})
    msp.add_blockref("STUD", (50.0, 50.0)).grid(size=(3, 4), spacing=(40.0, 40.0))
    msp.add_blockref("STUD", (50.0, 200.0)).grid(size=(2, 5), spacing=(40.0, 40.0))
    doc.saveas(tmp_path / "grids.dxf")
    assert len(read_layout(tmp_path / "grids.dxf", limits=DrawingLimits(max_minsert_cells=22)).studs) == 22
    with pytest.raises(DrawingLimitError, match=r"2 x 5 = 10 cells \(12 in MINSERTs before\), beyond the limit "
                                                r"max_minsert_cells = 21"):
        read_layout(tmp_path / "grids.dxf", limits=DrawingLimits(max_minsert_cells=21))


def test_a_minsert_with_zero_spacing_is_one_cell_however_many_rows_it_claims(tmp_path):
    doc, msp = _new_doc()
    doc.blocks.new("STUD").add_circle((0.0, 0.0), 8.0, dxfattribs={"layer": "STUDS"})
    msp.add_blockref("STUD", (50.0, 50.0)).grid(size=(10 ** 9, 10 ** 9), spacing=(0.0, 0.0))
    doc.saveas(tmp_path / "stacked.dxf")
    assert len(read_layout(tmp_path / "stacked.dxf").studs) == 1  # as ezdxf: each location once


def test_text_beyond_the_limit_is_refused_naming_the_entity_and_its_block(tmp_path):
    doc, msp = _new_doc()
    doc.blocks.new("STUD").add_circle((0.0, 0.0), 8.0, dxfattribs={"layer": "STUDS"})
    msp.add_blockref("STUD", (50.0, 50.0))
    note = doc.blocks.new("NOTE")
    note.add_mtext("General notes. " * 400)  # 6,000 characters: a long real note
    msp.add_blockref("NOTE", (0.0, -100.0))
    doc.saveas(tmp_path / "note.dxf")
    assert len(read_layout(tmp_path / "note.dxf").studs) == 1  # the default reads it
    with pytest.raises(DrawingLimitError, match=r"MTEXT \(handle \w+\) in block 'NOTE' \(nesting level 1\) has "
                                                r"6,000 characters, beyond the limit max_text_chars = 5,999"):
        read_layout(tmp_path / "note.dxf", limits=DrawingLimits(max_text_chars=5999))


def test_limits_refuse_nonsense_values():
    for bad in (0, -1, 1.5, True, "10"):
        with pytest.raises(ValueError, match="expected an integer >= 1"):
            DrawingLimits(max_block_depth=bad)  # type: ignore[arg-type]
    assert DrawingLimits().with_changes(max_text_chars=7).max_text_chars == 7
    assert issubclass(DrawingLimitError, DrawingError)  # every front end's error path takes it


# -- MINSERT as arrays: the cells of ezdxf's own multi_insert --------------------------------------
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(rows=st.integers(-1, 4), cols=st.integers(-1, 4), dx=st.sampled_from([0.0, 35.0, -20.0]),
       dy=st.sampled_from([0.0, 50.0]), rotation=st.floats(-360, 360, allow_nan=False),
       scale=st.sampled_from([(1.0, 1.0), (2.0, 2.0), (-1.5, 1.5)]), flip=st.booleans())
def test_minsert_cells_are_where_ezdxf_puts_them(tmp_path, rows, cols, dx, dy, rotation, scale, flip):
    doc, msp = _new_doc()
    block = doc.blocks.new("STUD", base_point=(3.0, -2.0))
    block.add_circle((5.0, 1.0), 8.0, dxfattribs={"layer": "STUDS"})
    ref = msp.add_blockref("STUD", (60.0, 70.0), dxfattribs={"rotation": rotation, "xscale": scale[0],
                                                           "yscale": scale[1], "layer": "STUDS"})
    ref.dxf.row_count, ref.dxf.column_count, ref.dxf.row_spacing, ref.dxf.column_spacing = rows, cols, dy, dx
    if flip:
        ref.dxf.extrusion = (0.0, 0.0, -1.0)
    doc.saveas(tmp_path / "grid.dxf")
    got = read_circles(tmp_path / "grid.dxf", plain_circles=False)
    on_studs = np.array([c for c, lay in zip(got.centers_wcs, got.layers) if lay == "STUDS"]).reshape(-1, 2)
    # ezdxf's own cells, only when it has more than one (else it is a plain INSERT to ezdxf too)
    refs = list(ref.multi_insert()) if ref.mcount > 1 else [ref]
    expected = np.array([tuple(r.matrix44().transform((5.0, 1.0, 0.0)))[:2] for r in refs]).reshape(-1, 2)
    assert on_studs.shape == expected.shape
    np.testing.assert_allclose(on_studs, expected, atol=1e-9 * max(1.0, float(np.abs(expected).max(initial=1.0))))

