"""Offline planning: `ros2 run stud_planner plan --drawing D.dxf --bag B [--out report.json] ...`.

Reads a rosbag2 MCAP sensor bag (colour, depth, camera info and /camera/pose, topic names
overridable), groups the messages into views by stamp, registers the drawing on the first
view where the marks are found, matches every stud on every view, keeps for each stud its best
view (matching/target_table.choose_best, the cell's rule too: the usable target with the smallest
lean bound), and writes the JSON report of docs/INTERFACES.md (one entry per drawing stud, in
drawing order), optionally overlay PNGs and a CSV. Errors are one line on stderr and exit code 2.

A drawing with reference marks (M1, M2, ... beside O, A, B: a long part, welded along a rail)
registers *every* view on the marks it sees, as the registration node does
(stud_perception.mark_registration.RegistrationTrail, in the bag's order: the first view needs O,
A, B, each later one names its marks by the nearest registration made before it, and a view with
too few marks takes the nearest registration, saying how far it extrapolates), and matches each
view with its own registration: the rail's error between two stations never reaches a target.
The report then lists every view's registration (``registrations``) besides the first
(``registration``). ``view_stamps_ns`` gives each view's stamp (a target's ``view`` indexes it).

Memory stays flat with the bag's length: a first pass keeps only stamps of the images (read from
their CDR headers) and the small camera-info and pose messages; a second pass deserialises each
view's images while it is processed (views before the registration view take a third).
300 views of 1280x960: 154 MB peak RSS instead of 1.96 GB when every view was held.
"""
from __future__ import annotations

import argparse
import csv
import math
import struct
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from stud_common import names, ros_io
from stud_common.strict_json import write_json
from stud_perception import image_io
from stud_perception.mark_registration import MarkFitConfig, RegistrationTrail
from stud_perception.markers import MarkDetectorConfig
from stud_perception.registration import MarkRegistration
from stud_perception.view_registration import config_for_layout, register_view
from stud_planner.drawing import DrawingError, DrawingLimits, read_layout
from stud_planner.drawing.limits import add_limit_arguments, cli_hint, limits_from_args
from stud_planner.matching.gun_clearance import GunModel
from stud_planner.matching.target_table import TargetTable
from stud_planner.matching.view_targets import ALGORITHMS, PlannerConfig, draw_targets_overlay, plan_view

DEFAULT_TOPICS = {"color": names.COLOR_IMAGE, "depth": names.DEPTH_IMAGE,
                  "info": names.CAMERA_INFO, "pose": names.CAMERA_POSE}


class PlanError(Exception):
    """A bag, drawing or option the planner cannot use; one line for the user."""


@dataclass
class View:
    """One view of a bag: the depth stamp, camera info and pose (small, kept), and the stamps of its
    colour and depth images, which are only deserialised while the view is processed
    (:func:`views_with_images`): a long bag must not sit in memory as images."""

    index: int
    stamp_ns: int
    info: Any             # sensor_msgs/CameraInfo
    pose: Any             # geometry_msgs/PoseStamped
    color_stamp_ns: int
    depth_stamp_ns: int
    color: Any = None     # sensor_msgs/Image, while the view is processed
    depth: Any = None


TOPIC_TYPES = {"color": "sensor_msgs/msg/Image", "depth": "sensor_msgs/msg/Image",
               "info": "sensor_msgs/msg/CameraInfo", "pose": "geometry_msgs/msg/PoseStamped"}
#: Default stamp tolerance between the four topics of one view. INTERFACES.md asks for one stamp per
#: shot, and our camera and the committed bags do that; a real driver stamps colour, depth and the
#: arm pose from separate clocks/threads, a few ms apart even when hardware-triggered. 5 ms absorbs
#: that while staying far below a frame period (33 ms at 30 fps), so two frames never merge.
DEFAULT_SYNC_SLOP_MS = 5.0


