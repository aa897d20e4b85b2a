"""The QA record of a weld job: every stud's inspection as JSON, CSV and a one-page HTML report.

Written by the cell at the end of a job -- also one stopped early -- into its output folder:
``qa_report.json`` (strict JSON), ``qa_report.csv`` (the same rows) and ``qa_report.html`` (one
self-contained page a fabricator hands to an inspector: the job, part, drawing and date, the limits,
the counts, the table, and each station's inspection overlay, embedded).

Rows, one per drawing stud in drawing order: ``stud_id``, ``drawing_xy_mm``, ``verdict`` (``pass``,
``fail``, ``missing``, ``not_inspected``, ``not_welded``), ``reasons`` (short strings), ``planned``
(``position_m``, ``normal``) and ``measured`` (``position_m``, ``axis``, ``lean_deg``, ``offset_mm``,
``height_mm``; null when not measured); plus ``station``, ``rework`` (the operator's latest decision,
``rework`` or ``accept``, null until one is recorded) and ``rework_note``. Decisions taken after the
job re-write the record (:func:`apply_rework`, called by the inspector node). No ROS here: rows come
as plain dicts.
"""
from __future__ import annotations

import base64
import contextlib
import csv
import datetime as _dt
import fcntl
import html
import io
import json
import os
from collections.abc import Iterator, Mapping
from pathlib import Path

from stud_common.strict_json import json_safe, write_json, write_text_atomic

JSON_NAME = "qa_report.json"

VERDICTS = ("pass", "fail", "missing", "not_inspected", "not_welded")
CSV_FIELDS = ["stud_id", "x_mm", "y_mm", "verdict", "reasons", "station", "planned_x_m", "planned_y_m", "planned_z_m",
              "measured_x_m", "measured_y_m", "measured_z_m", "lean_deg", "offset_x_mm", "offset_y_mm", "height_mm",
              "rework", "rework_note"]


def empty_row(stud_id: str, drawing_xy_mm) -> dict:
    """A drawing stud nothing has been done to yet: not welded."""
    return {"stud_id": stud_id, "drawing_xy_mm": [float(v) for v in drawing_xy_mm], "verdict": "not_welded",
            "reasons": [], "planned": None, "measured": None, "station": None, "rework": None, "rework_note": None}


def summary_of(rows: list[dict]) -> dict:
    counts = {v: 0 for v in VERDICTS}
    for r in rows:
        counts[r["verdict"]] += 1
    return counts


def document(job: dict, limits: dict, rows: list[dict], unexpected: list[dict]) -> dict:
    """The qa_report.json document: ``job`` (id, part, drawing, date, state), ``limits``, ``summary``
    (counts per verdict), ``studs`` (the rows) and ``unexpected_objects``."""
    return {"job": job, "limits": limits, "summary": summary_of(rows), "studs": rows,
            "unexpected_objects": unexpected}


def with_rework(rows: list[dict], decisions: Mapping[str, Mapping]) -> list[dict]:
    """``rows`` with each decided stud's ``rework`` (the decision) and ``rework_note`` filled in;
    ``decisions``: stud id -> {"decision", "note", ...} (rework.ReworkRecord.for_qa_record)."""
    out = []
    for row in rows:
        d = decisions.get(row["stud_id"])
        out.append({**row, "rework": d["decision"], "rework_note": d.get("note") or None} if d else row)
    return out


def _csv_row(r: dict) -> list:
    p = (r.get("planned") or {}).get("position_m") or [None] * 3
    m = r.get("measured") or {}
    mp = m.get("position_m") or [None] * 3
    off = m.get("offset_mm") or [None, None]
    return [r["stud_id"], *r["drawing_xy_mm"], r["verdict"], "; ".join(r["reasons"]), r.get("station"), *p, *mp,
            m.get("lean_deg"), *off, m.get("height_mm"), r.get("rework") or "", r.get("rework_note") or ""]


def _fmt(x, digits: int = 1) -> str:
    return "" if x is None else f"{x:.{digits}f}"


