#!/usr/bin/env python3
"""Regenerate the bundled demo data -- two curved parts -- so samples are reproducible.

Writes, for each part (``dome``, ``shell``):
  src/stud_planner/data/<part>_demo.dxf         the drawing civil engineers would hand us (mm, R2010)
  src/stud_perception/config/<part>_scene.json  the matching synthetic scene (world placement,
                                                surface, board), with the drawing's stud ids

The parts are the paper's kind, curved: a dome (a 150 mm-radius head, 9 studs, 8 of them on 21.5
deg slopes) and a tank-shell section (a horizontal cylinder of 150 mm radius, 16 studs across
+-23.6 deg of slope). The gun welds each stud along its normal.

`world` is the RM-65 base frame, and the RM-65 is small (610 mm reach): with a 0.15 m gun and a
50 mm approach along the normal, a stud leaning away from the arm pushes the wrist out of reach
and one leaning toward it folds the elbow past its limit, so a part with 20+ deg slopes all round
fits only where its studs stand high enough and close enough. The layout below is checked here
with the reach test the cell plans with and the driver applies (rm65_driver.weld.reach: every stud's
approach, contact and descent, the free rotation about the stud searched; the registration and
camera stations through the hand-eye, as the sequencer asks it), with the cell's defaults
(cell_sequencer, arm_driver); a layout that fails is an error, not a file.
Run: source ros2_ws/setup.bash && python tools/make_demo_data.py
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_common", "stud_perception", "stud_planner", "stud_inspection", "stud_cell", "rm65_driver", "rm65_sim"):
    sys.path.insert(0, str(REPO / "src" / pkg))

import numpy as np  # noqa: E402

from rm65_driver.kinematics.rm65 import RM65Kinematics  # noqa: E402
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits  # noqa: E402
from stud_common.rotations import rpy_to_matrix  # noqa: E402
from stud_perception.scene import MarkingBoard, SceneSpec, surface_height, surface_normal  # noqa: E402
from stud_perception.scene_file import scene_from_dict, scene_to_dict  # noqa: E402
from stud_perception.scene_solids import Cylinder, Dome, Pose2D  # noqa: E402
from stud_common.strict_json import write_json  # noqa: E402
from stud_cell.job import JobConfig  # noqa: E402
from stud_planner.drawing import read_layout  # noqa: E402
from stud_planner.drawing.dxf_writer import write_layout_dxf  # noqa: E402
from stud_cell.cell_reach import CellReach  # noqa: E402
from stud_cell.stations import footprint_m, plan_stations  # noqa: E402

DATA = REPO / "src" / "stud_planner" / "data"
CONFIG = REPO / "src" / "stud_perception" / "config"

#: The marking board beside the part, drawing frame = board frame: O at world (0.16, -0.34), x along
#: world +X. Both parts share it (one cell layout).
BOARD_POSE = Pose2D(x_m=0.16, y_m=-0.34, yaw_rad=0.0)
#: The cell's defaults these parts are laid out for (arm_driver and cell.yaml): tool and approach.
TOOL_OFFSET_M, STANDOFF_M = 0.15, 0.06  # the driver's tool_offset_m, cell.yaml standoff_m
HAND_EYE_XYZ_M, HAND_EYE_RPY_DEG = (0.05, 0.0, -0.10), (0.0, 0.0, 0.0)
PREFERRED_JOINT_SIGNS = (0, 0, -1, 0, -1, 0)  # cell.yaml's arm_driver preferred_joint_signs
#: M16x50 studs: the camera stations stand 0.25 m above the parts' tops (as high as the arm holds a
#: nadir camera here), and the post-weld shot must see every stud's top inside the image.
STUD_LENGTH_M = 0.05


def dome_scene() -> SceneSpec:
    """A 150 mm-radius head (a hemisphere) centred 0.215 m from the arm's axis: the apex and a ring of
    8 at 55 mm, on 21.5 deg slopes (43 mm apart: the drawing check's 2.5 stud diameters)."""
    centre = np.array([0.215, 0.0])
    comp = Dome(tuple(centre), base_radius_m=0.15, height_m=0.15)
    rings = [(0.055, 8, math.pi / 8)]
    world = [centre] + [centre + r * np.array([math.cos(a0 + 2 * math.pi * k / m), math.sin(a0 + 2 * math.pi * k / m)])
                        for r, m, a0 in rings for k in range(m)]
    return _scene(comp, np.array(world))


def shell_scene() -> SceneSpec:
    """A tank-shell section: a horizontal cylinder of 150 mm radius, its axis along world X (away
    from the arm), 0.26 m long, crown 0.12 m above the plane; 4 rows of 4 studs across it, 40-45 mm
    apart, the outer ones on 23.6 deg slopes."""
    comp = Cylinder((0.22, 0.0), radius_m=0.15, axis_yaw_rad=0.0, length_m=0.26, height_m=0.12)
    world = np.array([[x, y] for x in (0.15, 0.195, 0.24, 0.285) for y in (-0.06, -0.02, 0.02, 0.06)])
    return _scene(comp, world)


def _scene(component, studs_world_xy) -> SceneSpec:
    drawing = BOARD_POSE.apply_inverse(np.asarray(studs_world_xy))
    return SceneSpec(component=component, board=MarkingBoard(), drawing_to_world=BOARD_POSE,
                     studs_drawing_m=tuple(map(tuple, np.round(drawing, 6))), stud_mark_diameter_m=0.008,
                     stud_length_m=STUD_LENGTH_M, stud_diameter_m=0.016)


PARTS = {"dome": dome_scene, "shell": shell_scene}


def check_reach(scene: SceneSpec) -> list[str]:
    """Why the cell could not do this part with its defaults (empty: it can): every stud's weld
    plan, the registration station and the camera stations, as the driver would check them."""
    kin = RM65Kinematics()
    tool = np.eye(4)
    tool[2, 3] = TOOL_OFFSET_M
    he = np.eye(4)
    he[:3, :3], he[:3, 3] = rpy_to_matrix(*np.radians(HAND_EYE_RPY_DEG)), HAND_EYE_XYZ_M
    checker = SafetyChecker(kin, SafetyLimits(), tool, prefer_signs=PREFERRED_JOINT_SIGNS, hand_eye_T=he)
    home = np.radians([0.0, -30.0, -100.0, 0.0, -50.0, 0.0])
    problems = []
    xy = scene.studs_world_xy_m
    z = surface_height(scene, xy[:, 0], xy[:, 1])
    n = surface_normal(scene, xy[:, 0], xy[:, 1])
    for sid, p, nrm in zip(scene.stud_ids, np.column_stack([xy, z]), n):
        check = checker.check_target(p, nrm, STANDOFF_M, home)
        if not check.ok:
            problems.append(f"stud {sid} at {np.round(p, 3).tolist()}: {check.reason}")
    seq = vars(JobConfig())  # the cell job's defaults: the stations the cell will use
    cameras = CellReach(checker.reach_for(STANDOFF_M))
    plane_z = scene.board.thickness_m
    fov = footprint_m(seq["fov_width_m"], seq["fov_distance_m"], seq["image_aspect"], seq["camera_height_m"],
                      seq["part_height_m"])
    stations = plan_stations(xy, fov, seq["camera_height_m"], overlap=seq["overlap"], plane_z_m=plane_z).stations
    for what, xyz in [("registration station", seq["registration_station_xyz_m"])] + [
            (f"camera station {s.index}", s.camera_xyz_w) for s in stations]:
        verdict = cameras.cameras([(np.asarray(xyz), 0.0)])[0]
        if not verdict.ok:
            problems.append(f"{what} at {np.round(xyz, 3).tolist()} m is out of the arm's reach: {verdict.reason}")
    top = float(np.max(z))
    if top > seq["part_height_m"] + 1e-9:
        problems.append(f"the part's studs stand up to {top:.3f} m, above cell_sequencer part_height_m")
    return problems


def scene_with_drawing_ids(scene: SceneSpec, dxf_path: Path) -> SceneSpec:
    """The scene with its studs renamed to the ids our DXF parser gives them (matched by position)."""
    layout = read_layout(dxf_path)
    lay_xy = layout.studs_xy_m()
    ids = []
    for xy in np.asarray(scene.studs_drawing_m):
        i = int(np.argmin(np.linalg.norm(lay_xy - xy, axis=1)))
        if np.linalg.norm(lay_xy[i] - xy) > 1e-6:
            raise SystemExit(f"stud at {xy} not found in {dxf_path}")
        ids.append(layout.studs[i].id)
    d = scene_to_dict(scene)
    d["studs"]["ids"] = ids
    return scene_from_dict(d)


def main() -> int:
    for part, make in PARTS.items():
        scene = make()
        problems = check_reach(scene)
        if problems:
            print(f"{part}: the cell cannot do this layout:\n  " + "\n  ".join(problems), file=sys.stderr)
            return 1
        dxf, scene_file = DATA / f"{part}_demo.dxf", CONFIG / f"{part}_scene.json"
        marks = dict(zip("OAB", scene.board.marks_drawing_m))
        write_layout_dxf(dxf, np.asarray(scene.studs_drawing_m), marks, stud_diameter_m=0.016,
                         mark_diameter_m=scene.board.mark_diameter_m, dxfversion="R2010", units="mm")
        scene = scene_with_drawing_ids(scene, dxf)
        write_json(scene_file, scene_to_dict(scene))
        xy = scene.studs_world_xy_m
        slopes = np.degrees(np.arccos(surface_normal(scene, xy[:, 0], xy[:, 1])[:, 2]))
        print(f"{part}: wrote {dxf.relative_to(REPO)} and {scene_file.relative_to(REPO)}: {len(xy)} studs, "
              f"slopes up to {slopes.max():.1f} deg; every stud and station within the arm's reach")
    return 0


if __name__ == "__main__":
    sys.exit(main())