IMAGE_ROLES = ("color", "depth")


def _cdr_stamp_ns(data: bytes) -> int | None:
    """header.stamp of a CDR-serialised message that starts with a std_msgs/Header (Image does),
    read without deserialising the pixels; None for an encapsulation this does not know."""
    if len(data) < 12 or data[0] != 0 or data[1] not in (0, 1, 6, 7):  # (PLAIN_)CDR(2), BE or LE
        return None
    order = "<" if data[1] & 1 else ">"
    sec, nanosec = struct.unpack_from(order + "iI", data, 4)
    return sec * 1_000_000_000 + nanosec


def _bag_damage(reader, messages_missing: str) -> list[str]:
    """The reader's notes that mean messages are missing: a file cut short, or fewer messages than
    metadata.yaml lists (``messages_missing`` starts that note). Other disagreements with
    metadata.yaml -- times, which real rosbag2 bags often get wrong -- and a bag directory without
    metadata.yaml are not damage."""
    return [n for n in reader.notes if "ends in the middle of a record" in n or n.startswith(messages_missing)]


def _group_views(stamped: dict[str, list[tuple[int, object]]], slop_ns: int) -> list[dict]:
    """Views from all messages of a bag: each depth message with, per other topic, the message whose
    stamp is nearest to it within ``slop_ns``. Offline every message is at hand, so unlike
    ``ros_io.StampSync`` (live: a newer complete set evicts older incomplete ones) nothing is dropped
    because of the order the messages were logged in. Returns dicts name -> msg, in depth stamp order."""
    others = {name: sorted(items, key=lambda x: x[0]) for name, items in stamped.items() if name != "depth"}
    keys = {name: np.array([t for t, _ in items], dtype=np.int64) for name, items in others.items()}
    views = []
    for stamp, depth in sorted(stamped["depth"], key=lambda x: x[0]):
        view = {"depth": depth}
        for name, items in others.items():
            if not len(items):
                break
            gaps = np.abs(keys[name] - stamp)
            j = int(np.argmin(gaps))
            if gaps[j] > slop_ns:
                break
            view[name] = items[j][1]
        else:
            views.append(view)
    return views


def _nearest_gaps(stamped: dict[str, list[tuple[int, object]]]) -> str:
    depth = np.array(sorted(t for t, _ in stamped["depth"]), dtype=np.int64)
    parts = []
    for name, items in stamped.items():
        text = f"{name} {len(items)} messages"
        if name != "depth" and len(items) and len(depth):
            gap = min(int(np.abs(depth - t).min()) for t, _ in items)
            text += f", smallest stamp gap to depth {gap / 1e6:.3f} ms"
        parts.append(text)
    return "; ".join(parts)


