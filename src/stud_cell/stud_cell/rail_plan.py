"""Carriage positions along the rail: the fewest stops from which the arm reaches every camera
station, visited in one direction (issue 35).

With the arm's base on a rail's carriage, each camera station of the plan (stations.py, placed by
station_reach.py) is reachable from some carriage positions. :func:`plan_rail` finds them per
station, the fewest carriage positions ("stops") that cover every station, and the order:

1. **Where a station is reached from.** The driver's reach verdict depends on the pose in the arm's
   base frame and on the workspace box in ``world`` (cell_reach.py). The carriage only translates the
   base along world x (:func:`stud_common.frames.world_T_base`), so a camera pose at world x is
   reached with the carriage at ``c`` exactly when the same pose at the base-frame offset
   ``o = x - c - mount_x`` is, and its tool and flange lie in the box -- which does not depend on
   ``c``. :class:`RailReach` therefore searches the offsets once per (y, z, yaw) -- the stations of a
   row share them -- over ``reach_span_m``: samples ``coarse_step_m`` apart, then each end of a run of
   reachable samples refined by bisection to ``tolerance_m``, every round one batch of the reach test
   over all stations. Per station: the carriage intervals it is reached from, clipped to the rail.
2. **The studs' prior.** A station reached from where the arm cannot weld its studs costs the studs
   (a later stop, or named). Before a shot a stud's height and normal are unknown; with the prior the
   job plans by -- the registered plane, normal up -- a stud at ``prior_z_m`` is weldable from a set
   of offsets, searched the same way once per band of y (``prior_y_step_m``). A station's interval is
   its camera interval cut to where each of its studs is weldable by that prior (the camera interval
   alone when nothing is left).
3. **Few stops.** Interval stabbing, sweeping one way: the next stop covers the most stations not yet
   covered without passing the last carriage position any of them is reached from (with one interval
   per station: the earliest interval end, the classic greedy, whose count is the fewest; a camera
   reached on either side of the arm has two). Each stop then moves to the middle of the range all its
   stations are reached from: the count and the order stay, the stations come nearer the middle of
   the arm's reach.
4. **Checked.** Each stop's stations are put to the exact reach test at the stop's carriage
   position; a station refused there (a hole between samples) loses that position and the stops are
   placed again. A stop's stations are ones the driver accepts there.
5. **Order.** The stops in one direction along the rail, starting at the end nearer the carriage
   (never back); at each, its stations column by column along the travel, serpentine across.

A station no carriage position reaches is reported (``RailPlan.unreachable``) with the reason. Pure
numpy over the reach test (no ROS); world frame, metres, radians.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Sequence

import numpy as np

from rm65_driver.weld.reach import Reach
from stud_cell.cell_reach import CellReach, camera_pose_as_sent
from stud_cell.station_reach import StationGeometry
from stud_cell.stations import Station
from stud_common.frames import world_T_base
from stud_common.hand_eye_in_use import tool_in_world

#: Carriage intervals (m): sorted, disjoint ``(lo, hi)`` pairs.
Intervals = tuple[tuple[float, float], ...]

#: The box of the base-frame searches (m): far beyond any arm, so only the reach sphere and the IK decide.
_FREE_BOX_M = 1e3
#: Rounds of re-placing the stops after the exact check refused a station somewhere.
_MAX_CHECK_ROUNDS = 12


class RailPlanError(ValueError):
    """Rail settings no plan can come from (names the value)."""


@dataclass(frozen=True)
class Rail:
    """The rail the arm rides: travel ``0 .. length_m`` along world x, the base ``mount_xyz_m`` on the
    carriage (the driver's ``rail_length_m``, ``rail_mount_xyz_m``)."""

    length_m: float
    mount_xyz_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.length_m) and self.length_m > 0):
            raise RailPlanError(f"rail_length_m={self.length_m}: expected a rail longer than 0 m")
        mount = tuple(float(v) for v in np.asarray(self.mount_xyz_m, dtype=np.float64).ravel())
        if len(mount) != 3 or not all(math.isfinite(v) for v in mount):
            raise RailPlanError(f"rail_mount_xyz_m={list(self.mount_xyz_m)}: expected 3 finite numbers")
        object.__setattr__(self, "mount_xyz_m", mount)

    def world_T_base(self, carriage_m: float) -> np.ndarray:
        return world_T_base(carriage_m, self.mount_xyz_m)

    def clip(self, carriage_m: float) -> float:
        return float(min(max(carriage_m, 0.0), self.length_m))