def _html(doc: dict, overlays: list[Path]) -> str:
    job, lim, counts = doc["job"], doc["limits"], doc["summary"]
    e = html.escape
    rows = []
    for r in doc["studs"]:
        m = r.get("measured") or {}
        off = m.get("offset_mm")
        rows.append(f"<tr class='{e(r['verdict'])}'><td>{e(r['stud_id'])}</td><td>{e(r['verdict'].replace('_', ' '))}"
                    f"</td><td>{_fmt(m.get('lean_deg'))}</td><td>{_fmt((off[0] ** 2 + off[1] ** 2) ** 0.5) if off else ''}"
                    f"</td><td>{_fmt(m.get('height_mm'))}</td><td>{e('; '.join(r['reasons']))}</td>"
                    f"<td>{'' if r.get('station') is None else r['station']}</td>"
                    f"<td>{e(r.get('rework') or '')}{e(': ' + r['rework_note']) if r.get('rework_note') else ''}</td></tr>")
    images = []
    for path in overlays:
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        images.append(f"<figure><img alt='{e(path.name)}' src='data:image/png;base64,{data}'>"
                      f"<figcaption>{e(path.name)}</figcaption></figure>")
    unexpected = "".join(f"<li>at ({o['position_m'][0]:.3f}, {o['position_m'][1]:.3f}, {o['position_m'][2]:.3f}) m, "
                         f"{o['height_mm']:.0f} mm high</li>" for o in doc["unexpected_objects"]) or "<li>none</li>"
    return f"""<!doctype html><html><head><meta charset='utf-8'><title>Stud weld QA record {e(str(job.get('id', '')))}</title>
<style>body{{font-family:sans-serif;margin:1.5em;max-width:1100px}}table{{border-collapse:collapse;width:100%}}
td,th{{border:1px solid #bbb;padding:2px 6px;text-align:left}}tr.pass td:nth-child(2){{color:#187a18}}
tr.fail td:nth-child(2),tr.missing td:nth-child(2){{color:#b00;font-weight:bold}}tr.not_inspected td:nth-child(2){{color:#a66b00}}
figure{{display:inline-block;margin:.5em}}img{{max-width:520px}}</style></head><body>
<h1>Stud weld QA record</h1>
<p>Job <b>{e(str(job.get('id', '')))}</b>, part <b>{e(str(job.get('part', '')))}</b>, drawing <code>{e(str(job.get('drawing', '')))}</code>,
{e(str(job.get('date', '')))}; job {e(str(job.get('state', '')))}.</p>
<p>Limits: lean &le; {lim['max_lean_deg']:g}&deg; from the surface normal; base within {lim['position_tol_mm']:g} mm of the
planned point; standing height {lim['nominal_length_mm']:g} &plusmn; {lim['height_tol_mm']:g} mm; stud diameter {lim['stud_diameter_mm']:g} mm.
Measured in 3D by the cell's camera after the welds.</p>
<p>{' &middot; '.join(f"{e(k.replace('_', ' '))}: <b>{v}</b>" for k, v in counts.items())}</p>
<table><tr><th>stud</th><th>verdict</th><th>lean [deg]</th><th>offset [mm]</th><th>height [mm]</th><th>reasons</th>
<th>station</th><th>rework</th></tr>{''.join(rows)}</table>
<h2>Unexpected objects</h2><ul>{unexpected}</ul>
<h2>Inspection views</h2>{''.join(images) or '<p>none</p>'}
</body></html>
"""


@contextlib.contextmanager
def locked(out_dir: Path) -> Iterator[None]:
    """Hold the QA record of ``out_dir`` for one read-modify-write: the cell (writing it at the end
    of the job) and the inspector (adding an operator's decision) never interleave."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".qa_report.lock", "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _write_files(out_dir: Path, doc: dict) -> None:
    write_json(out_dir / JSON_NAME, doc)
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(CSV_FIELDS)
    for r in doc["studs"]:
        w.writerow(_csv_row(r))
    write_text_atomic(out_dir / "qa_report.csv", text.getvalue())
    overlays = [p if p.is_absolute() else out_dir / p for p in map(Path, doc.get("overlays", []))]
    write_text_atomic(out_dir / "qa_report.html", _html(doc, [p for p in overlays if p.exists()]))


def write_qa_report(out_dir: Path, job: dict, limits: dict, rows: list[dict], unexpected: list[dict],
                    overlays: list[Path], decisions: Mapping[str, Mapping] | None = None) -> dict:
    """Write qa_report.json, .csv and .html into ``out_dir`` (each replaced whole); returns the JSON
    document. ``decisions``: the operator's rework decisions so far (:func:`with_rework`). The
    document lists the ``overlays`` (relative to ``out_dir`` where inside it) for later re-writes."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    job = {"date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"), **job}
    doc = json_safe(document(job, limits, with_rework(rows, decisions or {}), unexpected))  # NaN -> null
    doc["overlays"] = [os.path.relpath(p, out_dir) if Path(p).resolve().is_relative_to(out_dir.resolve()) else str(p)
                       for p in overlays]
    _write_files(out_dir, doc)
    return doc


def apply_rework(out_dir: Path, decisions: Mapping[str, Mapping]) -> dict | None:
    """Re-write the QA record in ``out_dir`` with the operator's ``decisions`` in its ``rework``
    column; None when there is no record there (yet: the cell writes it at the end of the job, with
    the decisions taken so far). Raises ValueError naming the file when the record is not ours."""
    out_dir = Path(out_dir)
    path = out_dir / JSON_NAME
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the QA record ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("studs"), list):
        raise ValueError(f"{path}: not a QA record (expected an object with a 'studs' list)")
    doc["studs"] = with_rework(doc["studs"], decisions)
    _write_files(out_dir, doc)
    return doc


__all__ = ["CSV_FIELDS", "VERDICTS", "apply_rework", "document", "empty_row", "locked", "summary_of", "with_rework",
           "write_qa_report"]