def read_views(bag_path: Path, topics: dict[str, str], sync_slop_ms: float = DEFAULT_SYNC_SLOP_MS,
               warnings: list[str] | None = None, allow_damaged: bool = False) -> list[View]:
    """All complete views (the four topics with stamps within ``sync_slop_ms`` of the depth stamp)
    of a bag, in stamp order. A damaged bag (cut short, or holding fewer messages than its
    metadata.yaml lists) is a PlanError, unless ``allow_damaged``: then it is a line in ``warnings``."""
    warnings = [] if warnings is None else warnings
    if not np.isfinite(sync_slop_ms) or sync_slop_ms < 0:
        raise PlanError(f"--sync-slop-ms {sync_slop_ms}: expected a finite number of ms >= 0")
    slop_ns = int(round(sync_slop_ms * 1e6))
    roles: dict[str, list[str]] = {}
    for name, topic in topics.items():
        roles.setdefault(topic, []).append(name)
    dup = {t: names for t, names in roles.items() if len(names) > 1}
    if dup:
        raise PlanError("; ".join(f"topic {t} is given for {' and '.join(names)}" for t, names in dup.items())
                        + ": each of --color-topic/--depth-topic/--info-topic/--pose-topic needs its own topic")
    from stud_bag import MESSAGES_MISSING, BagError, open_bag
    try:
        reader = open_bag(bag_path)
    except BagError as exc:
        raise PlanError(str(exc)) from None
    try:
        damage = _bag_damage(reader, MESSAGES_MISSING)
        missing = [t for t in topics.values() if t not in reader.topics]
        if missing:
            have = ", ".join(f"{n} ({s.type}, {s.message_count})" for n, s in reader.topics.items()) or "none"
            why = f" (the bag is damaged, so they may have been cut off: {'; '.join(damage)})" if damage else ""
            raise PlanError(f"{bag_path}: topic(s) {', '.join(missing)} not in the bag{why}; it has: {have} "
                            "(override names with --color-topic/--depth-topic/--info-topic/--pose-topic)")
        if damage:
            if not allow_damaged:
                raise PlanError(f"{bag_path}: damaged bag: {'; '.join(damage)} (views would be missing; "
                                "--allow-damaged-bag plans with what can be read)")
            warnings.extend(f"{bag_path}: damaged bag, planned with what could be read: {d}" for d in damage)
        for name, topic in topics.items():
            found = reader.topics[topic].type
            if found != TOPIC_TYPES[name]:
                raise PlanError(f"{bag_path}: topic {topic} is {found or 'of unknown type'}, expected "
                                f"{TOPIC_TYPES[name]} (--{name}-topic)")
        # Images: only their stamps now (read from the CDR header); the small messages whole.
        stamped: dict[str, list[tuple[int, object]]] = {name: [] for name in topics}
        by_topic = {t: name for name, t in topics.items()}
        index = {t: 0 for t in topics.values()}
        for item in reader.messages(list(topics.values())):
            name = by_topic[item.topic]
            stamp, msg = _stamp(item, index[item.topic], bag_path, header_only=name in IMAGE_ROLES)
            index[item.topic] += 1
            stamped[name].append((stamp, stamp if name in IMAGE_ROLES else msg))
    except BagError as exc:
        raise PlanError(str(exc)) from None
    finally:
        reader.close()
    views = _group_views(stamped, slop_ns)
    if not views:
        raise PlanError(f"{bag_path}: no complete view (colour, depth, camera info and pose with stamps within "
                        f"{slop_ns / 1e6:g} ms of a depth stamp; --sync-slop-ms sets it): {_nearest_gaps(stamped)}")
    return [View(i, v["depth"], v["info"], v["pose"], v["color"], v["depth"]) for i, v in enumerate(views)]


def _stamp(item, index: int, bag_path: Path, header_only: bool) -> tuple[int, object]:
    """(header stamp in ns, the message or None): with ``header_only`` the stamp is read from the
    CDR header, without deserialising the message (an image's pixels), where the encoding allows."""
    stamp = _cdr_stamp_ns(item.data) if header_only else None
    if stamp is not None:
        return stamp, None
    msg = _deserialise(item, index, bag_path)
    return ros_io.stamp_to_ns(msg.header.stamp), msg


def _deserialise(item, index: int, bag_path: Path):
    try:
        return item.message()
    except Exception as exc:  # rclpy's RMWError / LookupError: a payload the type does not fit
        raise PlanError(f"{bag_path}: topic {item.topic} message index {index} (log time {item.log_time_ns} ns) "
                        f"cannot be deserialised as {item.type_name}: {' '.join(str(exc).split())}") from None


