"""The QA record of a weld job: every stud's inspection, the code it was judged by, the bend tests the
inspector must do, and every operator decision -- as JSON, CSV and a printable HTML page.

Written by the cell at the end of a job -- also one stopped early -- into its output folder, and
re-written by the inspector node each time an operator decides on a stud or enters a bend-test
result: ``qa_report.json`` (strict JSON), ``qa_report.csv`` (one row per stud, for a spreadsheet)
and ``qa_report.html`` (self-contained, printable on A4: the job, part, drawing and date, the code
profile and its limits, the counts, a map of the studs, the studs that need attention, the bend-test
list, each station's inspection overlay and a signature block).

Rows, one per drawing stud in drawing order: ``stud_id``, ``drawing_xy_mm``, ``verdict`` (``pass``,
``fail``, ``missing``, ``not_inspected``, ``not_welded``), ``reasons`` (short strings), ``planned``
(``position_m``, ``normal``) and ``measured`` (``position_m``, ``axis``, ``lean_deg``, ``offset_mm``,
``height_mm``, the collar's ``collar_seen_deg``, ``collar_coverage_deg``, ``collar_height_mm``,
``collar_gap_deg``, ``collar_gap_azimuth_deg``; null when not measured); ``station``, ``weld_seq``
(1, 2, ... in the job's weld order); ``rework`` (the operator's latest decision, ``rework`` or
``accept``, null until one is recorded), ``rework_note``, ``rework_operator``, ``rework_time``; and
``bend_test`` (null, or why it must be bent, how far, and the result with who and when).

The document also holds ``code`` (the profile, its limits and sampling rules with their sources,
stud_inspection.qa_codes) and ``sampling`` (the seed of the lot sample and the bend-test list, which
anyone can draw again from the record: stud_inspection.sampling).

Every write replaces each file whole, forced to disk (write a temporary file, fsync, rename, fsync
the folder): a crash or a kill mid-write leaves the previous record, readable. A file lock
(:func:`locked`) keeps the cell and the inspector from interleaving. No ROS here: rows come as
plain dicts.
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
from stud_inspection.qa_codes import SamplingRules
from stud_inspection.sampling import BendTest, plan_bend_tests

JSON_NAME = "qa_report.json"
CSV_NAME = "qa_report.csv"
HTML_NAME = "qa_report.html"
#: Above this many studs the printed page lists only those that need attention (the CSV has all).
HTML_ALL_ROWS_UP_TO = 60

VERDICTS = ("pass", "fail", "missing", "not_inspected", "not_welded")
#: The CSV's columns: the first eighteen as ever, then the collar, the weld order, who decided, the bend test.
CSV_FIELDS = ["stud_id", "x_mm", "y_mm", "verdict", "reasons", "station", "planned_x_m", "planned_y_m", "planned_z_m",
              "measured_x_m", "measured_y_m", "measured_z_m", "lean_deg", "offset_x_mm", "offset_y_mm", "height_mm",
              "rework", "rework_note",
              "weld_seq", "collar_seen_deg", "collar_coverage_deg", "collar_height_mm", "collar_gap_deg",
              "rework_operator", "rework_time", "bend_test", "bend_angle_deg", "bend_direction", "bend_result",
              "bend_bent_deg", "bend_note", "bend_operator", "bend_time"]


def empty_row(stud_id: str, drawing_xy_mm) -> dict:
    """A drawing stud nothing has been done to yet: not welded."""
    return {"stud_id": stud_id, "drawing_xy_mm": [float(v) for v in drawing_xy_mm], "verdict": "not_welded",
            "reasons": [], "planned": None, "measured": None, "station": None, "weld_seq": None, "rework": None,
            "rework_note": None, "rework_operator": None, "rework_time": None, "bend_test": None}


def summary_of(rows: list[dict]) -> dict:
    """The number of studs per verdict, every verdict of :data:`VERDICTS` listed (0 included)."""
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
    """``rows`` with each decided stud's ``rework`` (the decision), ``rework_note``, ``rework_operator``
    and ``rework_time`` filled in; ``decisions``: stud id -> {"decision", "note", "operator", "time"}
    (rework.ReworkRecord.for_qa_record)."""
    out = []
    for row in rows:
        d = decisions.get(row["stud_id"])
        out.append({**row, "rework": d["decision"], "rework_note": d.get("note") or None,
                    "rework_operator": d.get("operator") or None, "rework_time": d.get("time")} if d else row)
    return out


def with_bend_tests(rows: list[dict], plan: list[BendTest], results: Mapping[str, Mapping]) -> list[dict]:
    """``rows`` with ``bend_test`` filled: why and how far each listed stud is bent, and its result
    (``results``: stud id -> bend.BendRecord.for_qa_record); a result on a stud the list does not
    name is kept too ("tested beyond the list")."""
    listed = {t.stud_id: t for t in plan}
    out = []
    for row in rows:
        sid = row["stud_id"]
        t, res = listed.get(sid), results.get(sid)
        bend = None
        if t is not None or res is not None:
            bend = {"reasons": list(t.reasons) if t else ["tested beyond the list"],
                    "angle_deg": t.angle_deg if t else None, "direction": t.direction if t else None,
                    "result": None, "bent_deg": None, "note": None, "operator": None, "time": None}
            if res is not None:
                bend.update({k: res.get(k) for k in ("result", "bent_deg", "note", "operator", "time")})
                bend["note"] = bend["note"] or None
        out.append({**row, "bend_test": bend})
    return out


def _merge(doc: dict, decisions: Mapping[str, Mapping], bends: Mapping[str, Mapping]) -> dict:
    """``doc`` with the operator's decisions and bend results in its rows, and its bend-test list drawn
    again (from the record's own rules and seed: a failed bend test adds its neighbours)."""
    rows = with_rework(doc["studs"], decisions)
    sampling, code = doc.get("sampling"), doc.get("code")
    plan: list[BendTest] = []
    if sampling is not None and code is not None:
        failed = {sid for sid, b in bends.items() if b.get("result") == "fail"}
        plan = plan_bend_tests(rows, SamplingRules.from_dict(code["sampling"]), int(sampling["seed"]), failed)
    rows = with_bend_tests(rows, plan, bends)
    doc = {**doc, "studs": rows}
    if sampling is not None:
        listed = [r for r in rows if r["bend_test"] is not None]
        results = [r["bend_test"]["result"] for r in listed]
        welded = sum(r["verdict"] != "not_welded" for r in rows)
        doc["sampling"] = {"seed": int(sampling["seed"]), "lot_welded": welded,
                           "lot_sample": sum(any(w.startswith("lot sample") for w in r["bend_test"]["reasons"])
                                             for r in listed),
                           "bend_tests": [{"stud_id": r["stud_id"], **r["bend_test"]} for r in listed],
                           "counts": {"listed": len(listed), "passed": results.count("pass"),
                                      "failed": results.count("fail"), "pending": results.count(None)}}
    return doc


def _csv_row(r: dict) -> list:
    p = (r.get("planned") or {}).get("position_m") or [None] * 3
    m = r.get("measured") or {}
    mp = m.get("position_m") or [None] * 3
    off = m.get("offset_mm") or [None, None]
    b = r.get("bend_test") or {}
    return [r["stud_id"], *r["drawing_xy_mm"], r["verdict"], "; ".join(r["reasons"]), r.get("station"), *p, *mp,
            m.get("lean_deg"), *off, m.get("height_mm"), r.get("rework") or "", r.get("rework_note") or "",
            r.get("weld_seq"), m.get("collar_seen_deg"), m.get("collar_coverage_deg"), m.get("collar_height_mm"),
            m.get("collar_gap_deg"), r.get("rework_operator") or "", r.get("rework_time") or "",
            "; ".join(b.get("reasons") or []), b.get("angle_deg"), b.get("direction") or "", b.get("result") or "",
            b.get("bent_deg"), b.get("note") or "", b.get("operator") or "", b.get("time") or ""]


def _fmt(x, digits: int = 1) -> str:
    return "" if x is None else f"{x:.{digits}f}"


_VERDICT_FILL = {"pass": "#2a9d2a", "fail": "#c00000", "missing": "#a000a0", "not_inspected": "#e09000",
                 "not_welded": "#9a9a9a"}


def _map_svg(rows: list[dict]) -> str:
    """The studs on the drawing (drawing frame, y up), coloured by verdict; a ring marks a stud to
    bend-test, a cross one whose bend test failed."""
    pts = [(r, r["drawing_xy_mm"]) for r in rows if r.get("drawing_xy_mm")]
    if not pts:
        return ""
    xs, ys = [p[0] for _r, p in pts], [p[1] for _r, p in pts]
    x0, x1, y0, y1 = min(xs), max(xs), min(ys), max(ys)
    w_mm, h_mm = max(x1 - x0, 1.0), max(y1 - y0, 1.0)
    width = 640.0
    scale = min((width - 40) / w_mm, 200.0 / h_mm)
    height = h_mm * scale + 40
    labels = len(pts) <= 40
    out = [f"<svg class='map' viewBox='0 0 {width:.0f} {height:.0f}' xmlns='http://www.w3.org/2000/svg'>"]
    for r, (x, y) in pts:
        cx, cy = 20 + (x - x0) * scale, height - 20 - (y - y0) * scale
        b = r.get("bend_test")
        if b is not None:
            out.append(f"<circle cx='{cx:.1f}' cy='{cy:.1f}' r='8' fill='none' stroke='#000' stroke-width='1.5'/>")
        out.append(f"<circle cx='{cx:.1f}' cy='{cy:.1f}' r='4.5' fill='{_VERDICT_FILL[r['verdict']]}'/>")
        if b is not None and b.get("result") == "fail":
            out.append(f"<path d='M{cx - 7:.1f} {cy - 7:.1f}L{cx + 7:.1f} {cy + 7:.1f}M{cx - 7:.1f} {cy + 7:.1f}"
                       f"L{cx + 7:.1f} {cy - 7:.1f}' stroke='#c00000' stroke-width='2'/>")
        if labels:
            out.append(f"<text x='{cx + 9:.1f}' y='{cy + 3:.1f}' font-size='9'>{html.escape(r['stud_id'])}</text>")
    out.append("</svg>")
    legend = " ".join(f"<span style='color:{c}'>&#9679;</span> {v.replace('_', ' ')}" for v, c in _VERDICT_FILL.items())
    return "".join(out) + f"<p class='note'>The studs on the drawing: {legend} &middot; &#9711; to bend-test</p>"


_LIMIT_TEXT = {"max_lean_deg": ("lean from the surface normal", "&le; {v:g}&deg;"),
               "position_tol_mm": ("base from the planned point", "&le; {v:g} mm"),
               "height_tol_mm": ("standing height above nominal", "+{v:g} mm"),
               "height_tol_below_mm": ("standing height below nominal", "&minus;{v:g} mm"),
               "min_collar_coverage_deg": ("collar (flash) around the stud", "{v:g}&deg;"),
               "min_collar_height_mm": ("collar height", "&ge; {v:g} mm"),
               "lot_sample_fraction": ("lot sample", "{p:g} % of the welded studs"),
               "lot_sample_min": ("lot sample, at least", "{v:g} studs"),
               "failure_neighbours": ("neighbours of a failure (weld order)", "{v:g} before, {v:g} after"),
               "preproduction_studs": ("pre-production test studs per shift", "{v:g}"),
               "bend_angle_deg": ("bend test angle", "{v:g}&deg;"),
               "missing_flash_bend_deg": ("stud without a full collar: bend", "{v:g}&deg; away from the gap")}


def _code_html(doc: dict) -> str:
    code, judged = doc.get("code"), doc.get("limits") or {}
    e = html.escape
    if not code:  # a record of no code profile: the limits it was judged by
        rows = [f"<tr><td>{_LIMIT_TEXT[n][0]}</td><td>{_LIMIT_TEXT[n][1].format(v=v, p=100 * v)}</td></tr>"
                for n, v in judged.items() if n in _LIMIT_TEXT and v is not None]
        return ("<h2>Limits</h2><table class='code'><tr><th>check</th><th>limit</th></tr>"
                f"{''.join(rows)}</table>") if rows else ""
    rows = []
    for group in ("limits", "sampling"):
        for name, entry in code[group].items():
            v = judged.get(name, entry["value"]) if group == "limits" else entry["value"]
            label, fmt = _LIMIT_TEXT.get(name, (name, "{v:g}"))
            mark = " <b>(overridden)</b>" if entry.get("overridden") else ""
            if group == "limits" and name in judged and judged[name] != entry["value"]:
                mark = f" <b>(the inspector judged with {judged[name]:g})</b>"
            rows.append(f"<tr><td>{label}</td><td>{fmt.format(v=v, p=100 * v)}</td><td>{e(entry['source'])}{mark}"
                        "</td></tr>")
    return (f"<h2>Code: {e(code['title'])} <small>(qa_code <code>{e(code['profile'])}</code>)</small></h2>"
            f"<table class='code'><tr><th>check</th><th>limit</th><th>source</th></tr>{''.join(rows)}</table>")


def _stud_rows_html(doc: dict) -> tuple[str, str]:
    e = html.escape
    rows = doc["studs"]
    shown = rows
    if len(rows) > HTML_ALL_ROWS_UP_TO:
        shown = [r for r in rows if r["verdict"] != "pass" or r.get("bend_test") or r.get("rework")]
    out = []
    for r in shown:
        m = r.get("measured") or {}
        off = m.get("offset_mm")
        collar = (f"{m['collar_coverage_deg']:.0f}/{m['collar_seen_deg']:.0f}"
                  if m.get("collar_seen_deg") is not None and m.get("collar_coverage_deg") is not None else "")
        rework = ""
        if r.get("rework"):
            rework = e(r["rework"]) + (e(": " + r["rework_note"]) if r.get("rework_note") else "")
            rework += f"<br><small>{e(r.get('rework_operator') or '?')}, {e((r.get('rework_time') or '')[:16])}</small>"
        b = r.get("bend_test") or {}
        bend = ""
        if b:
            bend = f"{_fmt(b.get('angle_deg'), 0)}&deg;" if b.get("angle_deg") is not None else "&mdash;"
            if b.get("result"):
                bend += f" {e(b['result'])}"
        out.append(f"<tr class='{e(r['verdict'])}'><td>{e(r['stud_id'])}</td><td>{e(r['verdict'].replace('_', ' '))}"
                   f"</td><td>{_fmt(m.get('lean_deg'))}</td>"
                   f"<td>{_fmt((off[0] ** 2 + off[1] ** 2) ** 0.5) if off else ''}"
                   f"</td><td>{_fmt(m.get('height_mm'))}</td><td>{collar}</td><td>{e('; '.join(r['reasons']))}</td>"
                   f"<td>{'' if r.get('station') is None else r['station']}</td><td>{bend}</td><td>{rework}</td></tr>")
    note = ("" if shown is rows else
            f"<p class='note'>{len(shown)} of {len(rows)} studs shown: those that did not pass, are listed for a bend "
            f"test or were decided on. Every stud is in {CSV_NAME} and {JSON_NAME}.</p>")
    seen = [float(m["collar_seen_deg"]) for r in rows
            if (m := r.get("measured") or {}).get("collar_seen_deg") is not None]
    hidden = [360.0 - v for v in seen if v < 360.0]
    if seen:
        note += ("<p class='note'>Collar: the degrees of the circle a collar covers / the degrees the camera saw. "
                 + (f"On {len(hidden)} of {len(seen)} studs up to {max(hidden):.0f}&deg; of it was hidden behind the "
                    "stud from the camera: check that side by eye." if hidden else "Every collar was seen all round.")
                 + "</p>")
    return "".join(out), note


def _bend_html(doc: dict) -> str:
    e = html.escape
    sampling = doc.get("sampling")
    if sampling is None:
        return ""
    items = sampling["bend_tests"]
    c = sampling["counts"]
    rows = []
    for t in items:
        res = e(t["result"]) if t.get("result") else "&nbsp;"
        who = (f"{e(t.get('operator') or '')}<br><small>{e((t.get('time') or '')[:16])}</small>"
               if t.get("result") else "")
        direction = f"<br><small>{e(t['direction'])}</small>" if t.get("direction") else ""
        rows.append(f"<tr><td>{e(t['stud_id'])}</td><td>{e('; '.join(t['reasons']))}{direction}</td>"
                    f"<td>{_fmt(t.get('angle_deg'), 0)}&deg;</td><td class='result'>{res}"
                    f"{e(': ' + t['note']) if t.get('note') else ''}</td><td>{who}</td></tr>")
    return (f"<h2>Bend tests <small>{c['listed']} listed: {c['passed']} passed, {c['failed']} failed, "
            f"{c['pending']} to do &middot; lot sample of {sampling['lot_sample']} "
            f"from {sampling['lot_welded']} welded, "
            f"drawn with seed {sampling['seed']}</small></h2>"
            "<table class='bend'><tr><th>stud</th><th>why</th><th>angle</th><th>result</th><th>tested by</th></tr>"
            f"{''.join(rows) or '<tr><td colspan=5>none</td></tr>'}</table>")


_CSS = """@page{size:A4;margin:11mm 11mm 12mm 11mm}
body{font:8.5pt/1.25 sans-serif;margin:0;color:#000}
@media screen{body{max-width:190mm;margin:1.5em auto}}
h1{font-size:14pt;margin:0 0 .2em}h2{font-size:10pt;margin:.7em 0 .25em}h2 small{font-weight:normal;color:#333}
p{margin:.25em 0}.note{color:#333;font-style:italic}
table{border-collapse:collapse;width:100%;font-size:7.5pt}\
td,th{border:1px solid #999;padding:1px 3px;text-align:left;vertical-align:top}
thead{display:table-header-group}tr{page-break-inside:avoid;break-inside:avoid}
tr.pass td:nth-child(2){color:#187a18}tr.fail td:nth-child(2),tr.missing td:nth-child(2){color:#b00;font-weight:bold}
tr.not_inspected td:nth-child(2){color:#a66b00}td.result{min-width:22mm}
.map{width:100%;max-height:55mm;border:1px solid #ccc}
figure{display:inline-block;width:48%;margin:.4em 1% 0 0;page-break-inside:avoid;break-inside:avoid}
figure img{width:100%;max-height:62mm;object-fit:contain}figcaption{font-size:7pt}
.sign{page-break-inside:avoid;break-inside:avoid;margin-top:.8em}.sign td{height:12mm;width:33%}
"""


def _html(doc: dict, overlays: list[Path]) -> str:
    job, counts = doc["job"], doc["summary"]
    e = html.escape
    stud_rows, note = _stud_rows_html(doc)
    images = []
    for path in overlays:
        data = base64.b64encode(path.read_bytes()).decode("ascii")
        images.append(f"<figure><img alt='{e(path.name)}' src='data:image/png;base64,{data}'>"
                      f"<figcaption>{e(path.name)}</figcaption></figure>")
    unexpected = "".join(f"<li>at ({o['position_m'][0]:.3f}, {o['position_m'][1]:.3f}, {o['position_m'][2]:.3f}) m, "
                         f"{o['height_mm']:.0f} mm high</li>" for o in doc["unexpected_objects"]) or "<li>none</li>"
    code = doc.get("code") or {}
    lim = doc.get("limits") or {}
    design = (f"stud &Oslash;{lim['stud_diameter_mm']:g} mm, {lim['nominal_length_mm']:g} mm after welding"
              if "stud_diameter_mm" in lim and "nominal_length_mm" in lim else "")
    return f"""<!doctype html><html><head><meta charset='utf-8'>\
<title>Stud weld QA record {e(str(job.get('id', '')))}</title>
<style>{_CSS}</style></head><body>
<h1>Stud weld QA record</h1>
<p>Job <b>{e(str(job.get('id', '')))}</b> &middot; part <b>{e(str(job.get('part', '')))}</b> &middot; drawing
<code>{e(str(job.get('drawing', '')))}</code> &middot; {e(str(job.get('date', '')))} &middot; \
job {e(str(job.get('state', '')))}
{('&middot; code <b>' + e(code['title']) + '</b>') if code else ''}{(' &middot; ' + design) if design else ''}</p>
<p>{' &middot; '.join(f"{e(k.replace('_', ' '))}: <b>{v}</b>" for k, v in counts.items())}. Measured in 3D by the cell's
camera after the welds (lean, base offset, standing height, collar: covered/seen degrees).</p>
{_map_svg(doc['studs'])}
{_code_html(doc)}
<h2>Studs</h2>{note}
<table><thead><tr><th>stud</th><th>verdict</th><th>lean [&deg;]</th><th>offset [mm]</th><th>height [mm]</th>
<th>collar [&deg;]</th><th>reasons</th><th>station</th><th>bend</th><th>decision</th></tr></thead>{stud_rows}</table>
{_bend_html(doc)}
<h2>Unexpected objects</h2><ul>{unexpected}</ul>
<h2>Inspection views</h2>{''.join(images) or '<p>none</p>'}
<table class='sign'><tr><th>Inspector (name, signature)</th><th>Date</th><th>Checked by (name, signature)</th></tr>
<tr><td></td><td></td><td></td></tr></table>
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


def _remove_stale_temporaries(out_dir: Path) -> None:
    """Temporary files a writer killed mid-write left behind (never the live record: that is renamed
    into place whole)."""
    for name in (JSON_NAME, CSV_NAME, HTML_NAME):
        for tmp in out_dir.glob(f".{name}.tmp*"):
            with contextlib.suppress(OSError):
                tmp.unlink()


def _write_files(out_dir: Path, doc: dict) -> None:
    """The three files, each replaced whole and forced to disk; the JSON -- the record others read
    back -- last, so it is never newer than the pages made from it."""
    _remove_stale_temporaries(out_dir)
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(CSV_FIELDS)
    for r in doc["studs"]:
        w.writerow(_csv_row(r))
    write_text_atomic(out_dir / CSV_NAME, text.getvalue(), durable=True)
    overlays = [p if p.is_absolute() else out_dir / p for p in map(Path, doc.get("overlays", []))]
    write_text_atomic(out_dir / HTML_NAME, _html(doc, [p for p in overlays if p.exists()]), durable=True)
    write_json(out_dir / JSON_NAME, doc, durable=True)


def write_qa_report(out_dir: Path, job: dict, limits: dict, rows: list[dict], unexpected: list[dict],
                    overlays: list[Path], decisions: Mapping[str, Mapping] | None = None, *,
                    code: dict | None = None, seed: int | None = None,
                    bends: Mapping[str, Mapping] | None = None) -> dict:
    """Write qa_report.json, .csv and .html into ``out_dir``; returns the JSON document.
    ``decisions``: the operator's rework decisions so far (:func:`with_rework`); ``code``: the code
    profile (qa_codes.CodeProfile.describe) -- with it and the lot sample's ``seed`` the record lists
    the bend tests (stud_inspection.sampling), with ``bends`` the results entered so far
    (:func:`with_bend_tests`). The document lists the ``overlays`` (relative to ``out_dir`` where
    inside it) for later re-writes."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    job = {"date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"), **job}
    rows = [{**empty_row(r["stud_id"], r["drawing_xy_mm"]), **r} for r in rows]
    doc = json_safe(document(job, limits, rows, unexpected))  # NaN -> null
    doc["code"] = json_safe(code) if code is not None else None
    doc["sampling"] = {"seed": int(seed)} if code is not None and seed is not None else None
    doc["overlays"] = [os.path.relpath(p, out_dir) if Path(p).resolve().is_relative_to(out_dir.resolve()) else str(p)
                       for p in overlays]
    doc = _merge(doc, decisions or {}, bends or {})
    _write_files(out_dir, doc)
    return doc


def read_record(out_dir: Path) -> dict | None:
    """The QA record in ``out_dir``; None when there is none (yet). ValueError naming the file when it
    is not one of ours."""
    path = Path(out_dir) / JSON_NAME
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read the QA record ({exc})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("studs"), list):
        raise ValueError(f"{path}: not a QA record (expected an object with a 'studs' list)")
    return doc


