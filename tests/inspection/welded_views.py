"""Shots of a scene before and after its welds, as the cell takes them: planned on the shot before
(the matcher's plan_view), every stud welded where planned along the planned normal with the scene's
defects -- attached by position, as the sim camera attaches them -- and the shot after, from the same
pose, with a structured-light camera's correlated noise, quantisation and holes."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from stud_perception.scene_cameras import view_camera
from stud_perception.scene_file import load_scene
from stud_perception.scene_render import render
from stud_perception.welded_studs import DefectsByPosition, WeldDefect, welded_stud
from stud_planner.matching.view_targets import plan_view

CONFIG = Path(__file__).resolve().parents[2] / "src" / "stud_perception" / "config"
LENGTH_M = 0.05  # the bundled parts' M16x50 studs


def bundled(part: str):
    return dataclasses.replace(load_scene(CONFIG / f"{part}_scene.json"), stud_length_m=LENGTH_M)


def over(scene, distance=0.40):
    xy = scene.studs_world_xy_m.mean(axis=0)
    return view_camera((xy[0], xy[1], 0.0), distance + 0.005)


def with_defects(scene, defects: dict[str, WeldDefect], rename=None):
    """``scene`` with ``defects`` (by its stud ids); ``rename``: its studs numbered another way (old id ->
    new id), the defects following their studs -- a scene file written by someone else."""
    if rename is None:
        return dataclasses.replace(scene, weld_defects=dict(defects))
    return dataclasses.replace(scene, stud_ids=tuple(rename[s] for s in scene.stud_ids),
                               weld_defects={rename[s]: d for s, d in defects.items()})


@dataclasses.dataclass
class Shots:
    ids: list[str]          # the cell's (drawing) ids, as welded
    planned_w: np.ndarray
    normals_w: np.ndarray
    ok: np.ndarray
    before_m: np.ndarray
    after_m: np.ndarray
    camera: object
    studs: list             # the welded studs (None: missing)


def weld_and_shoot(scene, camera, weld_ids, seed=0, noise_m=0.0005, holes=0.01, correlation_px=1.5) -> Shots:
    """Plan on the shot before (targets named ``weld_ids``, the drawing's numbering, in scene order), weld
    every stud with the defect of the scene stud nearest to it, shoot after."""
    before = render(scene, camera, seed=seed, depth_noise_m=noise_m, hole_fraction=holes,
                    depth_noise_correlation_px=correlation_px)
    t = plan_view(list(weld_ids), np.asarray(scene.studs_drawing_m), scene.M_local2world, before.depth_m, camera)
    assert np.all(t.ok[before.stud_visible]), t.counts()
    by_position = DefectsByPosition(scene.studs_world_xy_m, scene.stud_ids, scene.weld_defects)
    studs = []
    for sid, p, n in zip(weld_ids, t.position_w, t.normal_w):
        scene_id, _d = by_position.nearest(p)
        defect = scene.weld_defects.get(scene_id) if scene_id is not None else None
        studs.append(welded_stud(sid, p, -n, defect, length_m=scene.stud_length_m,
                                 collar_height_m=scene.collar_height_m, collar_width_m=scene.collar_width_m))
    after = render(scene, camera, seed=seed + 1, depth_noise_m=noise_m, hole_fraction=holes,
                   welded=tuple(s for s in studs if s is not None), depth_noise_correlation_px=correlation_px)
    return Shots(list(weld_ids), t.position_w, t.normal_w, t.ok, before.depth_m, after.depth_m, camera, studs)