def views_with_images(bag_path: Path, topics: dict[str, str], views: list[View]):
    """Yield ``views`` with their colour and depth images filled in, in the order the bag logged
    them, one pass over the bag: only a view's own images are deserialised, and a view is released
    once yielded, so memory stays at a few views whatever the bag's length."""
    from stud_bag import BagError, open_bag

    want: dict[tuple[str, int], list[View]] = {}  # two views may share an image (nearest within the slop)
    for v in views:
        for name in IMAGE_ROLES:
            want.setdefault((name, getattr(v, f"{name}_stamp_ns")), []).append(v)
    got: dict[int, dict[str, Any]] = {}
    by_topic = {topics[name]: name for name in IMAGE_ROLES}
    count = {t: 0 for t in by_topic}
    try:
        with open_bag(bag_path) as reader:
            for item in reader.messages(list(by_topic)):
                name = by_topic[item.topic]
                stamp, msg = _stamp(item, count[item.topic], bag_path, header_only=True)
                owners = want.pop((name, stamp), [])
                if owners and msg is None:
                    msg = _deserialise(item, count[item.topic], bag_path)
                count[item.topic] += 1
                for view in owners:
                    parts = got.setdefault(view.index, {})
                    parts[name] = msg
                    if len(parts) == len(IMAGE_ROLES):
                        del got[view.index]
                        yield replace(view, **parts)
    except BagError as exc:
        raise PlanError(str(exc)) from None


def _decode(view: View, bag: Path, images_rectified: bool, topics: dict[str, str]):
    """The view's pinhole camera and images (raw images with lens distortion rectified onto it),
    checked by :func:`image_io.decode_view`."""
    try:
        decoded = image_io.decode_view(view.info, view.pose.pose, view.depth, view.color, images_rectified, topics)
    except (ros_io.MessageError, ValueError) as exc:
        raise PlanError(f"{bag}: view {view.index} (depth stamp {view.stamp_ns} ns): {exc}") from None
    return decoded.camera, decoded.color_bgr, decoded.depth_m


def _progress(i: int, n: int, quiet: bool, what: str) -> None:
    if quiet or not sys.stderr.isatty():
        return
    width = 30
    done = int(width * i / max(n, 1))
    sys.stderr.write(f"\r{what} [{'#' * done}{'.' * (width - done)}] {i}/{n}")
    if i == n:
        sys.stderr.write("\n")
    sys.stderr.flush()


