"""The stud-welding codes' checks: one table, one profile per code, every value cited and overridable.

A fabricator's inspector signs against a code. ``qa_code`` (the inspector's and the sequencer's
parameter, the cell's var) picks a profile here: the limits the post-weld inspection judges with
(stud_inspection.inspection.InspectionLimits) and the bend-test sampling the QA record lists
(stud_inspection.sampling). Each value carries where it comes from; a value the code's public
summary does not give is the cell's default and says so. Any value can be overridden per job
(the nodes' parameters of the same name): the record then says which were.

The numbers (docs/INSPECTION.md cites them):

- **GB 50205-2020 / GB 50661-2011** (China; the paper's code): stud inclination <= 5 deg; a full 360 deg
  collar at least 1 mm high; height after welding +-2 mm; bend test 30 deg on >= 1 % of the studs and
  at least 10 per lot.
- **EN ISO 14555** (production) with **EN ISO 13918** (the studs): 100 % visual examination; on a
  failure the 3 studs welded before and the 3 after it are tested; a simplified pre-production test
  of 3 studs per shift (visual and bend); length after welding: the design value +1 / -2 mm for shear
  studs (EN ISO 13918).
- **AWS D1.1** (clause 9 since 2020; D1.5 clause 7): a full 360 deg flash (collar) on visual
  inspection; before production, 2 test studs per shift bent about 30 deg from their axis (again after
  any change of current, time, lift or plunge); a stud whose flash is not 360 deg is bend-tested about
  15 deg, away from the missing flash.

The failure-neighbour rule (3 + 3 in weld order) is EN ISO 14555's; the other profiles keep it as
the cell's rule (their summaries give none), which an override of ``failure_neighbours`` can drop.
No ROS here.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Mapping

from stud_inspection.inspection import InspectionLimits

#: The profiles' names (the ``qa_code`` parameter's choices).
CODES = ("gb50205", "iso14555", "aws_d1_1")
DEFAULT_CODE = "gb50205"

#: The inspection limits a code may set (InspectionLimits fields) and the sampling rules (SamplingRules').
LIMIT_NAMES = ("max_lean_deg", "position_tol_mm", "height_tol_mm", "height_tol_below_mm", "min_collar_coverage_deg",
               "min_collar_height_mm")
SAMPLING_NAMES = ("lot_sample_fraction", "lot_sample_min", "failure_neighbours", "preproduction_studs",
                  "bend_angle_deg", "missing_flash_bend_deg")

_CELL = "cell default (not in the code's summary)"


@dataclass(frozen=True)
class Rule:
    """One value of a profile and where it comes from."""

    value: float
    source: str


def _r(value: float, source: str) -> Rule:
    return Rule(float(value), source)


#: The table: per code, per limit or sampling rule, the value and its source. One place.
TABLE: dict[str, dict[str, Any]] = {
    "gb50205": {
        "title": "GB 50205-2020 / GB 50661-2011 (China)",
        "max_lean_deg": _r(5.0, "GB 50205: stud inclination <= 5 deg"),
        "position_tol_mm": _r(2.0, _CELL),
        "height_tol_mm": _r(2.0, "GB 50205: height after welding +-2 mm"),
        "height_tol_below_mm": _r(2.0, "GB 50205: height after welding +-2 mm"),
        "min_collar_coverage_deg": _r(360.0, "GB 50205: a full 360 deg collar"),
        "min_collar_height_mm": _r(1.0, "GB 50205: collar height >= 1 mm"),
        "lot_sample_fraction": _r(0.01, "GB 50205: bend test on >= 1 % of the studs"),
        "lot_sample_min": _r(10, "GB 50205: and at least 10 per lot"),
        "failure_neighbours": _r(3, "the cell's rule, from EN ISO 14555 (3 before and 3 after a failed stud)"),
        "preproduction_studs": _r(0, _CELL),
        "bend_angle_deg": _r(30.0, "GB 50205: bend test 30 deg"),
        "missing_flash_bend_deg": _r(0.0, "none: a stud without a full collar fails"),
    },
    "iso14555": {
        "title": "EN ISO 14555 (production) with EN ISO 13918 (studs)",
        "max_lean_deg": _r(5.0, _CELL),
        "position_tol_mm": _r(2.0, _CELL),
        "height_tol_mm": _r(1.0, "EN ISO 13918: length after welding +1 mm"),
        "height_tol_below_mm": _r(2.0, "EN ISO 13918: length after welding -2 mm"),
        "min_collar_coverage_deg": _r(360.0, "EN ISO 14555: 100 % visual, a complete collar"),
        "min_collar_height_mm": _r(1.0, _CELL),
        "lot_sample_fraction": _r(0.0, "EN ISO 14555: no lot sample beyond the tests below"),
        "lot_sample_min": _r(0, "EN ISO 14555: no lot sample beyond the tests below"),
        "failure_neighbours": _r(3, "EN ISO 14555: on a failure, the 3 studs before and the 3 after it"),
        "preproduction_studs": _r(3, "EN ISO 14555: simplified pre-production test of 3 studs per shift"),
        "bend_angle_deg": _r(60.0, "EN ISO 14555: bend test 60 deg"),
        "missing_flash_bend_deg": _r(0.0, "none: a stud without a complete collar fails"),
    },
    "aws_d1_1": {
        "title": "AWS D1.1 clause 9 (D1.5 clause 7)",
        "max_lean_deg": _r(5.0, _CELL),
        "position_tol_mm": _r(2.0, _CELL),
        "height_tol_mm": _r(2.0, _CELL),
        "height_tol_below_mm": _r(2.0, _CELL),
        "min_collar_coverage_deg": _r(360.0, "AWS D1.1: a full 360 deg flash"),
        "min_collar_height_mm": _r(1.0, _CELL),
        "lot_sample_fraction": _r(0.0, "AWS D1.1: no lot sample beyond the tests below"),
        "lot_sample_min": _r(0, "AWS D1.1: no lot sample beyond the tests below"),
        "failure_neighbours": _r(3, "the cell's rule, from EN ISO 14555 (3 before and 3 after a failed stud)"),
        "preproduction_studs": _r(2, "AWS D1.1: 2 test studs per shift before production"),
        "bend_angle_deg": _r(30.0, "AWS D1.1: pre-production test studs bent about 30 deg"),
        "missing_flash_bend_deg": _r(15.0, "AWS D1.1: a stud without a full 360 deg flash bent about 15 deg, away "
                                           "from the missing flash"),
    },
}


class CodeError(ValueError):
    """An unknown code or override; the message names it and what was expected."""


@dataclass(frozen=True)
class SamplingRules:
    """Which studs the inspector must bend-test (stud_inspection.sampling): the lot's sample
    (``lot_sample_fraction`` of the welded studs, at least ``lot_sample_min``), the
    ``failure_neighbours`` welded before and after every failed stud, the first ``preproduction_studs``
    of the shift (the job), bent ``bend_angle_deg``; a stud without a full collar bent
    ``missing_flash_bend_deg`` away from the gap (0: no such test, the stud fails)."""

    lot_sample_fraction: float = 0.01
    lot_sample_min: int = 10
    failure_neighbours: int = 3
    preproduction_studs: int = 0
    bend_angle_deg: float = 30.0
    missing_flash_bend_deg: float = 0.0

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: Mapping) -> "SamplingRules":
        """From a QA record's ``code.sampling`` (each entry a value, or {"value": ...})."""
        fields = {f.name: f.type for f in dataclasses.fields(cls)}
        kw: dict[str, Any] = {}
        for name in fields:
            if name in d:
                v = d[name]["value"] if isinstance(d[name], Mapping) else d[name]
                integral = name in ("lot_sample_min", "failure_neighbours", "preproduction_studs")
                kw[name] = int(v) if integral else float(v)
        return cls(**kw)