@dataclass(frozen=True)
class RailPlanConfig:
    """How finely the carriage intervals are searched (m). ``reach_span_m``: how far along the rail
    from the arm's base a camera pose or a stud can lie and be reached at all (the RM-65: 0.61 m flange
    reach + gun + hand-eye); ``prior_y_step_m``: studs this close across the rail share one prior;
    ``prior_margin_m``: a stud's weldable range by the prior is kept this far inside its ends (the stud's
    true height and normal differ from the prior's); ``column_gap_m``: stations closer than this along
    the rail are one column of a stop."""

    coarse_step_m: float = 0.05
    tolerance_m: float = 0.005
    reach_span_m: float = 0.9
    prior_y_step_m: float = 0.02
    prior_max_bands: int = 8
    prior_coarse_step_m: float = 0.1
    prior_tolerance_m: float = 0.025
    prior_margin_m: float = 0.03
    column_gap_m: float = 0.05

    def __post_init__(self) -> None:
        if self.prior_max_bands < 1:
            raise RailPlanError(f"rail plan prior_max_bands={self.prior_max_bands}: expected at least 1")
        for name in ("coarse_step_m", "tolerance_m", "reach_span_m", "prior_y_step_m", "prior_coarse_step_m",
                     "prior_tolerance_m", "prior_margin_m", "column_gap_m"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise RailPlanError(f"rail plan {name}={value}: expected a positive length [m]")
        if self.tolerance_m > self.coarse_step_m or self.prior_tolerance_m > self.prior_coarse_step_m:
            raise RailPlanError(f"rail plan tolerance_m={self.tolerance_m} (prior_tolerance_m="
                                f"{self.prior_tolerance_m}) must not exceed coarse_step_m={self.coarse_step_m} "
                                f"(prior_coarse_step_m={self.prior_coarse_step_m})")


# -- intervals ------------------------------------------------------------------------------------
def intersect(a: Intervals, b: Intervals) -> Intervals:
    """The intersection of two sets of closed intervals (lo, hi) [m], sorted (empty when they do not overlap)."""
    out = []
    for lo1, hi1 in a:
        for lo2, hi2 in b:
            lo, hi = max(lo1, lo2), min(hi1, hi2)
            if lo <= hi:
                out.append((lo, hi))
    return tuple(sorted(out))


def _without(a: Intervals, around: float, half_m: float) -> Intervals:
    """``a`` less the open range ``around +- half_m``."""
    out = []
    for lo, hi in a:
        if hi < around - half_m or lo > around + half_m:
            out.append((lo, hi))
            continue
        if lo < around - half_m:
            out.append((lo, around - half_m))
        if hi > around + half_m:
            out.append((around + half_m, hi))
    return tuple(out)


def _runs(ok: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) index of each run of True in ``ok``."""
    runs, start = [], None
    for i, v in enumerate(ok):
        if v and start is None:
            start = i
        elif not v and start is not None:
            runs.append((start, i - 1))
            start = None
    if start is not None:
        runs.append((start, len(ok) - 1))
    return runs


def offset_bands(keys: list, test: Callable[[list[tuple[Any, float]]], np.ndarray], span_m: float,
                 step_m: float, tolerance_m: float) -> dict[Any, Intervals]:
    """Per key, the offsets ``o`` in ``[-reach_span_m, reach_span_m]`` where ``test`` holds:
    ``test([(key, o), ...]) -> bool array`` is asked for all keys' samples ``step_m`` apart in one call,
    then once per bisection round for every end of every run (module docstring). Each interval's ends
    are offsets the test accepted (within ``tolerance_m`` of where it stops holding)."""
    span, step = span_m, step_m
    n = int(math.ceil(span / step))
    samples = np.arange(-n, n + 1) * step
    ok = test([(k, float(o)) for k in keys for o in samples]).reshape(len(keys), len(samples))
    # ends[j] = [key index, ok offset, bad offset, is_low_end]
    ends: list[list] = []
    runs_of: dict[int, list[list[float]]] = {}
    for ki in range(len(keys)):
        runs_of[ki] = []
        for a, b in _runs(ok[ki]):
            run = [float(samples[a]), float(samples[b])]
            runs_of[ki].append(run)
            if a > 0:
                ends.append([ki, len(runs_of[ki]) - 1, float(samples[a]), float(samples[a - 1]), True])
            if b < len(samples) - 1:
                ends.append([ki, len(runs_of[ki]) - 1, float(samples[b]), float(samples[b + 1]), False])
    rounds = max(0, int(math.ceil(math.log2(step / tolerance_m))))
    for _ in range(rounds):
        if not ends:
            break
        mids = [(keys[e[0]], (e[2] + e[3]) / 2) for e in ends]
        verdict = test(mids)
        for e, (_k, mid), good in zip(ends, mids, verdict):
            if good:
                e[2] = mid
            else:
                e[3] = mid
    for ki, r, good_o, _bad, low in ends:
        runs_of[ki][r][0 if low else 1] = good_o
    return {keys[ki]: tuple((lo, hi) for lo, hi in runs_of[ki]) for ki in range(len(keys))}


# -- the reach test with the carriage -------------------------------------------------------------
class RailReach:
    """The driver's reach test with the arm's base on the rail's carriage (module docstring): the test
    at one carriage position (:meth:`at`), and where along the rail a camera pose (or, by the prior, a
    stud) is reached from. Searches are cached; ``checks`` counts the poses put to the reach test."""

    def __init__(self, reach: Reach, rail: Rail, config: RailPlanConfig = RailPlanConfig()) -> None:
        self.reach, self.rail, self.config = reach, rail, config
        big = _FREE_BOX_M
        self._free = Reach(replace(reach.config, workspace_min_m=(-big, -big, -big), workspace_max_m=(big, big, big)))
        self._base0 = rail.world_T_base(0.0)
        self._at: dict[float, CellReach] = {}
        self._camera_bands: dict[tuple, Intervals] = {}
        self._stud_bands: dict[tuple, Intervals] = {}
        self.checks = 0

    def at(self, carriage_m: float) -> CellReach:
        """The reach test with the carriage at ``carriage_m`` (m), as the driver applies it there."""
        key = round(float(carriage_m), 9)
        if key not in self._at:
            self._at[key] = CellReach(self.reach, self.rail.world_T_base(key))
        return self._at[key]

    # -- camera poses ---------------------------------------------------------------------------
    def _box_ok(self, poses) -> np.ndarray:
        """Tool tip and flange of each camera pose inside the workspace box (world; the carriage
        does not change where they are)."""
        c = self.reach.config
        lo, hi = np.asarray(c.workspace_min_m), np.asarray(c.workspace_max_m)
        hand_eye, tool_inv = c.hand_eye_matrix, np.linalg.inv(c.tool_matrix)
        out = []
        for xyz, yaw in poses:
            T = tool_in_world(camera_pose_as_sent(xyz, yaw), hand_eye)
            pts = np.array([T[:3, 3], (T @ tool_inv)[:3, 3]])
            out.append(not np.any((pts < lo - 1e-9) | (pts > hi + 1e-9)))
        return np.array(out, dtype=bool)

    def _camera_test(self, pairs: list[tuple[Any, float]]) -> np.ndarray:
        mx = self.rail.mount_xyz_m[0]
        T = np.array([camera_pose_as_sent((mx + o, key[0], key[1]), key[2]) for key, o in pairs])
        self.checks += len(T)
        return np.array([v.ok for v in self._free.cameras(T, self._base0)], dtype=bool)

    def camera_intervals(self, poses: Sequence[tuple]) -> list[Intervals]:
        """Per nadir camera pose ``(xyz_w, yaw_rad)``: the carriage intervals (m) it is reached from."""
        keys = [(round(float(xyz[1]), 9), round(float(xyz[2]), 9), round(float(yaw), 12)) for xyz, yaw in poses]
        new = sorted(set(keys) - set(self._camera_bands))
        if new:
            c = self.config
            self._camera_bands.update(offset_bands(new, self._camera_test, c.reach_span_m, c.coarse_step_m,
                                                   c.tolerance_m))
        box = self._box_ok(poses) if len(poses) else np.zeros(0, bool)
        return [self._to_carriage(float(xyz[0]), self._camera_bands[k]) if inside else ()
                for (xyz, _yaw), k, inside in zip(poses, keys, box)]

    def cameras_somewhere(self, poses: Sequence[tuple]) -> list[bool]:
        """Per camera pose: is it reached from some carriage position along the rail."""
        return [bool(iv) for iv in self.camera_intervals(poses)]

    def carriage_for(self, pose: tuple, near_m: float) -> float | None:
        """The carriage position nearest ``near_m`` from which the arm reaches the camera ``pose``,
        checked with the exact test there (None: none found)."""
        intervals = self.camera_intervals([pose])[0]
        candidates = [min(max(near_m, lo), hi) for lo, hi in intervals] + [(lo + hi) / 2 for lo, hi in intervals]
        for c in sorted(candidates, key=lambda v: abs(v - near_m)):
            self.checks += 1
            if self.at(c).camera_ok(pose[0], pose[1]):
                return float(c)
        return None

    # -- studs (the prior) ----------------------------------------------------------------------
    def _stud_test(self, pairs: list[tuple[Any, float]]) -> np.ndarray:
        mx = self.rail.mount_xyz_m[0]
        self.checks += len(pairs)
        return np.array([self._free.stud((mx + o, key[0], key[1]), (0.0, 0.0, 1.0), self._base0).ok
                         for key, o in pairs], dtype=bool)

    def stud_prior_intervals(self, xy_w, prior_z_m: float) -> list[Intervals]:
        """Per stud at world ``xy_w`` (N, 2): the carriage intervals from which a stud there, at height
        ``prior_z_m`` with its normal up, is weldable (studs within ``prior_y_step_m`` across the rail
        share one search)."""
        c = self.config
        xy = np.asarray(xy_w, dtype=np.float64).reshape(-1, 2)
        if not len(xy):
            return []
        # bands across the rail: prior_y_step_m wide, wider when the studs spread over more than prior_max_bands
        step = max(c.prior_y_step_m, float(np.ptp(xy[:, 1])) / c.prior_max_bands)
        y0 = float(xy[:, 1].min())
        keys = [(round(y0 + round((float(y) - y0) / step) * step, 9), round(float(prior_z_m), 9)) for _x, y in xy]
        new = sorted(set(keys) - set(self._stud_bands))
        if new:
            self._stud_bands.update(offset_bands(new, self._stud_test, c.reach_span_m, c.prior_coarse_step_m,
                                                 c.prior_tolerance_m))
        m = c.prior_margin_m   # the prior is a prior: its band's ends are kept clear of
        return [self._to_carriage(float(x),
                                  tuple((lo + m, hi - m) for lo, hi in self._stud_bands[k] if hi - lo > 2 * m))
                for (x, _y), k in zip(xy, keys)]

    def surely_unreachable(self, xy_w, z_range_m: tuple[float, float]) -> list[str]:
        """:meth:`CellReach.surely_unreachable` from every carriage position along the rail: why no
        carriage position lets the gun weld the stud, whatever its height and normal ("" when one may)."""
        xy = np.asarray(xy_w, dtype=np.float64).reshape(-1, 2)
        mx, step, span = self.rail.mount_xyz_m[0], self.config.coarse_step_m, self.config.reach_span_m
        out = []
        for x, y in xy:
            lo, hi = self.rail.clip(x - mx - span), self.rail.clip(x - mx + span)
            cs = np.append(np.arange(lo, hi, step), hi)
            why = self.at(0.0).surely_unreachable([(x, y)], z_range_m, [self.rail.world_T_base(c) for c in cs],
                                                  base_slack_m=step / 2)[0]
            out.append(f"from any carriage position 0..{self.rail.length_m:g} m: {why}" if why else "")
        return out

    def _to_carriage(self, x_w: float, band: Intervals) -> Intervals:
        """Offsets ``o`` of a pose at world ``x_w`` -> carriage intervals ``x_w - mount_x - o`` on the rail."""
        base = x_w - self.rail.mount_xyz_m[0]
        out = []
        for lo, hi in band:
            a, b = max(base - hi, 0.0), min(base - lo, self.rail.length_m)
            if a <= b:
                out.append((a, b))
        return tuple(sorted(out))


# -- the plan -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class CarriageStop:
    """One carriage position of the plan: ``index`` (1-based, in visiting order), ``position_m`` along
    the rail, the range ``window_m`` every one of its stations is reached from, and its stations in the
    order they are worked (renumbered along the whole job)."""

    index: int
    position_m: float
    window_m: tuple[float, float]
    stations: tuple[Station, ...]

    @property
    def stud_indices(self) -> tuple[int, ...]:
        return tuple(i for s in self.stations for i in s.stud_indices)


@dataclass(frozen=True)
class RailPlan:
    """The stops in visiting order; the stations no carriage position reaches (input station index ->
    reason; their studs are in ``unreachable_studs``); the reach checks the plan took and its time."""

    stops: tuple[CarriageStop, ...]
    unreachable: dict[int, str]
    unreachable_studs: dict[int, str]
    reach_checks: int
    planning_s: float
    prior_ignored: tuple[int, ...] = ()   # stations whose studs' prior left no carriage position: camera reach only

    @property
    def stations(self) -> tuple[Station, ...]:
        return tuple(s for stop in self.stops for s in stop.stations)


def _stab(intervals: dict[int, Intervals]) -> list[tuple[float, float, list[int]]]:
    """Few points stabbing every station, in increasing order (module docstring, 3): (window lo, window
    hi, stations) per point; a window is the range every station of it is reached from.

    A sweep that never goes back: the next point lies at most at the deadline -- the earliest of the
    pending stations' last interval ends, so no station is left behind -- and covers the most pending
    stations (the furthest such point among equals). With one interval per station the deadline itself
    covers the most: this is then the classic greedy, whose count is the fewest."""
    pending = {i for i, iv in intervals.items() if iv}
    out = []
    s = -math.inf
    while pending:
        deadline = min(max(hi for _lo, hi in intervals[i]) for i in pending)
        candidates = sorted({v for i in pending for lo, hi in intervals[i] for v in (lo, hi) if s <= v <= deadline}
                            | {deadline})
        best: tuple[int, float] = (-1, -math.inf)
        for p in candidates:
            n = sum(1 for i in pending if any(lo <= p <= hi for lo, hi in intervals[i]))
            if n >= best[0]:
                best = (n, p)
        p = best[1]
        members, lo_w, hi_w = [], -math.inf, math.inf
        for i in sorted(pending):
            hit = next(((lo, hi) for lo, hi in intervals[i] if lo <= p <= hi), None)
            if hit is not None:
                members.append(i)
                lo_w, hi_w = max(lo_w, hit[0]), min(hi_w, hit[1])
        if not members:  # cannot happen (the deadline lies in some station's last interval): guard
            break
        out.append((lo_w, hi_w, members))
        pending -= set(members)
        s = hi_w + 1e-12
    return out


def _serpentine(stations: list[Station], direction: int, column_gap_m: float) -> list[Station]:
    """Column by column along the travel (``direction`` +1: increasing x), alternately up and down y."""
    ordered = sorted(stations, key=lambda s: (direction * s.camera_xyz_w[0], s.camera_xyz_w[1]))
    columns: list[list[Station]] = []
    for st in ordered:
        if columns and abs(st.camera_xyz_w[0] - columns[-1][-1].camera_xyz_w[0]) <= column_gap_m:
            columns[-1].append(st)
        else:
            columns.append([st])
    out: list[Station] = []
    for k, col in enumerate(columns):
        out += sorted(col, key=lambda s: s.camera_xyz_w[1], reverse=bool(k % 2))
    return out


def plan_rail(stations: Sequence[Station], studs_xy_w, rail_reach: RailReach, prior_z_m: float | None,
              start_m: float = 0.0) -> RailPlan:
    """The stops for ``stations`` (world poses; their ``stud_indices`` index ``studs_xy_w`` (N, 2)) on
    ``rail_reach``'s rail, from the carriage at ``start_m`` (module docstring). ``prior_z_m``: the
    studs' height for the weld prior (None: camera reach only)."""
    t0 = time.monotonic()
    checks0 = rail_reach.checks
    xy = np.asarray(studs_xy_w, dtype=np.float64).reshape(-1, 2)
    by_index = {s.index: s for s in stations}
    camera = dict(zip(by_index, rail_reach.camera_intervals([(s.camera_xyz_w, s.yaw_rad) for s in stations])))
    unreachable = {i: (f"no carriage position along the rail 0..{rail_reach.rail.length_m:g} m lets the arm hold the "
                       f"camera at {np.round(by_index[i].camera_xyz_w, 3).tolist()} m")
                   for i, iv in camera.items() if not iv}
    feasible: dict[int, Intervals] = {}
    prior_ignored = []
    members = sorted({j for s in stations for j in s.stud_indices})
    prior = (dict(zip(members, rail_reach.stud_prior_intervals(xy[members], prior_z_m)))
             if prior_z_m is not None and members else {})
    for i, iv in camera.items():
        if not iv:
            continue
        cut = iv
        for j in by_index[i].stud_indices if prior else ():
            cut = intersect(cut, prior[j])
        if not cut:
            prior_ignored.append(i)
        feasible[i] = cut or iv
    placed: list[tuple[float, float, float, list[int]]] = []
    refused_at: dict[int, list[float]] = {}
    for last_round in range(_MAX_CHECK_ROUNDS, 0, -1):
        placed = [((lo + hi) / 2, lo, hi, group) for lo, hi, group in _stab(feasible)]
        refused = []
        for position, _lo, _hi, group in placed:
            verdicts = rail_reach.at(position).cameras([(by_index[i].camera_xyz_w, by_index[i].yaw_rad) for i in group])
            rail_reach.checks += len(group)
            refused += [(i, position) for i, v in zip(group, verdicts) if not v.ok]
        if not refused:
            break
        for i, position in refused:
            refused_at.setdefault(i, []).append(position)
            feasible[i] = _without(feasible[i], position, rail_reach.config.tolerance_m)
            if not feasible[i] and i not in prior_ignored:   # the prior's range is used up: the camera's
                prior_ignored.append(i)
                feasible[i] = camera[i]
                for q in refused_at[i]:
                    feasible[i] = _without(feasible[i], q, rail_reach.config.tolerance_m)
            if not feasible[i] or last_round == 1:
                feasible.pop(i)
                unreachable[i] = (f"the reach test refuses the camera at "
                                  f"{np.round(by_index[i].camera_xyz_w, 3).tolist()}"
                                  f" m from each of the carriage positions tried ({len(refused_at[i])})")
        if last_round == 1:
            placed = [(position, lo, hi, [i for i in group if i in feasible]) for position, lo, hi, group in placed]
    placed = [p for p in placed if p[3]]
    if placed and abs(start_m - placed[-1][0]) < abs(start_m - placed[0][0]):
        placed.reverse()   # start at the end nearer the carriage
    direction = 1 if len(placed) < 2 or placed[-1][0] >= placed[0][0] else -1
    stops, k = [], 0
    for n, (position, lo, hi, group) in enumerate(placed, 1):
        ordered = _serpentine([by_index[i] for i in group], direction, rail_reach.config.column_gap_m)
        renumbered = []
        for st in ordered:
            k += 1
            renumbered.append(Station(k, st.camera_xyz_w, st.yaw_rad, st.stud_indices))
        stops.append(CarriageStop(n, float(position), (float(lo), float(hi)), tuple(renumbered)))
    studs = {j: f"its camera station: {why}" for i, why in unreachable.items() for j in by_index[i].stud_indices}
    return RailPlan(tuple(stops), unreachable, studs, rail_reach.checks - checks0, time.monotonic() - t0,
                    tuple(sorted(prior_ignored)))


def registration_views(marks_xy_w, stations: Sequence[Station], geom: StationGeometry,
                       margin_m: float) -> list[tuple[tuple[tuple[float, float, float], float], int]]:
    """Nadir camera poses for a stop's registration on the part's reference marks, with the number of
    marks (world XY ``marks_xy_w`` (M, 2)) each holds in its inner footprint, ``margin_m`` clear of its
    border: the stop's station poses, and poses centred between two marks (every height and quarter
    turn of ``geom``). Most marks first, then nearest the stop's first station."""
    marks = np.asarray(marks_xy_w, dtype=np.float64).reshape(-1, 2)
    if not stations:
        return []
    first = np.asarray(stations[0].camera_xyz_w[:2])
    reach = float(np.max([np.linalg.norm(np.asarray(s.camera_xyz_w[:2]) - first) for s in stations])) + 0.5
    near = marks[np.linalg.norm(marks - first, axis=1) <= reach]
    poses: list[tuple[tuple[float, float, float], float]] = [(s.camera_xyz_w, s.yaw_rad) for s in stations]
    yaw0 = stations[0].yaw_rad
    for i in range(len(near)):
        for j in range(i + 1, len(near)):
            centre = (near[i] + near[j]) / 2
            for h in geom.heights():
                for turn in (0.0, math.pi / 2, math.pi, -math.pi / 2):
                    poses.append(((float(centre[0]), float(centre[1]), geom.plane_z_m + h), yaw0 + turn))
    out = []
    for xyz, yaw in poses:
        half = geom.inner_half(xyz[2] - geom.plane_z_m) - margin_m
        c, s_ = math.cos(yaw), math.sin(yaw)
        local = (marks - np.asarray(xyz[:2])) @ np.array([[c, -s_], [s_, c]])
        out.append(((xyz, yaw), int(np.sum(np.all(np.abs(local) <= half, axis=1))) if np.all(half > 0) else 0))
    return sorted(out, key=lambda pc: (-pc[1], float(np.linalg.norm(np.asarray(pc[0][0][:2]) - first))))


__all__ = ["CarriageStop", "Intervals", "Rail", "RailPlan", "RailPlanConfig", "RailPlanError", "RailReach",
           "intersect", "offset_bands", "plan_rail", "registration_views"]