def plan(drawing: Path, bag: Path, algorithm: str = "batch", topics: dict[str, str] | None = None,
         overlay_dir: Path | None = None, quiet: bool = True, config: PlannerConfig | None = None,
         sync_slop_ms: float = DEFAULT_SYNC_SLOP_MS, allow_damaged: bool = False,
         images_rectified: bool = False, drawing_limits: DrawingLimits | None = None) -> dict:
    """Run the offline planning and return the report (see the module docstring). ``report["warnings"]``
    lists what the user must know about the result (a damaged bag read anyway, drawing circles left
    out for non-finite or out-of-range values). Raw images with lens distortion are rectified; ``images_rectified``:
    they were already (see :func:`image_io.camera_model_from_msgs`). ``drawing_limits``: the drawing's work budget
    (a drawing beyond it is a PlanError naming the block, its level and the count, before the bag is read)."""
    topics = topics or DEFAULT_TOPICS
    try:
        layout = read_layout(drawing, limits=drawing_limits)
    except DrawingError as exc:
        raise PlanError(str(exc) + cli_hint(exc)) from None
    config = config or PlannerConfig(algorithm=algorithm)
    warnings: list[str] = []
    if layout.invalid_entities:  # not studs of the report: the user must hear of them here
        bad = layout.invalid_entities
        warnings.append(f"{drawing}: {len(bad)} circle{'s' if len(bad) != 1 else ''} with non-finite or out-of-range "
                        f"values left out, not planned: " + "; ".join(bad[:5])
                        + (f"; ... (+{len(bad) - 5})" if len(bad) > 5 else ""))
    views = read_views(bag, topics, sync_slop_ms, warnings, allow_damaged)
    marks = layout.marks_xy_m()
    det_config = config_for_layout(MarkDetectorConfig(), layout.mark_diameter_m)

    ids = [s.id for s in layout.studs]
    xy = layout.studs_xy_m()
    chosen = TargetTable.unseen(ids, xy)
    totals = {"iterations": 0, "views": 0}
    match_time = 0.0

    def match_view(v: View, camera, color, depth, registration: MarkRegistration) -> None:
        nonlocal match_time, chosen
        _progress(totals["views"], len(views), quiet, "matching")
        t = plan_view(ids, xy, registration.M_local2world, depth, camera, config, view_index=v.index)
        totals["iterations"] += t.matches.total_iterations
        match_time += t.match_time_s
        totals["views"] += 1
        if overlay_dir is not None:
            import cv2

            overlay_dir.mkdir(parents=True, exist_ok=True)
            cv2.imwrite(str(overlay_dir / f"view_{v.index:03d}.png"), draw_targets_overlay(color, t, camera))
        chosen = chosen.merge(t)

    references = layout.reference_marks_xy_m()
    if references:
        registrations = _register_every_view(bag, topics, views, images_rectified, marks, references, det_config,
                                             match_view, warnings)
        first = min(registrations)
        registration, reg_view = registrations[first], first
    else:
        registration, reg_view = _register_once(drawing, bag, topics, views, images_rectified, marks, det_config,
                                                match_view)
        registrations = {}
        if totals["views"] != len(views):
            raise PlanError(f"{bag}: {len(views) - totals['views']} of {len(views)} views lost their images between "
                            "two reads of the bag (was it written to meanwhile?)")
    iterations_total = totals["iterations"]
    _progress(len(views), len(views), quiet, "matching")
    targets = chosen.report_entries()
    report = {
        "drawing": str(drawing), "bag": str(bag), "algorithm": config.algorithm,
        "registration": {"M_local2world": registration.M_local2world.tolist(),
                         "residual_mm": registration.residual_m * 1e3, "view": reg_view},
        "views": len(views), "total_iterations": int(iterations_total), "match_time_s": match_time,
        "targets": targets, "warnings": warnings, "view_stamps_ns": [v.stamp_ns for v in views],
    }
    if references:
        report["registrations"] = [_registration_entry(i, views[i].stamp_ns, r)
                                   for i, r in sorted(registrations.items())]
    return report


def _register_once(drawing: Path, bag: Path, topics: dict[str, str], views: list[View], images_rectified: bool,
                   marks: np.ndarray, det_config: MarkDetectorConfig, match_view) -> tuple[MarkRegistration, int]:
    """A drawing with O, A, B only: register on the first view (in logged order) where the marks are
    found, match it and every later view, then the views before it (a second pass over the bag)."""
    registration, reg_view, reasons, before = None, -1, [], []
    for v in views_with_images(bag, topics, views):
        camera, color, depth = _decode(v, bag, images_rectified, topics)
        if registration is None:
            result = register_view(color, depth, camera, marks, det_config)
            if not result.ok:
                reasons.append(f"view {v.index}: {result.message}")
                before.append(replace(v, color=None, depth=None))  # its images are read again
                continue
            registration, reg_view = result.registration, v.index
        match_view(v, camera, color, depth, registration)
    if registration is None:
        raise PlanError(f"the marks O, A, B of {drawing} were found on none of the {len(views)} views of {bag} "
                        f"(drawing and bag do not match?): " + "; ".join(reasons[:3]))
    for v in views_with_images(bag, topics, before):
        match_view(v, *_decode(v, bag, images_rectified, topics), registration)
    return registration, reg_view


