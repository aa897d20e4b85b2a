"""The weld-target table: `plan`'s report through TargetTable.merge/report_entries is, field for field,
the report of the per-stud arrays it replaced (kept below as they were, until they are deleted)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from stud_perception.scene import demo_dome_scene
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_render import render
from stud_planner.matching.target_table import TargetTable
from stud_planner.matching.view_targets import STATUS_OK, STATUS_OUT_OF_VIEW, STATUS_TEXT, PlannerConfig, plan_view

REPO = Path(__file__).resolve().parents[2]


class OldBestTargets:
    """offline_plan._BestTargets as it was (main at b2cee05), to compare against."""

    NONE, OK, FALLBACK = 2, 0, 1

    def __init__(self, n: int):
        self.rank = np.full(n, self.NONE, np.int8)
        self.centrality = np.full(n, np.inf)
        self.view = np.full(n, np.iinfo(np.int64).max, np.int64)
        self.status = np.zeros(n, np.uint8)
        self.position = np.full((n, 3), np.nan)
        self.normal = np.full((n, 3), np.nan)
        self.pixel = np.full((n, 2), np.nan)
        self.iterations = np.zeros(n, np.int64)
        self.xy_error_mm = np.full(n, np.nan)
        self.inclination = np.full(n, np.nan)
        self.normal_sigma = np.full(n, np.nan)
        self.lean_bound = np.full(n, np.nan)
        self.fill_ratio = np.full(n, np.nan)
        self.gun_clearance_mm = np.full(n, np.nan)
        self.reason: dict[int, str] = {}

    def add_view(self, t, view_index: int, camera) -> None:
        ok = t.status == STATUS_OK
        centre = np.array([camera.cx, camera.cy])
        half_diag = np.hypot(camera.width, camera.height) / 2
        centrality = np.linalg.norm(t.matches.pixel_uv - centre, axis=1) / half_diag
        take_ok = ok & ((self.rank != self.OK) | (centrality < self.centrality)
                        | ((centrality == self.centrality) & (view_index < self.view)))
        take_other = (~ok & (t.status != STATUS_OUT_OF_VIEW) & (self.rank != self.OK)
                      & (view_index < self.view))
        take = take_ok | take_other
        self.rank[take_ok], self.rank[take_other] = self.OK, self.FALLBACK
        self.centrality[take_ok] = centrality[take_ok]
        self.view[take] = view_index
        self.status[take] = t.status[take]
        self.position[take] = t.position_w[take]
        self.normal[take] = t.normal_w[take]
        self.pixel[take] = t.matches.pixel_uv[take]
        self.iterations[take] = t.matches.iterations[take]
        self.xy_error_mm[take] = t.matches.xy_residual_m[take] * 1e3
        self.inclination[take] = t.inclination_deg[take]
        self.normal_sigma[take] = t.normal_sigma_deg[take]
        self.lean_bound[take] = t.lean_bound_deg[take]
        self.fill_ratio[take] = t.poses.fill_ratio[take]
        self.gun_clearance_mm[take] = t.gun_clearance_m[take] * 1e3
        for i in np.flatnonzero(take_ok).tolist():
            self.reason.pop(i, None)
        for i in np.flatnonzero(take_other).tolist():
            self.reason[i] = t.reason(i)

    def entries(self, ids: list[str], xy_m: np.ndarray) -> list[dict]:
        xy_mm = (np.asarray(xy_m, dtype=np.float64).reshape(-1, 2) * 1e3).tolist()
        out = [{"stud_id": sid, "drawing_xy_mm": xy, "status": STATUS_TEXT[STATUS_OUT_OF_VIEW]}
               for sid, xy in zip(ids, xy_mm)]
        seen = np.flatnonzero(self.rank != self.NONE)
        names = [STATUS_TEXT[s] for s in self.status[seen].tolist()]
        pos, nrm, pix = (_nullable(a[seen]) for a in (self.position, self.normal, self.pixel))
        err, inc = _nullable(self.xy_error_mm[seen]), _nullable(self.inclination[seen])
        views, its = self.view[seen].tolist(), self.iterations[seen].tolist()
        sig, lean, fill, clear = (_nullable(a[seen]) for a in (self.normal_sigma, self.lean_bound, self.fill_ratio,
                                                                self.gun_clearance_mm))
        for k, i in enumerate(seen.tolist()):
            out[i].update(status=names[k], position_m=pos[k], normal=nrm[k], pixel=pix[k], view=views[k],
                          iterations=its[k], xy_error_mm=err[k], inclination_deg=inc[k], normal_sigma_deg=sig[k],
                          lean_bound_deg=lean[k], fill_ratio=fill[k], gun_clearance_mm=clear[k])
            if self.reason.get(i):
                out[i]["reason"] = self.reason[i]
        return out


def _nullable(values: np.ndarray) -> list:
    values = np.asarray(values, dtype=np.float64)
    out = values.tolist()
    bad = ~np.isfinite(values)
    if values.ndim == 1:
        for i in np.flatnonzero(bad).tolist():
            out[i] = None
    else:
        for i in np.flatnonzero(bad.any(axis=1)).tolist():
            out[i] = [v if math.isfinite(v) else None for v in out[i]]
    return out


def _same(new: list[dict], old: list[dict]) -> None:
    assert json.dumps(new) == json.dumps(old)  # the same keys in the same order, the same values


def test_plan_on_the_committed_bag_reports_what_the_old_arrays_reported(monkeypatch):
    from stud_planner import offline_plan

    seen = []
    real = offline_plan.plan_view

    def recording(*args, **kwargs):
        t = real(*args, **kwargs)
        seen.append((t, args[4]))
        return t

    monkeypatch.setattr(offline_plan, "plan_view", recording)
    report = offline_plan.plan(REPO / "src/stud_planner/data/dome_demo.dxf", REPO / "bags/dome_demo")
    old = OldBestTargets(len(report["targets"]))
    for t, camera in seen:
        old.add_view(t, int(t.view_index[0]), camera)
    _same(report["targets"], old.entries(seen[0][0].ids, seen[0][0].drawing_xy_m))


@pytest.mark.parametrize("config", [PlannerConfig(), PlannerConfig(lean_budget_deg=1.3)])
def test_merged_views_report_what_the_old_arrays_reported(config):
    """Views that overlap, miss studs, and fail some: merged one by one, in a shuffled order."""
    scene = demo_dome_scene()
    ids, xy = list(scene.stud_ids), np.asarray(scene.studs_drawing_m)
    apex = np.append(scene.studs_world_xy_m.mean(axis=0), 0.1)
    cams = [view_camera(apex + (dx, dy, 0.0), 0.5, tilt_rad=tilt, tilt_azimuth_rad=az, width=640, height=480)
            for dx, dy, tilt, az in ((0.0, 0.0, 0.0, 0.0), (0.12, 0.0, 0.0, 0.0), (-0.05, 0.08, 0.35, 1.0),
                                     (0.2, -0.1, 0.0, 0.0), (0.0, 0.0, 0.2, 3.0))]
    views = []
    for k, cam in enumerate(cams):
        view = render(scene, cam, seed=k, depth_noise_m=0.0005 * (1 + 2 * (k % 2)), hole_fraction=0.02)
        views.append((plan_view(ids, xy, scene.M_local2world, view.depth_m, cam, config, view_index=k), cam))
    statuses = {int(s) for t, _c in views for s in t.status}
    assert STATUS_OK in statuses and STATUS_OUT_OF_VIEW in statuses and len(statuses) >= 3, statuses
    for order in ([0, 1, 2, 3, 4], [3, 1, 4, 0, 2]):
        old, new = OldBestTargets(len(ids)), TargetTable.unseen(ids, xy)
        for k in order:
            t, cam = views[k]
            old.add_view(t, k, cam)
            new = new.merge(t)
        _same(new.report_entries(), old.entries(ids, xy))