def apply_operator_entries(out_dir: Path, decisions: Mapping[str, Mapping],
                           bends: Mapping[str, Mapping] | None = None) -> dict | None:
    """Re-write the QA record in ``out_dir`` with every rework decision and bend-test result so far
    (the bend-test list drawn again from the record's rules and seed); None when there is no record
    (yet: the cell writes it at the end of the job, with the entries made so far)."""
    doc = read_record(out_dir)
    if doc is None:
        return None
    if bends is None:  # keep the results the record holds
        bends = {r["stud_id"]: r["bend_test"] for r in doc["studs"] if (r.get("bend_test") or {}).get("result")}
    doc = _merge(doc, decisions, bends)
    _write_files(Path(out_dir), doc)
    return doc


def apply_rework(out_dir: Path, decisions: Mapping[str, Mapping]) -> dict | None:
    """Re-write the QA record in ``out_dir`` with the operator's ``decisions`` in its ``rework``
    column (:func:`apply_operator_entries`, keeping the bend results it holds)."""
    return apply_operator_entries(out_dir, decisions)


__all__ = ["CSV_FIELDS", "CSV_NAME", "HTML_NAME", "JSON_NAME", "VERDICTS", "apply_operator_entries", "apply_rework",
           "document", "empty_row", "locked", "read_record", "summary_of", "with_bend_tests", "with_rework",
           "write_qa_report"]