def _register_every_view(bag: Path, topics: dict[str, str], views: list[View], images_rectified: bool,
                         marks: np.ndarray, references: dict, det_config: MarkDetectorConfig, match_view,
                         warnings: list[str]) -> dict[int, MarkRegistration]:
    """A drawing with reference marks: every view registered on the marks it sees, in the bag's order
    (:class:`RegistrationTrail`, as the registration node), and matched with its own registration. Views
    before the first registration (no prior to name their marks by) are registered in a second pass; a
    view that cannot be registered at all is left out, with a warning. Returns view index -> registration."""
    trail = RegistrationTrail()
    all_marks = {**dict(zip(("O", "A", "B"), marks)), **references}
    fit = MarkFitConfig()
    done: dict[int, MarkRegistration] = {}
    failed: dict[int, str] = {}
    before: list[View] = []

    def register(v: View, camera, color, depth) -> bool:
        result = trail.register(color, depth, camera, all_marks, det_config, fit)
        if not result.ok or result.registration is None:
            failed[v.index] = result.message
            return False
        failed.pop(v.index, None)
        done[v.index] = result.registration
        match_view(v, camera, color, depth, result.registration)
        return True

    for v in views_with_images(bag, topics, views):
        camera, color, depth = _decode(v, bag, images_rectified, topics)
        if not register(v, camera, color, depth) and not trail.stations:
            before.append(replace(v, color=None, depth=None))  # no prior yet: again once one is known
    if not done:
        raise PlanError(f"no view of {bag} could be registered on the drawing's marks (the first needs O, A, B): "
                        + "; ".join(f"view {i}: {why}" for i, why in list(failed.items())[:3]))
    for v in views_with_images(bag, topics, before):
        register(v, *_decode(v, bag, images_rectified, topics))
    for i, why in sorted(failed.items()):
        warnings.append(f"{bag}: view {i} could not be registered and was not matched: {why}")
    return done


def _registration_entry(view: int, stamp_ns: int, r: MarkRegistration) -> dict:
    """A view's registration in the report: the marks used, the residuals (mm), how far it extrapolates (m)."""
    return {"view": view, "stamp_ns": int(stamp_ns), "M_local2world": r.M_local2world.tolist(),
            "marks": list(r.labels_used), "residual_mm": r.residual_m * 1e3,
            "residual_max_mm": r.residual_max_m * 1e3 if math.isfinite(r.residual_max_m) else None,
            "extrapolated_m": r.extrapolated_m}