@dataclass(frozen=True)
class CodeProfile:
    """A code's profile with this job's overrides: the inspection limits, the sampling rules and,
    for the record, every value with its source (:meth:`describe`)."""

    code: str
    title: str
    rules: dict[str, Rule]
    overridden: tuple[str, ...] = ()

    def value(self, name: str) -> float:
        return self.rules[name].value

    def limits(self, **design) -> InspectionLimits:
        """The inspection limits of this profile; ``design``: the stud's own InspectionLimits fields
        (``nominal_length_mm``, ``stud_diameter_mm``, ...), not the code's."""
        v = self.value
        return InspectionLimits(max_lean_deg=v("max_lean_deg"), position_tol_mm=v("position_tol_mm"),
                                height_tol_mm=v("height_tol_mm"), height_tol_below_mm=v("height_tol_below_mm"),
                                min_collar_coverage_deg=v("min_collar_coverage_deg"),
                                min_collar_height_mm=v("min_collar_height_mm"), **design)

    def sampling(self) -> SamplingRules:
        v = self.value
        return SamplingRules(lot_sample_fraction=v("lot_sample_fraction"), lot_sample_min=int(v("lot_sample_min")),
                             failure_neighbours=int(v("failure_neighbours")),
                             preproduction_studs=int(v("preproduction_studs")), bend_angle_deg=v("bend_angle_deg"),
                             missing_flash_bend_deg=v("missing_flash_bend_deg"))

    def describe(self) -> dict:
        """The record's ``code``: the profile, its title, and per limit and rule its value, source and
        whether this job overrode it."""
        def entry(n: str) -> dict:
            return {"value": self.rules[n].value, "source": self.rules[n].source, "overridden": n in self.overridden}
        return {"profile": self.code, "title": self.title, "limits": {n: entry(n) for n in LIMIT_NAMES},
                "sampling": {n: entry(n) for n in SAMPLING_NAMES}}


