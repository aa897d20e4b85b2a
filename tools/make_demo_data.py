#!/usr/bin/env python3
"""Regenerate the bundled demo data -- two curved parts and a long girder -- so samples are reproducible.

Writes, for each part (``dome``, ``shell``, ``girder``):
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

The girder (issue 35) is longer than the arm: a 6 m bridge-girder top flange (30 mm camber, 2.5 deg
cross slope) along the rail the arm rides (stud_bringup.demo_parts: a 7 m rail, the base 0.2 m up on
the carriage), rows of three studs 80 mm apart every 150 mm -- 120 studs, the most the issue's deck
spacing (rows every 150-250 mm) puts on 6 m -- and a reference mark every 100 mm alternately either
side of the studs (a camera view, 0.38 m along the girder, holds three or four of them: the fit over
them has a residual; at 200 mm a view held one or two), the marking board before its start. It is
checked with the same reach test at carriage positions along the rail (stud_common.frames.world_T_base):
for every camera station of the
cell's plan, a carriage position from which the arm puts the camera there *and* welds every stud the
station sees (so every stud is weldable from some carriage position), and one for the registration
view over the board. The RM-65's patch is narrow: a stud 0.22-0.38 m beside the rail's line is
weldable from a carriage up to 0.27-0.4 m before or after it; nearer than 0.2 m, the elbow folds.
Run: source ros2_ws/setup.bash && python tools/make_demo_data.py [--part girder]
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_common", "stud_perception", "stud_planner", "stud_inspection", "stud_cell", "rm65_driver", "rm65_sim",
            "stud_bringup"):
    sys.path.insert(0, str(REPO / "src" / pkg))

import numpy as np  # noqa: E402

from rm65_driver.kinematics.rm65 import RM65Kinematics  # noqa: E402
from rm65_driver.weld.reach import Reach  # noqa: E402
from rm65_driver.weld.safety import SafetyChecker, SafetyLimits  # noqa: E402
from stud_bringup.demo_parts import PARTS as DEMO_PARTS  # noqa: E402
from stud_bringup.demo_parts import DemoPart  # noqa: E402
from stud_cell.cell_reach import CellReach  # noqa: E402
from stud_cell.job import JobConfig  # noqa: E402
from stud_cell.stations import footprint_m, plan_stations  # noqa: E402
from stud_common.frames import world_T_base  # noqa: E402
from stud_common.rotations import rpy_to_matrix  # noqa: E402
from stud_common.strict_json import write_json  # noqa: E402
from stud_perception.scene import MarkingBoard, SceneSpec, girder_scene, surface_height, surface_normal  # noqa: E402
from stud_perception.scene_file import scene_from_dict, scene_to_dict  # noqa: E402
from stud_perception.scene_solids import Cylinder, Dome, Pose2D  # noqa: E402
from stud_planner.drawing import read_layout  # noqa: E402
from stud_planner.drawing.dxf_writer import LayoutDxfOptions, write_layout_dxf  # noqa: E402

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


#: The girder's layout (world: the rail's frame, x along it): the centreline's start, 0.30 m beside the
#: rail's line, so the three studs of a row stand 0.22, 0.30 and 0.38 m from the arm's axis; the board's
#: O 0.25 m before the start (A along the rail, B across), on the table where one view sees O, A, B, and
#: beside the near row (every stud in the drawing's first quadrant, as the drawing check expects).
GIRDER_START_XY_M = (0.5, 0.30)
GIRDER_BOARD_O_XY_M = (0.25, 0.20)


def girder_demo_scene() -> SceneSpec:
    """The bundled girder: 6 m, 0.4 m wide, 30 mm camber, 2.5 deg cross slope, crown 0.15 m above the
    table; rows of three studs 80 mm apart every 150 mm (120 studs); reference marks every 100 mm, 120 mm
    alternately either side of the centreline (clear of the studs, 20 mm discs like O, A, B)."""
    scene = girder_scene(length_m=6.0, width_m=0.4, camber_m=0.03, cross_slope_deg=2.5, height_m=0.12,
                         row_pitch_m=0.15, studs_per_row=3, stud_spacing_m=0.08, mark_pitch_m=0.1,
                         mark_offset_m=0.12, start_xy_m=GIRDER_START_XY_M, board_origin_xy_m=GIRDER_BOARD_O_XY_M)
    return dataclasses.replace(scene, stud_length_m=STUD_LENGTH_M, stud_diameter_m=0.016)  # M16x50, as the others


PARTS = {"dome": dome_scene, "shell": shell_scene, "girder": girder_demo_scene}


def _checker(limits: SafetyLimits = SafetyLimits()) -> SafetyChecker:
    """The driver's checks with the cell's tool, working branch and hand-eye (and ``limits``' box)."""
    kin = RM65Kinematics()
    tool = np.eye(4)
    tool[2, 3] = TOOL_OFFSET_M
    he = np.eye(4)
    he[:3, :3], he[:3, 3] = rpy_to_matrix(*np.radians(HAND_EYE_RPY_DEG)), HAND_EYE_XYZ_M
    return SafetyChecker(kin, limits, tool, prefer_signs=PREFERRED_JOINT_SIGNS, hand_eye_T=he)


def _cell_settings(part: DemoPart) -> dict:
    """The cell job's settings for ``part``: the job's defaults with the part's cell vars over them."""
    seq = vars(JobConfig())
    seq.update({k: v for k, v in part.cell_vars.items() if k in seq})
    return seq


def _stations(xy: np.ndarray, seq: dict, plane_z: float):
    fov = footprint_m(seq["fov_width_m"], seq["fov_distance_m"], seq["image_aspect"], seq["camera_height_m"],
                      seq["part_height_m"])
    return plan_stations(xy, fov, seq["camera_height_m"], overlap=seq["overlap"], plane_z_m=plane_z).stations


def check_reach(scene: SceneSpec, part: DemoPart) -> list[str]:
    """Why the cell could not do this part with its settings (empty: it can): every stud's weld plan,
    the registration station and the camera stations, as the driver would check them; on a rail
    (:func:`check_rail_reach`) from carriage positions along it."""
    if part.rail_length_m > 0:
        return check_rail_reach(scene, part)
    checker = _checker()
    home = np.radians([0.0, -30.0, -100.0, 0.0, -50.0, 0.0])
    problems = []
    xy = scene.studs_world_xy_m
    z = surface_height(scene, xy[:, 0], xy[:, 1])
    n = surface_normal(scene, xy[:, 0], xy[:, 1])
    for sid, p, nrm in zip(scene.stud_ids, np.column_stack([xy, z]), n):
        check = checker.check_target(p, nrm, STANDOFF_M, home)
        if not check.ok:
            problems.append(f"stud {sid} at {np.round(p, 3).tolist()}: {check.reason}")
    seq = _cell_settings(part)  # the cell job's settings: the stations the cell will use
    cameras = CellReach(checker.reach_for(STANDOFF_M))
    stations = _stations(xy, seq, scene.board.thickness_m)
    for what, xyz in [("registration station", seq["registration_station_xyz_m"])] + [
            (f"camera station {s.index}", s.camera_xyz_w) for s in stations]:
        verdict = cameras.cameras([(np.asarray(xyz), 0.0)])[0]
        if not verdict.ok:
            problems.append(f"{what} at {np.round(xyz, 3).tolist()} m is out of the arm's reach: {verdict.reason}")
    top = float(np.max(z))
    if top > seq["part_height_m"] + 1e-9:
        problems.append(f"the part's studs stand up to {top:.3f} m, above cell_sequencer part_height_m")
    return problems


#: Where a carriage may stand for a camera station: the station's x minus the base's, these offsets
#: tried nearest first (m): the RM-65 reaches about 0.45 m along the rail either way.
CARRIAGE_OFFSETS_M = sorted(np.round(np.arange(-0.45, 0.4501, 0.025), 3).tolist(), key=abs)


def carriage_for(reach: Reach, part: DemoPart, camera_xyz, studs: list[tuple[np.ndarray, np.ndarray]]) -> float | None:
    """A carriage position (m) from which the arm puts the nadir camera at ``camera_xyz`` (world) and
    welds every stud of ``studs`` ((position, normal) in world), by the driver's reach test; None if
    none along the rail does."""
    cameras = CellReach(reach)
    for dx in CARRIAGE_OFFSETS_M:
        c = float(camera_xyz[0]) - part.mount_xyz_m[0] - dx
        if not 0.0 <= c <= part.rail_length_m:
            continue
        W = world_T_base(c, part.mount_xyz_m)
        cameras.world_T_base = W
        if not cameras.camera_ok(camera_xyz) or not all(reach.stud(p, n, W).ok for p, n in studs):
            continue
        return c
    return None


def check_rail_reach(scene: SceneSpec, part: DemoPart) -> list[str]:
    """:func:`check_reach` on a rail: for the registration view over the board and every camera station
    of the cell's plan, a carriage position from which the arm puts the camera there and welds every
    stud of the station (its studs' exact heights and normals). Prints the carriage positions found."""
    seq = _cell_settings(part)
    limits = SafetyLimits(workspace_min_m=tuple(part.cell_vars["workspace_min_m"]),
                          workspace_max_m=tuple(part.cell_vars["workspace_max_m"]))
    reach = _checker(limits).reach_for(STANDOFF_M)
    xy = scene.studs_world_xy_m
    z = surface_height(scene, xy[:, 0], xy[:, 1])
    n = surface_normal(scene, xy[:, 0], xy[:, 1])
    stations = _stations(xy, seq, scene.board.thickness_m)
    problems = []
    covered = sorted(i for s in stations for i in s.stud_indices)
    if covered != list(range(len(xy))):
        problems.append(f"the cell's stations cover {len(covered)} of {len(xy)} studs")
    found = []
    for what, xyz, idx in [("registration station", seq["registration_station_xyz_m"], ())] + [
            (f"camera station {s.index}", s.camera_xyz_w, s.stud_indices) for s in stations]:
        c = carriage_for(reach, part, np.asarray(xyz, dtype=np.float64),
                         [(np.array([*xy[i], z[i]]), n[i]) for i in idx])
        if c is None:
            problems.append(f"{what} at {np.round(xyz, 3).tolist()} m with its {len(idx)} studs: no carriage position "
                            f"on the {part.rail_length_m:g} m rail reaches them all")
        else:
            found.append(f"{c:.3f}")
    top = float(np.max(z))
    if top > seq["part_height_m"] + 1e-9:
        problems.append(f"the part's studs stand up to {top:.3f} m, above cell_sequencer part_height_m")
    if not problems:
        print(f"girder: the registration view and {len(stations)} camera stations, each with its studs, reached from "
              f"carriage positions {', '.join(found)} m")
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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", nargs="+", choices=sorted(PARTS), default=list(PARTS),
                    help="the parts to write (default: all)")
    args = ap.parse_args(argv)
    for part in args.part:
        scene = PARTS[part]()
        problems = check_reach(scene, DEMO_PARTS[part])
        if problems:
            print(f"{part}: the cell cannot do this layout:\n  " + "\n  ".join(problems), file=sys.stderr)
            return 1
        dxf, scene_file = DATA / f"{part}_demo.dxf", CONFIG / f"{part}_scene.json"
        marks = {**dict(zip("OAB", scene.board.marks_drawing_m)), **scene.reference_marks_drawing_m}
        write_layout_dxf(dxf, np.asarray(scene.studs_drawing_m), marks,
                         LayoutDxfOptions(stud_diameter_m=0.016, mark_diameter_m=scene.board.mark_diameter_m,
                                          dxfversion="R2010", units="mm"))
        scene = scene_with_drawing_ids(scene, dxf)
        write_json(scene_file, scene_to_dict(scene))
        xy = scene.studs_world_xy_m
        slopes = np.degrees(np.arccos(surface_normal(scene, xy[:, 0], xy[:, 1])[:, 2]))
        marks_note = f", {len(scene.reference_marks)} reference marks" if scene.reference_marks else ""
        print(f"{part}: wrote {dxf.relative_to(REPO)} and {scene_file.relative_to(REPO)}: {len(xy)} studs{marks_note}, "
              f"slopes up to {slopes.max():.1f} deg; every stud and station within the arm's reach")
    return 0


if __name__ == "__main__":
    sys.exit(main())