def write_csv(report: dict, path: Path) -> None:
    """The report's targets as CSV at ``path``, a row per stud: status, world position [m], unit normal,
    inclination [deg], XY error [mm], view."""
    fields = ["stud_id", "status", "x_m", "y_m", "z_m", "nx", "ny", "nz", "inclination_deg", "xy_error_mm", "view"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(fields)
        for t in report["targets"]:
            p = t.get("position_m") or [None] * 3
            n = t.get("normal") or [None] * 3
            w.writerow([t["stud_id"], t["status"], *p, *n, t.get("inclination_deg"), t.get("xy_error_mm"),
                        t.get("view")])


def main(argv: list[str] | None = None) -> int:
    """`ros2 run stud_planner plan`: plan a drawing on a recorded bag; 0 done, 2 on an error (one line)."""
    parser = argparse.ArgumentParser(prog="plan", description="Weld targets for a drawing from a recorded sensor bag.")
    parser.add_argument("--drawing", required=True, type=Path, help="DXF drawing with studs and marks O, A, B")
    parser.add_argument("--bag", required=True, type=Path, help="rosbag2 MCAP bag (folder or .mcap)")
    parser.add_argument("--out", type=Path, help="JSON report (default: print a summary only)")
    parser.add_argument("--csv", type=Path, help="also write the targets as CSV")
    parser.add_argument("--overlay-dir", type=Path, help="write an overlay PNG per view here")
    parser.add_argument("--algorithm", choices=ALGORITHMS, default="batch")
    for name, default in DEFAULT_TOPICS.items():
        parser.add_argument(f"--{name}-topic", default=default)
    parser.add_argument("--sync-slop-ms", type=float, default=DEFAULT_SYNC_SLOP_MS,
                        help="colour, camera info and pose stamps within this of a depth stamp form one view "
                             f"(default {DEFAULT_SYNC_SLOP_MS:g}: real drivers stamp streams a few ms apart)")
    parser.add_argument("--allow-damaged-bag", action="store_true",
                        help="plan with what a truncated/damaged bag still holds (a warning) instead of an error")
    parser.add_argument("--images-rectified", action="store_true",
                        help="the bag's images are rectified already (image_rect): use camera_info P, ignore D "
                             "(default: raw images, rectified here when camera_info has distortion)")
    defaults, gun = PlannerConfig(), GunModel()
    parser.add_argument("--lean-budget-deg", type=float, default=defaults.lean_budget_deg,
                        help="the most a welded stud may lean from the true normal (default: the code's "
                             f"{defaults.lean_budget_deg:g} deg); a target whose normal is too uncertain for it "
                             "is normal_uncertain. The surface's slope never refuses a stud")
    parser.add_argument("--normal-window-m", type=float, default=defaults.normal_window_m,
                        help="side of the surface patch each stud's normal is fitted on [m] (the matcher node's "
                             f"normal_window_m, cell.yaml's var; default {defaults.normal_window_m:g})")
    parser.add_argument("--arm-orientation-error-deg", type=float, default=defaults.arm_orientation_error_deg,
                        help="the arm's share of the lean budget [deg]")
    parser.add_argument("--gun-radius-m", type=float, default=gun.radius_m,
                        help="the welding gun's radius about the stud, for the clearance check [m]")
    parser.add_argument("--gun-length-m", type=float, default=gun.length_m,
                        help="surface to the gun's top at the approach pose, for the clearance check [m]")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    add_limit_arguments(parser)
    from rclpy.utilities import remove_ros_args

    # `ros2 run` may append --ros-args ...: drop only those, so a misspelt option is a usage error
    args = parser.parse_args(remove_ros_args(sys.argv[1:] if argv is None else list(argv)))
    topics = {name: getattr(args, f"{name}_topic") for name in DEFAULT_TOPICS}
    t0 = time.perf_counter()
    try:
        config = PlannerConfig(algorithm=args.algorithm, lean_budget_deg=args.lean_budget_deg,
                               normal_window_m=args.normal_window_m,
                               arm_orientation_error_deg=args.arm_orientation_error_deg,
                               gun=GunModel(radius_m=args.gun_radius_m, length_m=args.gun_length_m))
        drawing_limits = limits_from_args(args)
    except ValueError as exc:
        print(f"plan: error: {exc}", file=sys.stderr)
        return 2
    try:
        report = plan(args.drawing, args.bag, args.algorithm, topics, args.overlay_dir, args.quiet, config=config,
                      sync_slop_ms=args.sync_slop_ms, allow_damaged=args.allow_damaged_bag,
                      images_rectified=args.images_rectified, drawing_limits=drawing_limits)
        for warning in report["warnings"]:
            print(f"plan: warning: {warning}", file=sys.stderr)
        if args.out:
            write_json(args.out, report)  # strict JSON: a missing value is null, never NaN
        if args.csv:
            write_csv(report, args.csv)
    except PlanError as exc:
        print(f"plan: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"plan: error: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # anything else thrown at the boundary: still one line, never a traceback
        print(f"plan: error: unexpected {type(exc).__name__}: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    counts: dict[str, int] = {}
    for t in report["targets"]:
        counts[t["status"]] = counts.get(t["status"], 0) + 1
    if not args.quiet:
        print(f"{len(report['targets'])} studs over {report['views']} views ({report['algorithm']}): "
              + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()))
              + (f"; {len(report['registrations'])} views registered on their own marks, residual up to "
                 f"{max(r['residual_mm'] for r in report['registrations']):.2f} mm RMS; " if "registrations" in report
                 else f"; registration residual {report['registration']['residual_mm']:.2f} mm; ")
              + f"{time.perf_counter() - t0:.1f} s" + (f"; report {args.out}" if args.out else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
