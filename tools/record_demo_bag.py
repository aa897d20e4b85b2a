#!/usr/bin/env python3
"""Re-record bags/dome_demo: the sim camera's shots of the demo dome, with ground truth (or a girder's, on a rail).

Views: the registration station over the marking board, then the camera stations the cell
sequencer plans for the drawing (station_planning with the sequencer's defaults), each one
shot as the camera node publishes it (stud_perception.camera_node.shot_messages: bgr8,
16UC1 mm depth with 0.5 mm noise and 1 % holes, camera info, /camera/pose), 0.5 s apart,
plus the latched /drawing/layout. Written with the same rosbag2 MCAP writer `ros2 bag record`
uses (zstd chunks). Next to it, ground_truth.json: the exact weld point and normal of every
stud, the true M_local2world and the camera poses.

``--part girder``: the bundled 6 m girder seen from the arm on its rail (stud_bringup.demo_parts: the
rail's simulated error on): the registration view over the board, then the camera stations of the
girder's cell settings (``--stations 0 1 17 18`` picks some; all 19 make a ~10 MB bag), the carriage
under each station. ``/camera/pose`` is where the cell believes the camera is (the straight, exact rail);
the image is rendered where the rail truly carries it. ground_truth.json adds each view's carriage and
the rail's true correction there (``stud_common.frames.true_world_correction``): a stud's target in the
cell's believed world from that view is that correction's inverse applied to its true position.
Not committed (the girder demo records its own, ``sensor_bag/``); the tests record a few views.
Run: source ros2_ws/setup.bash && python tools/record_demo_bag.py [--out bags/dome_demo]
     python tools/record_demo_bag.py --part girder --out /tmp/girder_bag [--stations 0 1 17 18]
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_common", "stud_perception", "stud_planner", "stud_inspection", "stud_cell", "stud_bringup"):
    sys.path.insert(0, str(REPO / "src" / pkg))

import numpy as np  # noqa: E402

from stud_bag import BagWriter, Qos  # noqa: E402
from stud_cell.job import JobConfig  # noqa: E402
from stud_cell.stations import footprint_m, plan_stations  # noqa: E402
from stud_common import ros_io  # noqa: E402
from stud_common.frames import RailDeviation, true_world_correction  # noqa: E402
from stud_common.strict_json import write_json  # noqa: E402
from stud_perception.camera_model import CameraModel, nadir_rotation  # noqa: E402
from stud_perception.camera_node import shot_messages  # noqa: E402
from stud_perception.scene import SceneSpec  # noqa: E402
from stud_perception.scene_cameras import view_camera  # noqa: E402
from stud_perception.scene_file import load_scene  # noqa: E402
from stud_perception.scene_render import render  # noqa: E402
from stud_planner.drawing import read_layout  # noqa: E402
from stud_planner.msg_convert import layout_to_msg  # noqa: E402

DRAWING = REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf"
SCENE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"
T0_NS = 1_790_000_000_000_000_000  # fixed start time: the bag is byte-for-byte reproducible
NOISE_M, HOLES = 0.0005, 0.01


def camera_at(xyz) -> CameraModel:
    template = view_camera((0.0, 0.0, 0.0), distance_m=1.0)
    return template.with_pose(nadir_rotation(0.0), np.asarray(xyz, dtype=float))


def station_cameras(scene: SceneSpec, settings: dict, plane_z_m: float = 0.0) -> list[tuple[float, float, float]]:
    """The registration station, then the camera stations the cell job plans with ``settings``."""
    fov = footprint_m(settings["fov_width_m"], settings["fov_distance_m"], settings["image_aspect"],
                      settings["camera_height_m"], settings["part_height_m"])
    plan = plan_stations(scene.studs_world_xy_m, fov, settings["camera_height_m"], overlap=settings["overlap"],
                         plane_z_m=plane_z_m)
    return [tuple(settings["registration_station_xyz_m"])] + [s.camera_xyz_w for s in plan.stations]


def write_sensor_bag(out: Path, scene_file: Path, drawing: Path, cameras: list[CameraModel],
                     corrections: list[np.ndarray] | None = None, carriages_m: list[float] | None = None,
                     t0_ns: int = T0_NS) -> dict:
    """Render one shot per believed camera pose of ``cameras`` (the true pose: ``corrections[k]`` (4x4) applied
    to it, identity by default) and write the bag at ``out`` (replaced) with ``ground_truth.json``; returns it.
    ``carriages_m``: the carriage of each view (a rail), written to the ground truth with its correction."""
    scene, layout = load_scene(scene_file), read_layout(drawing)
    corrections = corrections or [np.eye(4)] * len(cameras)
    if out.exists():
        shutil.rmtree(out)
    topics = ros_io_topics()
    truth_views = []
    with BagWriter(out) as bag:
        bag.add_topic("/drawing/layout", "stud_welding_msgs/msg/StudLayout",
                      offered_qos_profiles=[Qos(durability="transient_local", depth=1)])
        for name, type_name in topics.values():
            bag.add_topic(name, type_name)
        bag.write("/drawing/layout", layout_to_msg(layout, ros_io.ns_to_stamp(t0_ns)), t0_ns)
        for k, (believed, C) in enumerate(zip(cameras, corrections)):
            t_ns = t0_ns + (k + 1) * 500_000_000
            true = believed.with_pose(C[:3, :3] @ believed.R_wc, C[:3, :3] @ believed.position_w + C[:3, 3])
            view = render(scene, true, seed=k, depth_noise_m=NOISE_M, hole_fraction=HOLES)
            shot = shot_messages(view, "16UC1", ros_io.ns_to_stamp(t_ns), pose_camera=believed)
            for key, (topic, _type) in topics.items():
                bag.write(topic, shot[key], t_ns)
            entry = {"view": k, "camera_xyz_m": list(map(float, believed.position_w)),
                     "visible": [sid for sid, vis in zip(scene.stud_ids, view.stud_visible) if vis]}
            if carriages_m is not None:
                entry.update(stamp_ns=t_ns, carriage_m=carriages_m[k], true_world_correction=C.tolist())
            truth_views.append(entry)
    order = {sid: i for i, sid in enumerate(scene.stud_ids)}
    exact = render(scene, camera_at(cameras[0].position_w))  # stud truth does not depend on the view
    truth = {
        "drawing": _rel(drawing), "scene": _rel(scene_file), "M_local2world": scene.M_local2world.tolist(),
        "depth_noise_m": NOISE_M,
        "hole_fraction": HOLES, "views": truth_views,
        "studs": [{"stud_id": s.id, "position_m": exact.studs_world_m[order[s.id]].tolist(),
                   "normal": exact.stud_normals_w[order[s.id]].tolist()} for s in layout.studs],
    }
    write_json(out / "ground_truth.json", truth)
    return truth


def _rel(path: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(REPO))
    except ValueError:
        return str(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--part", choices=["dome", "girder"], default="dome")
    ap.add_argument("--out", type=Path, help="the bag to write (default: bags/dome_demo; the girder's has none)")
    ap.add_argument("--stations", type=int, nargs="+", help="girder: the camera stations to shoot (default: all)")
    args = ap.parse_args()
    if args.part == "dome":
        out = args.out or REPO / "bags" / "dome_demo"
        cameras = [camera_at(xyz) for xyz in station_cameras(load_scene(SCENE), vars(JobConfig()))]
        truth = write_sensor_bag(out, SCENE, DRAWING, cameras)
    else:
        if args.out is None:
            ap.error("--part girder needs --out (the girder's bag is not committed)")
        out = args.out
        truth = record_girder(out, args.stations)
    size = sum(f.stat().st_size for f in out.iterdir())
    print(f"wrote {out} ({len(truth['views'])} views, {size / 1e6:.1f} MB)")
    return 0


def record_girder(out: Path, stations: list[int] | None = None) -> dict:
    """The bundled girder's views from the arm on its rail (the module docstring); ``stations``: which of
    the cell's camera stations (indices; default all), after the registration view."""
    from stud_bringup.demo_parts import PARTS

    part = PARTS["girder"]
    scene_file = REPO / "src" / "stud_perception" / part.scene
    scene = load_scene(scene_file)
    settings = {**vars(JobConfig()), **{k: v for k, v in part.cell_vars.items() if k in vars(JobConfig())}}
    xyz = station_cameras(scene, settings, plane_z_m=scene.board.thickness_m)
    picked = [xyz[0]] + [xyz[1 + i] for i in (range(len(xyz) - 1) if stations is None else stations)]
    deviation = RailDeviation(part.sim_vars["true_rail_scale_ppm"], part.sim_vars["true_rail_offset_m"],
                              part.sim_vars["true_rail_yaw_urad_per_m"])
    carriages = [float(np.clip(p[0] - part.mount_xyz_m[0], 0.0, part.rail_length_m)) for p in picked]
    truth = write_sensor_bag(out, scene_file, REPO / "src" / "stud_planner" / part.drawing,
                             [camera_at(p) for p in picked], [true_world_correction(c, deviation) for c in carriages],
                             carriages)
    truth["rail_deviation"] = {"scale_ppm": deviation.scale_ppm, "offset_m": deviation.offset_m,
                               "yaw_urad_per_m": deviation.yaw_urad_per_m}
    write_json(out / "ground_truth.json", truth)
    return truth


def ros_io_topics() -> dict[str, tuple[str, str]]:
    return {"color": ("/camera/color/image_raw", "sensor_msgs/msg/Image"),
            "depth": ("/camera/depth/image_raw", "sensor_msgs/msg/Image"),
            "info": ("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo"),
            "pose": ("/camera/pose", "geometry_msgs/msg/PoseStamped")}


if __name__ == "__main__":
    sys.exit(main())
