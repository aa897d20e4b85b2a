#!/usr/bin/env python3
"""Re-record bags/dome_demo: the sim camera's shots of the demo dome, with ground truth.

Views: the registration station over the marking board, then the camera stations the cell
sequencer plans for the drawing (station_planning with the sequencer's defaults), each one
shot as the camera node publishes it (stud_perception.camera_node.shot_messages: bgr8,
16UC1 mm depth with 0.5 mm noise and 1 % holes, camera info, /camera/pose), 0.5 s apart,
plus the latched /drawing/layout. Written with the same rosbag2 MCAP writer `ros2 bag record`
uses (zstd chunks). Next to it, ground_truth.json: the exact weld point and normal of every
stud, the true M_local2world and the camera poses.
Run: source ros2_ws/setup.bash && python tools/record_demo_bag.py [--out bags/dome_demo]
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for pkg in ("stud_common", "stud_perception", "stud_planner", "stud_inspection", "stud_cell"):
    sys.path.insert(0, str(REPO / "src" / pkg))

import numpy as np  # noqa: E402
from stud_bag import BagWriter, Qos  # noqa: E402
from stud_common import ros_io  # noqa: E402
from stud_perception.camera_model import nadir_rotation  # noqa: E402
from stud_perception.camera_node import shot_messages  # noqa: E402
from stud_perception.scene_cameras import view_camera  # noqa: E402
from stud_perception.scene_file import load_scene  # noqa: E402
from stud_perception.scene_render import render  # noqa: E402
from stud_common.strict_json import write_json  # noqa: E402
from stud_cell.job import JobConfig  # noqa: E402
from stud_planner.drawing import read_layout  # noqa: E402
from stud_planner.msg_convert import layout_to_msg  # noqa: E402
from stud_cell.stations import footprint_m, plan_stations  # noqa: E402

DRAWING = REPO / "src" / "stud_planner" / "data" / "dome_demo.dxf"
SCENE = REPO / "src" / "stud_perception" / "config" / "dome_scene.json"
T0_NS = 1_790_000_000_000_000_000  # fixed start time: the bag is byte-for-byte reproducible
NOISE_M, HOLES = 0.0005, 0.01


def camera_at(xyz) -> "CameraModel":  # noqa: F821
    template = view_camera((0.0, 0.0, 0.0), distance_m=1.0)
    return template.with_pose(nadir_rotation(0.0), np.asarray(xyz, dtype=float))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=REPO / "bags" / "dome_demo")
    args = ap.parse_args()
    scene, layout = load_scene(SCENE), read_layout(DRAWING)
    seq = vars(JobConfig())  # the cell job's defaults: the stations the cell will use
    studs_w = scene.studs_world_xy_m
    fov = footprint_m(seq["fov_width_m"], seq["fov_distance_m"], seq["image_aspect"], seq["camera_height_m"],
                      seq["part_height_m"])
    plan = plan_stations(studs_w, fov, seq["camera_height_m"], overlap=seq["overlap"])
    stations = [tuple(seq["registration_station_xyz_m"])] + [s.camera_xyz_w for s in plan.stations]

    if args.out.exists():
        shutil.rmtree(args.out)
    topics = ros_io_topics()
    with BagWriter(args.out) as bag:
        bag.add_topic("/drawing/layout", "stud_welding_msgs/msg/StudLayout",
                      offered_qos_profiles=[Qos(durability="transient_local", depth=1)])
        for name, type_name in topics.values():
            bag.add_topic(name, type_name)
        bag.write("/drawing/layout", layout_to_msg(layout, ros_io.ns_to_stamp(T0_NS)), T0_NS)
        truth_views = []
        for k, xyz in enumerate(stations):
            t_ns = T0_NS + (k + 1) * 500_000_000
            view = render(scene, camera_at(xyz), seed=k, depth_noise_m=NOISE_M, hole_fraction=HOLES)
            shot = shot_messages(view, "16UC1", ros_io.ns_to_stamp(t_ns))
            for key, (topic, _type) in topics.items():
                bag.write(topic, shot[key], t_ns)
            truth_views.append({"view": k, "camera_xyz_m": list(map(float, xyz)),
                                "visible": [sid for sid, vis in zip(scene.stud_ids, view.stud_visible) if vis]})
    order = {sid: i for i, sid in enumerate(scene.stud_ids)}
    exact = render(scene, camera_at(stations[0]))  # stud truth does not depend on the view
    truth = {
        "drawing": str(DRAWING.relative_to(REPO)), "scene": str(SCENE.relative_to(REPO)),
        "M_local2world": scene.M_local2world.tolist(), "depth_noise_m": NOISE_M, "hole_fraction": HOLES,
        "views": truth_views,
        "studs": [{"stud_id": s.id, "position_m": exact.studs_world_m[order[s.id]].tolist(),
                   "normal": exact.stud_normals_w[order[s.id]].tolist()} for s in layout.studs],
    }
    write_json(args.out / "ground_truth.json", truth)
    size = sum(f.stat().st_size for f in args.out.iterdir())
    print(f"wrote {args.out} ({len(stations)} views, {size / 1e6:.1f} MB)")
    return 0


def ros_io_topics() -> dict[str, tuple[str, str]]:
    return {"color": ("/camera/color/image_raw", "sensor_msgs/msg/Image"),
            "depth": ("/camera/depth/image_raw", "sensor_msgs/msg/Image"),
            "info": ("/camera/color/camera_info", "sensor_msgs/msg/CameraInfo"),
            "pose": ("/camera/pose", "geometry_msgs/msg/PoseStamped")}


if __name__ == "__main__":
    sys.exit(main())