_BOUNDS = {"max_lean_deg": (0.1, 45.0), "position_tol_mm": (0.05, 100.0), "height_tol_mm": (0.05, 100.0),
           "height_tol_below_mm": (0.05, 100.0), "min_collar_coverage_deg": (0.0, 360.0),
           "min_collar_height_mm": (0.05, 50.0), "lot_sample_fraction": (0.0, 1.0), "lot_sample_min": (0, 100000),
           "failure_neighbours": (0, 100), "preproduction_studs": (0, 1000), "bend_angle_deg": (1.0, 180.0),
           "missing_flash_bend_deg": (0.0, 90.0)}


def profile(code: str, overrides: Mapping[str, float] | None = None) -> CodeProfile:
    """The profile of ``code`` (one of :data:`CODES`) with ``overrides`` (name -> value; a NaN value, or
    a negative one for the counts, keeps the code's): CodeError naming the code or the override."""
    key = str(code).strip().lower()
    if key not in TABLE:
        raise CodeError(f"qa_code {code!r}: expected one of {', '.join(CODES)}")
    entry = TABLE[key]
    rules = {n: entry[n] for n in (*LIMIT_NAMES, *SAMPLING_NAMES)}
    overridden = []
    for name, value in (overrides or {}).items():
        if name not in rules:
            raise CodeError(f"qa_code override {name!r}: expected one of {', '.join((*LIMIT_NAMES, *SAMPLING_NAMES))}")
        if value is None or (isinstance(value, float) and math.isnan(value)) or (
                name in ("lot_sample_min", "failure_neighbours", "preproduction_studs") and value < 0):
            continue
        lo, hi = _BOUNDS[name]
        if not lo <= float(value) <= hi:
            raise CodeError(f"qa_code override {name}={value}: expected a value in [{lo:g}, {hi:g}]")
        rules[name] = Rule(float(value), f"overridden for this job (the code's: {rules[name].value:g}, "
                                         f"{rules[name].source})")
        overridden.append(name)
    return CodeProfile(key, entry["title"], rules, tuple(overridden))


__all__ = ["CODES", "CodeError", "CodeProfile", "DEFAULT_CODE", "LIMIT_NAMES", "Rule", "SAMPLING_NAMES",
           "SamplingRules", "TABLE", "profile"]
