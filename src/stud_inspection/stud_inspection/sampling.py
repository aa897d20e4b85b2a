"""Which studs the inspector must bend-test: the lot's sample, the neighbours of failures, the
pre-production test studs, and (AWS D1.1) the studs without a full collar.

The rules are the code profile's (stud_inspection.qa_codes.SamplingRules); the studs are the QA
record's rows (stud_inspection.qa_report), with their verdicts, where they are on the drawing
(``drawing_xy_mm``) and when they were welded (``weld_seq``: 1, 2, ... in the job's weld order). The
lot is the job: its welded studs.

- **Lot sample**: ``max(lot_sample_min, ceil(lot_sample_fraction x welded))`` of the studs that passed
  (or could not be judged), spread over the part: the studs in Morton (Z-curve) order of their drawing
  position cut into as many runs of neighbouring studs as the sample has studs, one drawn from each.
  The draw is ``numpy.random.default_rng(seed)``'s: the seed is stored in the record, so anyone can
  draw the same sample again from the record alone (:func:`plan_bend_tests`).
- **Neighbours of a failure**: the ``failure_neighbours`` studs welded just before and just after every
  stud that failed inspection (fail, missing) or its bend test, in weld order (those standing).
- **Pre-production**: the first ``preproduction_studs`` the job welded (the shift's first).
- **Missing flash** (``missing_flash_bend_deg`` > 0, AWS D1.1): a stud that failed for its collar is
  bent that far, away from the gap (toward the gap's azimuth + 180 deg in the tangent frame).

A stud named by several rules is listed once, with every reason, bent to the largest angle asked.
No ROS here.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from stud_inspection.qa_codes import SamplingRules

#: Verdicts of studs a lot sample is drawn from (the others are failures, or not there).
SAMPLED_VERDICTS = ("pass", "not_inspected")
#: Verdicts that are failures (their neighbours are tested); a failed bend test is one too.
FAILED_VERDICTS = ("fail", "missing")


@dataclass(frozen=True)
class BendTest:
    """One stud to bend-test: why (one or more reasons), how far, and which way when it matters."""

    stud_id: str
    reasons: tuple[str, ...]
    angle_deg: float
    direction: str | None = None

    def to_dict(self) -> dict:
        return {"stud_id": self.stud_id, "reasons": list(self.reasons), "angle_deg": self.angle_deg,
                "direction": self.direction}


def morton_order(xy: np.ndarray) -> np.ndarray:
    """Indices sorting points ``xy`` (N, 2) along a Z-order curve over their bounding box: neighbours
    along the curve are neighbours on the part, and every contiguous run covers a compact patch."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if not len(xy):
        return np.zeros(0, dtype=int)
    lo, span = xy.min(axis=0), np.ptp(xy, axis=0)
    q = np.floor((xy - lo) / np.where(span > 0, span, 1.0) * 65535).astype(np.int64)

    def spread(v: np.ndarray) -> np.ndarray:  # 16 bits -> every other of 32
        v = (v | (v << 8)) & 0x00FF00FF
        v = (v | (v << 4)) & 0x0F0F0F0F
        v = (v | (v << 2)) & 0x33333333
        return (v | (v << 1)) & 0x55555555

    return np.argsort(spread(q[:, 0]) | (spread(q[:, 1]) << 1), kind="stable")


def lot_sample(ids: list[str], xy_mm: np.ndarray, count: int, seed: int) -> list[str]:
    """``count`` of ``ids`` (at drawing positions ``xy_mm`` (N, 2)) spread over the part, drawn with
    ``seed``; in the order given."""
    if count <= 0 or not ids:
        return []
    order = morton_order(xy_mm)
    rng = np.random.default_rng(seed)
    picked = {int(run[rng.integers(len(run))]) for run in np.array_split(order, min(count, len(ids)))}
    return [ids[i] for i in sorted(picked)]


