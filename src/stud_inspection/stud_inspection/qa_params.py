"""The nodes' parameters of the code profile (stud_inspection.qa_codes), declared once: ``qa_code``
and, per limit or sampling rule, an override whose "not set" value (NaN, or -1 for a count) keeps the
code's. The inspector takes the limits, the cell sequencer the sampling rules."""
from __future__ import annotations

import math

from stud_common.ros_io import Param
from stud_inspection import qa_codes

QA_CODE_PARAM = Param("qa_code", qa_codes.DEFAULT_CODE, "the stud-welding code the studs are judged and sampled by "
                      "(gb50205: GB 50205/50661, iso14555: EN ISO 14555 with 13918, aws_d1_1: AWS D1.1 clause 9); "
                      "each of its values can be overridden below (docs/INSPECTION.md)", choices=qa_codes.CODES)

_CODE = "NaN: the qa_code's"
_COUNT = "-1: the qa_code's"
LIMIT_PARAMS = [
    Param("max_lean_deg", math.nan, "the most a welded stud may lean from the surface normal [deg]", min=0.1,
          max=45.0, nan_means=_CODE),
    Param("position_tol_mm", math.nan, "the most the stud's base may lie from the planned point [mm]", min=0.05,
          max=100.0, nan_means=_CODE),
    Param("height_tol_mm", math.nan, "how far the standing height may exceed the nominal length [mm]", min=0.05,
          max=100.0, nan_means=_CODE),
    Param("height_tol_below_mm", math.nan, "how far the standing height may fall short of the nominal length [mm]",
          min=0.05, max=100.0, nan_means=_CODE),
    Param("min_collar_coverage_deg", math.nan, "the part of the circle the weld collar (flash) must cover; 0: no "
          "collar check [deg]", min=0.0, max=360.0, nan_means=_CODE),
    Param("min_collar_height_mm", math.nan, "the least height that counts as collar [mm]", min=0.05, max=50.0,
          nan_means=_CODE),
]
SAMPLING_PARAMS = [
    Param("lot_sample_fraction", math.nan, "the lot's bend-test sample: this fraction of the welded studs", min=0.0,
          max=1.0, nan_means=_CODE),
    Param("lot_sample_min", -1, f"the lot's bend-test sample: at least this many studs ({_COUNT})", min=-1,
          max=100000),
    Param("failure_neighbours", -1, f"studs welded before and after a failed one that are bend-tested ({_COUNT})",
          min=-1, max=100),
    Param("preproduction_studs", -1, f"the shift's first studs bend-tested as pre-production test studs ({_COUNT})",
          min=-1, max=1000),
    Param("bend_angle_deg", math.nan, "the bend test's angle [deg]", min=1.0, max=180.0, nan_means=_CODE),
    Param("missing_flash_bend_deg", math.nan, "a stud without a full collar is bent this far away from the gap; 0: "
          "it fails instead [deg]", min=0.0, max=90.0, nan_means=_CODE),
]


def overrides(p: dict, params: list[Param]) -> dict[str, float]:
    """The override parameters of ``params`` that are set, by name (qa_codes.profile's ``overrides``)."""
    out = {}
    for param in params:
        v = p[param.name]
        if isinstance(v, float) and math.isnan(v) or isinstance(v, int) and v < 0:
            continue
        out[param.name] = v
    return out


__all__ = ["LIMIT_PARAMS", "QA_CODE_PARAM", "SAMPLING_PARAMS", "overrides"]
