"""The match tolerance decides: a stud whose best point on the view is between 1 and 10 mm from its
drawing position is refused at the default 1 mm (the paper's), never matched there.

Studs a few millimetres beyond the image border: the nearest surface the view shows is the border
itself, 2-7 mm from the stud. Before, no test produced a residual between 1 and 10 mm, so both
defaults (``PlannerConfig.tol_m``, the matcher node's ``tolerance_m``) could be raised to 10 mm with the
suite green, and such a stud would be welded up to 7 mm from where the drawing puts it."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from stud_perception.depth_image import depth_mm_to_m
from stud_perception.registration import world_to_local
from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render
from stud_planner.matching.view_targets import STATUS_TEXT, PlannerConfig, plan_view

REPO = Path(__file__).resolve().parents[2]
SCENE = load_scene(REPO / "src" / "stud_perception" / "config" / "dome_scene.json")
BEYOND_BORDER_PX = (5, 8, 12, 20)  # 2-7 mm at this view's 0.36 mm pixels


def edge_view():
    """The demo scene seen from 0.5 m straight down, and studs (drawing frame) just beyond the image's
    right border, on the floor's height there."""
    camera = view_camera((0, 0, 0), 1.0)
    camera = camera.with_pose(camera.R_wc, np.array([0.28, 0.10, 0.5]))
    depth = depth_mm_to_m(render(SCENE, camera, seed=1).depth_mm)
    h, w = depth.shape
    world = np.array([camera.pixel_to_world(w - 0.5 + du, h // 2, depth[h // 2, w - 1])[:2] for du in BEYOND_BORDER_PX])
    return camera, depth, world_to_local(SCENE.M_local2world, world)


@pytest.mark.parametrize("algorithm", ["batch", "fpm"])
def test_a_stud_whose_best_match_is_between_1_and_10_mm_off_is_refused_at_the_default_tolerance(algorithm):
    camera, depth, studs = edge_view()
    ids = [f"E{i}" for i in range(len(studs))]
    default = plan_view(ids, studs, SCENE.M_local2world, depth, camera, PlannerConfig(algorithm=algorithm))
    residual_mm = default.matches.xy_residual_m * 1e3
    assert np.all((residual_mm > 1.0) & (residual_mm < 10.0)), residual_mm  # the scene the limit decides
    refused = [STATUS_TEXT[int(s)] for s in default.status]
    assert set(refused) == {"out_of_view" if algorithm == "batch" else "not_converged"}, (refused, residual_mm)
    # what a 10 mm tolerance would have done: welded them where the border is
    loose = plan_view(ids, studs, SCENE.M_local2world, depth, camera, replace(PlannerConfig(algorithm=algorithm),
                                                                               tol_m=0.01))
    assert [STATUS_TEXT[int(s)] for s in loose.status] == ["ok"] * len(ids)
