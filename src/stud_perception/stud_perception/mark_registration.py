"""Register a view on every mark it sees: the board's O, A, B and the reference marks along a part.

A part longer than the arm is welded from a rail, station by station; one board at one end does not
hold over metres (a rail error of 1 mm/m puts the far studs 6 mm off). The drawing may carry
*reference marks* ``M1``, ``M2``, ... painted on the part itself, and each station registers on the
marks it sees (paper Eq. 2, least squares over all of them, :func:`~stud_perception.registration.fit_marks`).

Pipeline of :func:`register_view_on_marks`:

1. every dark disc of the mark size, lifted with the depth around it
   (:func:`~stud_perception.markers.find_mark_candidates`, the Hough stages of the board's marks);
2. each disc named after a drawing mark: with a *prior* drawing -> world transform (an earlier
   station's, which the rail's error puts a few millimetres off here), the drawing mark whose
   predicted world position lies nearest, within ``gate_m`` (each mark and each disc used once,
   nearest pairs first); without a prior, the board's O, A, B triple by its distances and
   handedness, as the board's registration finds it (:func:`~stud_perception.markers.detect_marks`),
   whose Eq. 3 registration is then the prior for the rest;
3. the least-squares fit over all named marks, then once more after naming again with that fit (a
   mark just outside the gate of a poor prior joins); a mark farther than ``max_residual_m`` from
   the fit refuses the registration (a wrong association shows there: two marks swapped cannot be
   fitted by a rigid motion).

The transform is planar as in Eq. 2: the drawing is the part's plan, so a mark's drawing (x, y) is
where it lies seen from above, whatever its height; marks on a cambered, sloped flange are at
different heights, each measured by its own depth, and the heights are not part of the fit. Two
marks therefore fix the transform (the plane is known: world z up), three or more over-determine it.

A station that sees too few marks is not a failure when an earlier station registered:
:class:`RegistrationTrail` keeps the registrations made along the part and answers with the nearest
one, saying how far it extrapolates (``MarkRegistration.extrapolated_m``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal, Mapping

import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.depth_image import FillRule
from stud_perception.markers import MarkCandidates, MarkDetection, MarkDetectorConfig, MarkStatus, find_mark_candidates
from stud_perception.registration import (
    BOARD_LABELS,
    MarkRegistration,
    RegistrationError,
    fit_marks,
    local_to_world,
    registration_from_marks,
)
from stud_perception.view_registration import ViewRegistration


@dataclass(frozen=True)
class MarkFitConfig:
    """Tunables of :func:`register_view_on_marks` (metres).

    ``gate_m``: a disc is named after a drawing mark only within this distance of the mark's predicted
    world position; keep it below half the smallest distance between two marks (and above the prior's
    error: the rail's error between two stations). ``max_residual_m``: the largest distance a mark may
    lie from the fit. ``min_marks``: the fewest marks a registration uses (2: the plane is known).
    ``method``: the transform when the view's marks are exactly O, A, B (as
    :func:`~stud_perception.view_registration.register_view`: ``eq3`` or ``least_squares``).
    """

    gate_m: float = 0.03
    max_residual_m: float = 0.002
    min_marks: int = 2
    method: Literal["eq3", "least_squares"] = "eq3"

    def __post_init__(self) -> None:
        if not (self.gate_m > 0 and self.max_residual_m > 0):
            raise ValueError(f"gate_m and max_residual_m must be > 0, got {self.gate_m}, {self.max_residual_m}")
        if self.min_marks < 2:
            raise ValueError(f"min_marks must be >= 2 (two marks fix a planar transform), got {self.min_marks}")
        if self.method not in ("eq3", "least_squares"):
            raise ValueError(f"method must be 'eq3' or 'least_squares', got {self.method!r}")


def checked_drawing_marks(drawing_marks_m: Mapping[str, object]) -> tuple[tuple[str, ...], np.ndarray]:
    """(labels, (M, 2) drawing positions) of ``drawing_marks_m`` (label -> drawing (x, y), metres),
    which must hold O, A and B; ValueError naming the label otherwise."""
    labels = tuple(str(lb) for lb in drawing_marks_m)
    missing = [lb for lb in BOARD_LABELS if lb not in labels]
    if missing:
        raise ValueError(f"drawing marks lack {', '.join(missing)}: need O, A, B (and any reference marks)")
    xy = np.array([np.asarray(drawing_marks_m[lb], dtype=np.float64).ravel() for lb in labels])
    if xy.shape != (len(labels), 2) or not np.isfinite(xy).all():
        raise ValueError(f"drawing marks must be finite (x, y) pairs, got shape {xy.shape}")
    return labels, xy


def associate_marks(candidates_xy_m: np.ndarray, predicted_xy_m: np.ndarray, gate_m: float) -> np.ndarray:
    """Name discs after drawing marks by position: (M,) index of the candidate taken for each predicted
    mark, -1 for none. ``candidates_xy_m`` (K, 2) measured world XY (NaN rows never match);
    ``predicted_xy_m`` (M, 2) where a prior puts each drawing mark. Pairs closer than ``gate_m`` are
    taken nearest first, each candidate and each mark at most once."""
    C = np.asarray(candidates_xy_m, dtype=np.float64).reshape(-1, 2)
    P = np.asarray(predicted_xy_m, dtype=np.float64).reshape(-1, 2)
    taken = np.full(len(P), -1, dtype=np.int64)
    if len(C) == 0 or len(P) == 0:
        return taken
    d = np.linalg.norm(P[:, None, :] - C[None, :, :], axis=2)
    d = np.where(np.isfinite(d), d, np.inf)
    used = np.zeros(len(C), dtype=bool)
    for flat in np.argsort(d, axis=None, kind="stable"):
        m, k = divmod(int(flat), len(C))
        if d[m, k] >= gate_m:
            break
        if taken[m] < 0 and not used[k]:
            taken[m], used[k] = k, True
    return taken


def register_view_on_marks(
    color_bgr: np.ndarray,
    depth_m: np.ndarray,
    camera: CameraModel,
    drawing_marks_m: Mapping[str, object],
    config: MarkDetectorConfig = MarkDetectorConfig(),
    fit: MarkFitConfig = MarkFitConfig(),
    prior: np.ndarray | None = None,
) -> ViewRegistration:
    """Register one view on all the marks it sees (module docstring).

    ``drawing_marks_m``: label -> drawing (x, y), metres: O, A, B and the reference marks.
    ``prior``: a drawing -> world transform (3, 3) to name the marks by (an earlier station's);
    None: the view must show O, A, B. ``config.mark_diameter_m``: the drawing's mark diameter.
    The result's registration (:class:`~stud_perception.registration.MarkRegistration`) lists the
    marks used with their residuals; a view that cannot be registered gives ``ok=False`` and why.
    """
    labels, drawing_xy = checked_drawing_marks(drawing_marks_m)
    board_xy = drawing_xy[[labels.index(lb) for lb in BOARD_LABELS]]
    found = find_mark_candidates(color_bgr, depth_m, camera, config)
    if isinstance(found, MarkDetection):
        return ViewRegistration(False, f"marks not found ({found.status.value}): {found.message}", found, None)
    if prior is None:
        picked = found.board_triple(board_xy, config.distance_tol_m)
        if isinstance(picked, MarkDetection):
            return ViewRegistration(False, f"marks not found ({picked.status.value}): {picked.message} (no prior "
                                    "registration to name reference marks by)", picked, None)
        uv, world = found.corrected(picked[0], camera, config.mark_diameter_m / 2)
        try:
            prior = registration_from_marks(world[0], world[1], world[2], drawing_marks=board_xy,
                                            tol_m=config.distance_tol_m, method=fit.method).M_local2world
        except RegistrationError as exc:
            return ViewRegistration(False, f"marks found but unusable: {exc}", _detection(found, None), None,
                                    refused=True)
    return _fit_associated(found, camera, labels, drawing_xy, board_xy, np.asarray(prior, dtype=np.float64),
                           config, fit)


def _fit_associated(found: MarkCandidates, camera: CameraModel, labels: tuple[str, ...], drawing_xy: np.ndarray,
                    board_xy: np.ndarray, prior: np.ndarray, config: MarkDetectorConfig,
                    fit: MarkFitConfig) -> ViewRegistration:
    """Steps 2-3: name the candidates by ``prior``, fit, name again by the fit and fit once more."""
    r_m = config.mark_diameter_m / 2
    M, reg = prior, None
    for _ in range(2):
        taken = associate_marks(found.world_m[:, :2], local_to_world(M, drawing_xy), fit.gate_m)
        marks = np.flatnonzero(taken >= 0)
        if len(marks) < fit.min_marks:
            seen = ", ".join(labels[m] for m in marks) or "none"
            msg = (f"too few marks: {len(marks)} of the drawing's marks named in view ({seen}), need {fit.min_marks} "
                   f"({len(found)} mark-sized disc(s) seen, gate {fit.gate_m * 1000:.0f} mm){found.note}")
            return ViewRegistration(False, msg, _detection(found, None), None)
        idx = taken[marks]
        world = found.world_m[idx]
        uv, world = found.corrected(idx, camera, r_m, _surface_normal(world))
        used = tuple(labels[m] for m in marks)
        try:
            if set(used) == set(BOARD_LABELS):  # the board alone: Eq. 3 (or LSQ) as register_view does
                o, a, b = (world[used.index(lb)] for lb in BOARD_LABELS)
                reg = registration_from_marks(o, a, b, drawing_marks=board_xy, tol_m=config.distance_tol_m,
                                              method=fit.method)
                order = [used.index(lb) for lb in BOARD_LABELS]
                uv = uv[order]
                if reg.residual_max_m > fit.max_residual_m:
                    raise RegistrationError(f"O, A, B fit with residual {reg.residual_max_m * 1000:.1f} mm (limit "
                                            f"{fit.max_residual_m * 1000:.1f} mm)")
            else:
                reg = fit_marks(used, drawing_xy[marks], world, board_xy, fit.max_residual_m, fit.min_marks)
        except RegistrationError as exc:
            return ViewRegistration(False, f"marks found but unusable: {exc}", _detection(found, None), None,
                                    refused=True)
        M = reg.M_local2world
    assert reg is not None
    msg = (f"registered on {len(reg.labels_used)} marks ({', '.join(reg.labels_used)}): residual "
           f"{reg.residual_m * 1e3:.2f} mm RMS, {reg.residual_max_m * 1e3:.2f} mm max, yaw "
           f"{math.degrees(reg.yaw_rad):.2f} deg{found.note}")
    return ViewRegistration(True, msg, _detection(found, (reg, uv)), reg)


def _surface_normal(world: np.ndarray) -> np.ndarray:
    """Unit normal of the plane through the marks (world), +z when they are fewer than three or
    nearly collinear: only the perspective correction of the imaged disc centres uses it."""
    if len(world) >= 3 and np.isfinite(world).all():
        centred = world - world.mean(axis=0)
        _, s, vt = np.linalg.svd(centred)
        if s[1] > 0.2 * s[0]:
            n = vt[2]
            return n if n[2] > 0 else -n
    return np.array([0.0, 0.0, 1.0])


def _detection(found: MarkCandidates, used) -> MarkDetection:
    """The view's candidates as a :class:`MarkDetection` (for the overlay): O, A, B where the fit used
    them, NaN otherwise."""
    marks_uv = np.full((3, 2), np.nan)
    marks_w = np.full((3, 3), np.nan)
    if used is not None:
        reg, uv = used
        for i, name in enumerate(BOARD_LABELS):
            if name in reg.labels_used:
                j = reg.labels_used.index(name)
                marks_uv[i], marks_w[i] = uv[j], reg.marks_used_world_m[j]
    return MarkDetection(
        status=MarkStatus.OK if used is not None else MarkStatus.NO_MATCHING_TRIPLE,
        message="" if used is None else f"{len(used[0].labels_used)} marks used",
        marks_world_m=marks_w, marks_pixels_uv=marks_uv, depth_rules=np.full(3, FillRule.NONE, dtype=np.int8),
        distance_error_m=float("nan"), candidates_uv=found.uv, candidates_radius_px=found.radius_px,
        candidates_world_m=found.world_m,
    )


# -- registrations along the part -----------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class RegisteredStation:
    """A registration made on a view's own marks, and where: ``position_xy_m`` (2,) the camera's world
    XY at that view (along a rail: moves with the carriage)."""

    position_xy_m: np.ndarray
    registration: MarkRegistration


@dataclass(eq=False)
class RegistrationTrail:
    """The registrations made along a part, station by station: each view is named by the nearest
    one (the prior), and a view with too few marks takes the nearest one, saying how far away it
    was (``MarkRegistration.extrapolated_m``). Not thread-safe (one registration node owns one)."""

    stations: list[RegisteredStation] = field(default_factory=list)

    def nearest(self, position_xy_m) -> tuple[RegisteredStation, float] | None:
        """(the registered station nearest ``position_xy_m``, its distance in metres), None when empty."""
        if not self.stations:
            return None
        p = np.asarray(position_xy_m, dtype=np.float64).ravel()[:2]
        d = [float(np.linalg.norm(s.position_xy_m - p)) for s in self.stations]
        i = int(np.argmin(d))
        return self.stations[i], d[i]

    def clear(self) -> None:
        self.stations.clear()

    def register(self, color_bgr: np.ndarray, depth_m: np.ndarray, camera: CameraModel,
                 drawing_marks_m: Mapping[str, object], config: MarkDetectorConfig = MarkDetectorConfig(),
                 fit: MarkFitConfig = MarkFitConfig(), position_xy_m=None) -> ViewRegistration:
        """Register the view (:func:`register_view_on_marks`) with the nearest registered station as the
        prior; remember it when it succeeds. When the view shows too few marks and a station registered
        before, the result is that station's registration (``ok``, ``extrapolated_m`` > 0 unless at the
        same spot; the message says why and how far). A view whose marks disagree with the drawing
        (``refused``) stays a failure. ``position_xy_m``: where this view is (default: the
        camera's world XY)."""
        pos = np.asarray(camera.position_w[:2] if position_xy_m is None else position_xy_m, dtype=np.float64)
        near = self.nearest(pos)
        prior = near[0].registration.M_local2world if near is not None else None
        result = register_view_on_marks(color_bgr, depth_m, camera, drawing_marks_m, config, fit, prior)
        if result.ok and result.registration is not None:
            self.stations.append(RegisteredStation(pos.copy(), result.registration))
            return result
        if near is None or result.refused:  # marks that disagree with the drawing are reported, never papered over
            return result
        station, dist = near
        reg = replace(station.registration, extrapolated_m=max(dist, 1e-9))
        msg = (f"extrapolated {dist:.3f} m from the nearest registered station (its residual "
               f"{reg.residual_max_m * 1e3:.2f} mm max on {', '.join(reg.labels_used)}): {result.message}")
        return ViewRegistration(True, msg, result.detection, reg)
