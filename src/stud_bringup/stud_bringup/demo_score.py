"""The demo's judgement of a simulated job against the scene's exact truth (pure; the cell bag read with stud_bag).

* :func:`welds_from_journal` -- where the gun truly was at each weld: forward kinematics of the joints the
  controller reported at the contact pose (the weld journal's ``started`` record), the arm's base where the
  carriage truly stood (:func:`stud_common.frames.world_T_base` with the rail's sim-only
  :class:`~stud_common.frames.RailDeviation`; the identity without a rail). On a rail the cell's own
  ``world`` is the believed, straight rail: a target it computes there is not where the studs truly are,
  the gun is.
* :func:`score` -- per stud, the weld point (the true gun tip backed off the plunge along the gun's axis;
  the cell's target when no weld was journalled) and the gun's axis against the true stud position and
  normal; :func:`accuracy_at_ends` the same at both ends of a long part.
* :func:`registrations` (``/registration/result``, with the carriage from ``/arm/state``),
  :func:`rail_moves` (``/arm/state``) and :func:`job_span_s` (``/cell/status``) from the cell's bag.

Frames: ``world`` (m); on a rail the rail's frame (docs/FRAMES.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
from numpy.typing import ArrayLike

from stud_common import names
from stud_common.frames import RailDeviation, world_T_base
from stud_perception.scene import surface_height, surface_normal
from stud_perception.scene_file import load_scene


@dataclass(frozen=True, eq=False)
class WeldPose:
    """The gun at one weld, in the true ``world``: ``tip_w`` (3,) m, ``axis_w`` (3,) unit, along the gun
    into the part; ``rail_position_m`` the carriage (the encoder's, m; 0 without a rail)."""

    stud_id: str
    tip_w: np.ndarray
    axis_w: np.ndarray
    rail_position_m: float = 0.0


def welds_from_journal(journal_file: Path, tool_offset_m: float = 0.15, mount_xyz_m: ArrayLike = (0.0, 0.0, 0.0),
                       deviation: RailDeviation = RailDeviation()) -> dict[str, WeldPose]:
    """Per welded stud of the journal (the last ``started`` record before its ``welded``), the gun's
    true pose at the weld: ``world_T_base(rail_position_m, mount_xyz_m, deviation) @ fk(joints_at_weld)``
    with the tool ``tool_offset_m`` along the flange's z. A record without ``rail_position_m`` (no rail)
    has its base at the carriage's 0."""
    from rm65_driver.journal.scan import read_records
    from rm65_driver.kinematics.rm65 import RM65Kinematics

    if not Path(journal_file).exists():
        return {}
    kin = RM65Kinematics()
    tool = np.eye(4)
    tool[2, 3] = float(tool_offset_m)
    started: dict[str, WeldPose] = {}
    welded: dict[str, WeldPose] = {}
    for rec in read_records(Path(journal_file)):
        sid = str(rec.get("stud"))
        if rec.get("event") == "started" and rec.get("joints_at_weld") is not None:
            c = float(rec.get("rail_position_m", 0.0))
            T = (world_T_base(c, mount_xyz_m, deviation)
                 @ kin.fk(np.asarray(rec["joints_at_weld"], dtype=np.float64)) @ tool)
            started[sid] = WeldPose(sid, T[:3, 3].copy(), T[:3, 2].copy(), c)
        elif rec.get("event") == "welded" and sid in started:
            welded[sid] = started[sid]
    return welded


def gun_axes_at_weld(journal_file: Path) -> dict[str, np.ndarray]:
    """Per welded stud, the gun's axis at the weld (unit, world, pointing into the part) of a fixed arm:
    forward kinematics of the joints the controller reported at the contact pose (the journal's
    ``started`` record); the gun lies along the flange's z axis, whatever its length."""
    return {sid: w.axis_w for sid, w in welds_from_journal(journal_file).items()}


def score(report: dict, scene_file: Path, gun_axes: dict[str, np.ndarray] | None = None,
          welds: dict[str, WeldPose] | None = None, plunge_m: float = 0.0) -> dict:
    """Per-stud errors against the scene truth (metres, degrees): the weld point -- from ``welds``
    (the true gun tip backed off ``plunge_m`` along its axis) when the stud has one, else the
    report's target -- against the true stud, the report's normal against the true normal, and the gun's
    axis (``welds``, else ``gun_axes``) against it. Rows carry the stud's true ``x_m`` along the rail."""
    scene = load_scene(scene_file)
    truth_xy = dict(zip(scene.stud_ids, scene.studs_world_xy_m))
    rows = []
    for t in report["targets"]:
        if t.get("position_m") is None or t["stud_id"] not in truth_xy:
            continue
        x, y = truth_xy[t["stud_id"]]
        true_p = np.array([x, y, float(surface_height(scene, np.array([x]), np.array([y]))[0])])
        true_n = np.asarray(surface_normal(scene, np.array([x]), np.array([y]))).reshape(-1, 3)[0]
        weld = (welds or {}).get(t["stud_id"])
        p = weld.tip_w - plunge_m * weld.axis_w if weld is not None else np.asarray(t["position_m"], float)
        n = np.asarray(t["normal"], float)
        row = {"stud_id": t["stud_id"], "x_m": float(x), "xy_error_m": float(np.linalg.norm(p[:2] - true_p[:2])),
               "z_error_m": float(abs(p[2] - true_p[2])), "from_weld": weld is not None,
               "normal_error_deg": float(np.degrees(np.arccos(np.clip(n @ true_n, -1, 1)))),
               "slope_deg": float(np.degrees(np.arccos(np.clip(true_n[2], -1, 1)))), "welded": bool(t.get("welded"))}
        axis = weld.axis_w if weld is not None else (gun_axes or {}).get(t["stud_id"])
        if axis is not None:
            row["gun_axis_error_deg"] = float(np.degrees(np.arccos(np.clip(-axis @ true_n, -1, 1))))
        rows.append(row)
    return {"studs": rows, **_maxima(rows)}


def _maxima(rows: Sequence[dict]) -> dict:
    welded = [r for r in rows if r["welded"]]
    gun = [r["gun_axis_error_deg"] for r in rows if "gun_axis_error_deg" in r]
    return {"steepest_welded_slope_deg": max((r["slope_deg"] for r in welded), default=float("nan")),
            "max_gun_axis_error_deg": max(gun, default=float("nan")), "gun_axes_checked": len(gun),
            "max_xy_error_mm": 1e3 * max((r["xy_error_m"] for r in rows), default=float("nan")),
            "mean_xy_error_mm": 1e3 * float(np.mean([r["xy_error_m"] for r in rows])) if rows else float("nan"),
            "max_z_error_mm": 1e3 * max((r["z_error_m"] for r in rows), default=float("nan")),
            "max_normal_error_deg": max((r["normal_error_deg"] for r in rows), default=float("nan"))}


def accuracy_at_ends(rows: Sequence[dict], span_m: float = 0.5) -> dict[str, dict]:
    """The maxima of :func:`score` over the studs within ``span_m`` (m, along world x: the rail) of each
    end of the part: ``{"start": {...}, "far_end": {...}}``, each with ``studs`` (how many) and
    ``x_m`` (the range of their x)."""
    if not rows:
        return {}
    xs = np.array([r["x_m"] for r in rows])
    out = {}
    for name, near in (("start", xs <= xs.min() + span_m), ("far_end", xs >= xs.max() - span_m)):
        sel = [r for r, k in zip(rows, near) if k]
        out[name] = {"studs": len(sel), "x_m": [float(xs[near].min()), float(xs[near].max())], **_maxima(sel)}
    return out


# -- the cell's bag ----------------------------------------------------------------------------------
def _stamp_s(header) -> float:
    return header.stamp.sec + 1e-9 * header.stamp.nanosec


def read_topics(bag_dir: Path, topics: Sequence[str]) -> dict[str, list]:
    """The messages of ``topics`` in a rosbag2 bag, in logged order, per topic ({} when no bag)."""
    from stud_bag import open_bag

    out: dict[str, list] = {t: [] for t in topics}
    if not (Path(bag_dir) / "metadata.yaml").exists() and not Path(bag_dir).is_file():
        return out
    with open_bag(Path(bag_dir)) as bag:
        present = [t for t in topics if t in bag.topics]
        for item in bag.messages(present):
            out[item.topic].append(item.message())
    return out


def registrations(results: Iterable, states: Iterable = ()) -> list[dict]:
    """One row per valid ``/registration/result`` (stud_welding_msgs/Registration): its time (s), the
    marks used, the RMS and largest residual (mm), how far it was extrapolated (m), and the carriage
    (``/arm/state`` ``rail_position_m`` of the last state at or before it; None without states)."""
    track = sorted(((_stamp_s(s.header), float(s.rail_position_m)) for s in states), key=lambda x: x[0])
    times = np.array([t for t, _ in track])
    rows = []
    for r in results:
        if not r.valid:
            continue
        t = _stamp_s(r.header)
        i = int(np.searchsorted(times, t, side="right")) - 1 if len(times) else -1
        rows.append({"t_s": t, "marks": list(r.labels_used), "residual_mm": 1e3 * float(r.residual),
                     "residual_max_mm": 1e3 * float(r.residual_max), "extrapolated_m": float(r.extrapolated_distance),
                     "carriage_m": track[i][1] if i >= 0 else None})
    return rows


def rail_moves(states: Iterable, tol_m: float = 0.001) -> dict:
    """The carriage's moves from ``/arm/state`` messages: each stop (a still carriage, ``rail_moving``
    false) more than ``tol_m`` from the previous one ends a move. ``moves``, ``distance_m`` (summed
    between stops), ``stops_m`` (the carriage at each stop, in order)."""
    stops: list[float] = []
    for s in sorted(states, key=lambda m: _stamp_s(m.header)):
        if s.rail_moving:
            continue
        p = float(s.rail_position_m)
        if not stops or abs(p - stops[-1]) > tol_m:
            stops.append(p)
    return {"moves": max(len(stops) - 1, 0), "distance_m": float(np.sum(np.abs(np.diff(stops)))) if stops else 0.0,
            "stops_m": stops}


def job_span_s(statuses: Iterable) -> float | None:
    """Seconds from the job's first working state (registration, moves, shots, welding, inspection) to
    its first done/failed state, by the ``/cell/status`` stamps; None when the bag holds no whole job."""
    from stud_cell.cycle_time import CELL_CATEGORY, END_STATES

    start = end = None
    for s in sorted(statuses, key=lambda m: _stamp_s(m.header)):
        if start is None and s.state_text in CELL_CATEGORY:
            start = _stamp_s(s.header)
        elif start is not None and s.state_text in END_STATES:
            end = _stamp_s(s.header)
            break
    return None if start is None or end is None else end - start


def cell_bag_summary(bag_dir: Path) -> dict:
    """:func:`registrations`, :func:`rail_moves` and :func:`job_span_s` of a cell bag."""
    msgs = read_topics(bag_dir, [names.REGISTRATION_RESULT, names.ARM_STATE, names.CELL_STATUS])
    states = msgs[names.ARM_STATE]
    return {"registrations": registrations(msgs[names.REGISTRATION_RESULT], states),
            "registrations_invalid": sum(not r.valid for r in msgs[names.REGISTRATION_RESULT]),
            "rail": rail_moves(states), "job_s": job_span_s(msgs[names.CELL_STATUS])}