def sample_size(rules: SamplingRules, welded: int, eligible: int) -> int:
    """How many studs the lot's sample holds: the code's fraction of the welded studs, at least its
    minimum, at most every eligible stud."""
    if rules.lot_sample_fraction <= 0 and rules.lot_sample_min <= 0:
        return 0
    return min(eligible, max(rules.lot_sample_min, math.ceil(rules.lot_sample_fraction * welded - 1e-9)))


def _has_collar_failure(row: dict) -> bool:
    return row["verdict"] == "fail" and any("collar" in r for r in row.get("reasons", []))


def plan_bend_tests(rows: list[dict], rules: SamplingRules, seed: int,
                    bend_failed: set[str] | frozenset[str] = frozenset()) -> list[BendTest]:
    """The studs to bend-test, in drawing order (``rows``: the QA record's, drawing order), for
    ``rules`` and the lot sample's ``seed``; ``bend_failed``: studs whose bend test failed (their
    neighbours are tested too)."""
    reasons: dict[str, list[str]] = {}
    angle: dict[str, float] = {}
    direction: dict[str, str] = {}

    def add(sid: str, why: str, deg: float) -> None:
        if why not in reasons.setdefault(sid, []):
            reasons[sid].append(why)
        angle[sid] = max(angle.get(sid, 0.0), deg)

    by_id = {r["stud_id"]: r for r in rows}
    order = sorted((r for r in rows if r.get("weld_seq") is not None), key=lambda r: r["weld_seq"])
    standing = [r for r in order if r["verdict"] != "missing"]
    for k, r in enumerate(standing[:rules.preproduction_studs]):
        add(r["stud_id"], f"pre-production test stud (welded {k + 1}. this shift)", rules.bend_angle_deg)

    eligible = [r for r in rows if r["verdict"] in SAMPLED_VERDICTS and r.get("weld_seq") is not None]
    welded = sum(r["verdict"] != "not_welded" for r in rows)
    n = sample_size(rules, welded, len(eligible))
    for sid in lot_sample([r["stud_id"] for r in eligible],
                          np.array([r["drawing_xy_mm"] for r in eligible], dtype=np.float64).reshape(-1, 2), n, seed):
        add(sid, f"lot sample ({n} of {welded} welded)", rules.bend_angle_deg)

    if rules.failure_neighbours > 0:
        position = {r["stud_id"]: k for k, r in enumerate(order)}
        failed = [sid for sid in (*(r["stud_id"] for r in order if r["verdict"] in FAILED_VERDICTS), *bend_failed)
                  if sid in position]
        for sid in dict.fromkeys(failed):
            why = "bend test failed" if sid in bend_failed else by_id[sid]["verdict"]
            k = position[sid]
            for other in order[max(0, k - rules.failure_neighbours):k] + order[k + 1:k + 1 + rules.failure_neighbours]:
                if other["verdict"] not in ("missing", "not_welded"):
                    add(other["stud_id"], f"welded next to {sid} ({why})", rules.bend_angle_deg)

    if rules.missing_flash_bend_deg > 0:
        for r in rows:
            if _has_collar_failure(r):
                add(r["stud_id"], "collar (flash) not 360 deg", rules.missing_flash_bend_deg)
                gap = (r.get("measured") or {}).get("collar_gap_azimuth_deg")
                if gap is not None:
                    toward = (gap + 180.0 + 180.0) % 360.0 - 180.0
                    direction[r["stud_id"]] = (f"away from the gap: toward azimuth {toward:.0f} deg (gap at {gap:.0f} "
                                               "deg; azimuth 0 = world X across the surface)")

    return [BendTest(r["stud_id"], tuple(reasons[r["stud_id"]]), angle[r["stud_id"]], direction.get(r["stud_id"]))
            for r in rows if r["stud_id"] in reasons]


__all__ = ["BendTest", "FAILED_VERDICTS", "SAMPLED_VERDICTS", "lot_sample", "morton_order", "plan_bend_tests",
           "sample_size"]
