"""Drawing -> world registration from the marks O, A, B (paper Eq. 2-3) and least squares.

Frames: the drawing frame has its origin at mark O, x toward A, y toward B (metres); `world`
is the robot base frame, z up (the working plane at any height in it). Registration is planar: the
3x3 homogeneous ``M_local2world`` maps drawing (x, y, 1) to world (x, y, 1) (Eq. 2); its
rotation block is orthonormal and its last column is the translation in metres.

Eq. 3 builds M from the unit vectors OA and OB in world (the cosines of OA and OB with world
X and Y) and O. Measured OA and OB are never exactly perpendicular, so the 2x2 block
[OA/|OA|, OB/|OB|] is replaced by its closest rotation (polar decomposition): the angular error
is shared between the two axes instead of all being put into one. When the drawing's own
marks are given, the same construction on them makes any drawing placement of O, A, B work.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np


class RegistrationError(ValueError):
    """Marks or point sets from which no trustworthy drawing -> world transform follows."""


_PAIR_NAMES = ("|OA|", "|OB|", "|AB|")


@dataclass(frozen=True, eq=False)
class MarkRegistration:
    """A drawing -> world registration from the marks O, A, B, with its quality figures (not the
    ``stud_welding_msgs/Registration`` message the registration node publishes from it).

    ``M_local2world`` (3, 3): drawing metres -> world metres (Eq. 2). ``marks_world_m`` (3, 3):
    measured O, A, B in world. ``marks_drawing_m`` (3, 2): O, A, B in the drawing (the ideal
    right-angle layout with the measured lengths when no drawing was given). ``residual_m``: RMS
    distance between the transformed drawing marks and the measured ones (world XY).
    ``angle_AOB_deg``: measured angle at O. ``distance_errors_m`` (3,): measured minus drawing
    |OA|, |OB|, |AB| (NaN without a drawing); ``scale_error``: the largest relative length error.
    ``method``: ``eq3`` (paper) or ``least_squares``.

    Every mark the fit used (O, A, B and the reference marks M1, M2, ... of a long part:
    :func:`fit_marks`): ``labels_used`` (L,), ``marks_used_world_m`` (L, 3) measured,
    ``marks_used_drawing_m`` (L, 2), ``mark_residuals_m`` (L,) the distance (world XY) between each
    measured mark and where the transform puts its drawing position, ``residual_max_m`` the largest.
    A fit without O, A, B in view has NaN rows in ``marks_world_m`` for the marks it did not see and
    NaN ``angle_AOB_deg``. ``extrapolated_m``: 0 for a registration on the view's own marks; for a
    station that saw too few marks and took the nearest registered one, how far that one was
    (:class:`~stud_perception.mark_registration.RegistrationTrail`), metres.
    """

    M_local2world: np.ndarray
    marks_world_m: np.ndarray
    marks_drawing_m: np.ndarray
    residual_m: float
    angle_AOB_deg: float
    distance_errors_m: np.ndarray
    scale_error: float
    method: str
    labels_used: tuple[str, ...] = ("O", "A", "B")
    marks_used_world_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    marks_used_drawing_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    mark_residuals_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    residual_max_m: float = float("nan")
    extrapolated_m: float = 0.0

    @property
    def extrapolated(self) -> bool:
        """True when this registration was not measured on the view it is used for."""
        return self.extrapolated_m > 0.0

    @property
    def yaw_rad(self) -> float:
        """Rotation of the drawing frame about world z."""
        return math.atan2(self.M_local2world[1, 0], self.M_local2world[0, 0])

    @property
    def translation_m(self) -> np.ndarray:
        """World XY of the drawing origin, shape (2,)."""
        return self.M_local2world[:2, 2].copy()

    def to_world(self, xy_m) -> np.ndarray:
        return local_to_world(self.M_local2world, xy_m)


@dataclass(frozen=True, eq=False)
class RigidFit2D:
    """Least-squares rigid 2D fit: ``M_local2world`` (3, 3), RMS residual ``rms_m`` and the
    per-point residual distances ``residuals_m`` (N,), metres."""

    M_local2world: np.ndarray
    rms_m: float
    residuals_m: np.ndarray


# -- applying a transform ------------------------------------------------------------------------
def local_to_world(M_local2world: np.ndarray, xy_m) -> np.ndarray:
    """Drawing points (..., 2) -> world XY (..., 2) with a 3x3 homogeneous M (Eq. 2)."""
    M = np.asarray(M_local2world, dtype=np.float64)
    xy = np.asarray(xy_m, dtype=np.float64)
    return xy @ M[:2, :2].T + M[:2, 2]


def world_to_local(M_local2world: np.ndarray, xy_m) -> np.ndarray:
    """World XY (..., 2) -> drawing points (..., 2); M must be rigid (orthonormal rotation)."""
    M = np.asarray(M_local2world, dtype=np.float64)
    xy = np.asarray(xy_m, dtype=np.float64)
    return (xy - M[:2, 2]) @ M[:2, :2]


def _homogeneous(angle_rad: float, origin_xy) -> np.ndarray:
    c, s = math.cos(angle_rad), math.sin(angle_rad)
    return np.array([[c, -s, origin_xy[0]], [s, c, origin_xy[1]], [0.0, 0.0, 1.0]])


# -- least squares ---------------------------------------------------------------------------------
def fit_rigid_2d(local_pts, world_pts, max_rms_m: float | None = None) -> RigidFit2D:
    """Rigid (rotation + translation, no scale) least-squares fit world ~ M @ local.

    ``local_pts``, ``world_pts``: (N, 2) corresponding points, N >= 2, metres. This is the 2D
    Kabsch/Umeyama solution in closed form (the rotation angle is the atan2 of the summed cross
    and dot products of the centred points), which is always a proper rotation: a mirrored set
    of correspondences cannot be fitted by a reflection and shows as a large residual. With
    ``max_rms_m`` a fit worse than that raises :class:`RegistrationError`.
    """
    L = np.asarray(local_pts, dtype=np.float64)
    W = np.asarray(world_pts, dtype=np.float64)
    if L.ndim != 2 or L.shape[1] != 2 or L.shape != W.shape:
        raise RegistrationError(f"need two (N, 2) point arrays of equal shape, got {L.shape} and {W.shape}")
    if not (np.isfinite(L).all() and np.isfinite(W).all()):
        raise RegistrationError("point arrays contain NaN or inf (a point without depth?)")
    if len(L) < 2:
        raise RegistrationError(f"a rigid 2D fit needs at least 2 points, got {len(L)}")
    lc, wc = L.mean(axis=0), W.mean(axis=0)
    l0, w0 = L - lc, W - wc
    if np.max(np.linalg.norm(l0, axis=1)) < 1e-9:
        raise RegistrationError("all local points coincide: the rotation is undetermined")
    cross = np.sum(l0[:, 0] * w0[:, 1] - l0[:, 1] * w0[:, 0])
    dot = np.sum(l0[:, 0] * w0[:, 0] + l0[:, 1] * w0[:, 1])
    theta = math.atan2(cross, dot)
    c, s = math.cos(theta), math.sin(theta)
    R = np.array([[c, -s], [s, c]])
    M = _homogeneous(theta, wc - R @ lc)
    res = np.linalg.norm(local_to_world(M, L) - W, axis=1)
    rms = float(np.sqrt(np.mean(res**2)))
    if max_rms_m is not None and rms > max_rms_m:
        worst = int(np.argmax(res))
        raise RegistrationError(
            f"rigid fit residual {rms * 1000:.2f} mm RMS exceeds {max_rms_m * 1000:.2f} mm "
            f"(worst: point {worst}, {res[worst] * 1000:.2f} mm); check the correspondences"
        )
    return RigidFit2D(M_local2world=M, rms_m=rms, residuals_m=res)


# -- Eq. 3 ----------------------------------------------------------------------------------------
def _check_triangle(P: np.ndarray, what: str, min_separation_m: float, min_angle_deg: float) -> None:
    names = ("O", "A", "B")
    for i, j in ((0, 1), (0, 2), (1, 2)):
        dist = float(np.linalg.norm(P[j] - P[i]))
        if dist < min_separation_m:
            raise RegistrationError(
                f"{what} marks {names[i]} and {names[j]} coincide ({dist * 1000:.2f} mm apart, need >= "
                f"{min_separation_m * 1000:.1f} mm): one circle was taken for two marks"
            )
    angle = _angle_deg(P[1] - P[0], P[2] - P[0])
    if not (min_angle_deg < angle < 180.0 - min_angle_deg):
        raise RegistrationError(
            f"{what} marks O, A, B are nearly collinear (angle AOB = {angle:.1f} deg, need between "
            f"{min_angle_deg:.0f} and {180 - min_angle_deg:.0f} deg): their frame is undetermined"
        )


def _angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between two 2D or 3D vectors, degrees in [0, 180]."""
    a3, b3 = np.r_[a, 0.0][:3], np.r_[b, 0.0][:3]
    return math.degrees(math.atan2(np.linalg.norm(np.cross(a3, b3)), float(a3 @ b3)))


def _turn(a: np.ndarray, b: np.ndarray) -> float:
    """z of the 2D cross product a x b: > 0 when b lies counter-clockwise of a (seen from +z)."""
    return float(a[0] * b[1] - a[1] * b[0])


def _mark_frame(O: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Eq. 3, orthonormalised: 3x3 frame at O whose rotation is closest to [OA/|OA|, OB/|OB|]."""
    ex = (A - O) / np.linalg.norm(A - O)
    ey = (B - O) / np.linalg.norm(B - O)
    # Closest rotation to the 2x2 [[ex0, ey0], [ex1, ey1]] (polar decomposition, closed form in 2D).
    theta = math.atan2(ex[1] - ey[0], ex[0] + ey[1])
    return _homogeneous(theta, O)


def registration_from_marks(
    O_w,
    A_w,
    B_w,
    drawing_marks=None,
    tol_m: float = 0.003,
    method: Literal["eq3", "least_squares"] = "eq3",
    min_separation_m: float = 0.005,
    min_angle_deg: float = 10.0,
) -> MarkRegistration:
    """:class:`MarkRegistration` from the world positions of marks O, A, B (each (2,) or (3,), metres).

    ``drawing_marks``: (3, 2) O, A, B in the drawing (metres); then |OA|, |OB|, |AB| measured in
    world (3D when z is given, so a mark lifted with a wrong depth is caught) must agree with the
    drawing within ``tol_m``, and the triangle must have the drawing's handedness. Without it,
    the drawing frame is the paper's: origin O, x toward A, y toward B. ``method``: ``eq3``
    (paper Eq. 3, orthonormalised) or ``least_squares`` (:func:`fit_rigid_2d` on the three marks).

    Raises :class:`RegistrationError` for coincident or collinear marks, a mirrored triangle,
    or distances that disagree with the drawing (measured and expected values in mm).
    """
    Pw = _measured_marks(O_w, A_w, B_w)
    if method not in ("eq3", "least_squares"):
        raise RegistrationError(f"method must be 'eq3' or 'least_squares', got {method!r}")
    _check_triangle(Pw, "measured", min_separation_m, min_angle_deg)
    xy = Pw[:, :2]
    measured = np.array([np.linalg.norm(Pw[1] - Pw[0]), np.linalg.norm(Pw[2] - Pw[0]), np.linalg.norm(Pw[2] - Pw[1])])
    turn_w = _turn(xy[1] - xy[0], xy[2] - xy[0])
    if drawing_marks is None:
        D, dist_err, scale_error = _paper_drawing(measured, turn_w)
    else:
        D, dist_err, scale_error = _checked_drawing(drawing_marks, measured, turn_w, tol_m, min_separation_m,
                                                    min_angle_deg)

    if method == "eq3":
        M = _mark_frame(*xy) @ np.linalg.inv(_mark_frame(*D))
        res = np.linalg.norm(local_to_world(M, D) - xy, axis=1)
        residual = float(np.sqrt(np.mean(res**2)))
    else:
        fit = fit_rigid_2d(D, xy)
        M, residual, res = fit.M_local2world, fit.rms_m, fit.residuals_m
    return MarkRegistration(
        M_local2world=M,
        marks_world_m=Pw,
        marks_drawing_m=D,
        residual_m=residual,
        angle_AOB_deg=_angle_deg(xy[1] - xy[0], xy[2] - xy[0]),
        distance_errors_m=dist_err,
        scale_error=scale_error,
        method=method,
        marks_used_world_m=Pw,
        marks_used_drawing_m=D,
        mark_residuals_m=res,
        residual_max_m=float(res.max()),
    )


def _measured_marks(O_w, A_w, B_w) -> np.ndarray:
    """(3, 3) world O, A, B from three (2,) or (3,) points (z = 0 when not given)."""
    marks = []
    for name, p in zip("OAB", (O_w, A_w, B_w)):
        p = np.asarray(p, dtype=np.float64).ravel()
        if p.shape not in ((2,), (3,)) or not np.isfinite(p).all():
            raise RegistrationError(f"mark {name} must be a finite (x, y) or (x, y, z) in metres, got {p.tolist()}")
        marks.append(np.r_[p, 0.0] if p.size == 2 else p)
    return np.array(marks)


def _paper_drawing(measured: np.ndarray, turn_w: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(drawing marks, distance errors, scale error) without a drawing: the paper's frame (origin O, x
    toward A, y toward B) with the measured lengths; the marks must turn counter-clockwise."""
    D = np.array([[0.0, 0.0], [measured[0], 0.0], [0.0, measured[1]]])
    if turn_w < 0:
        raise RegistrationError(
            "marks are mirrored: seen from above, B lies clockwise of A around O, but the drawing frame "
            "(x toward A, y toward B) needs it counter-clockwise; is the board upside down, or A and B swapped?"
        )
    return D, np.full(3, np.nan), float("nan")


def _checked_drawing(drawing_marks, measured: np.ndarray, turn_w: float, tol_m: float, min_separation_m: float,
                     min_angle_deg: float) -> tuple[np.ndarray, np.ndarray, float]:
    """(drawing marks (3, 2), measured minus drawing |OA|, |OB|, |AB|, largest relative error) when the
    measured marks agree with the drawing's triangle: its handedness and distances within ``tol_m``."""
    D = np.asarray(drawing_marks, dtype=np.float64)
    if D.shape != (3, 2) or not np.isfinite(D).all():
        raise RegistrationError(f"drawing_marks must be a finite (3, 2) array O, A, B, got shape {D.shape}")
    _check_triangle(D, "drawing", min_separation_m, min_angle_deg)
    turn_d = _turn(D[1] - D[0], D[2] - D[0])
    if np.sign(turn_w) != np.sign(turn_d):
        raise RegistrationError(
            "marks are mirrored relative to the drawing (the sign of OA x OB differs): "
            "is the board upside down, or are A and B swapped?"
        )
    expected = np.array([np.linalg.norm(D[1] - D[0]), np.linalg.norm(D[2] - D[0]), np.linalg.norm(D[2] - D[1])])
    dist_err = measured - expected
    scale_error = float(np.max(np.abs(dist_err) / expected))
    bad = np.abs(dist_err) > tol_m
    if bad.any():
        detail = ", ".join(
            f"{n} measured {m * 1000:.1f} mm vs {e * 1000:.1f} mm in the drawing"
            for n, m, e, b in zip(_PAIR_NAMES, measured, expected, bad) if b
        )
        raise RegistrationError(
            f"mark distances disagree with the drawing beyond {tol_m * 1000:.1f} mm: {detail}; "
            "wrong board, a mis-detected mark, or a mark lifted with a wrong depth"
        )
    return D, dist_err, scale_error


def layout_marks_m(layout) -> np.ndarray:
    """(3, 2) marks O, A, B of a stud_welding_msgs/StudLayout message (``mark_o``, ``mark_a``,
    ``mark_b`` points), drawing frame, metres: what :func:`registration_from_marks` checks against."""
    return np.array([(m.x, m.y) for m in (layout.mark_o, layout.mark_a, layout.mark_b)], dtype=np.float64)



# -- every visible mark (a long part, registered station by station) ---------------------------------
BOARD_LABELS = ("O", "A", "B")


def fit_marks(labels, drawing_xy_m, world_m, board_drawing_m, max_residual_m: float | None = None,
              min_marks: int = 2, min_separation_m: float = 0.005) -> MarkRegistration:
    """Least-squares drawing -> world registration over any set of marks (paper Eq. 2, rigid, by
    :func:`fit_rigid_2d`): the board's O, A, B and the reference marks painted along the part.

    ``labels`` (L,) names each mark (``O``, ``A``, ``B``, ``M1``, ...); ``drawing_xy_m`` (L, 2) their
    drawing positions; ``world_m`` (L, 3) their measured world positions (Eq. 1). The drawing is the
    part's plan: a mark's drawing (x, y) is where it lies seen from above, whatever its height, so
    M_local2world maps drawing (x, y) to world (x, y) and the marks' heights (a cambered, sloped flange
    puts them at different z) are not part of the fit -- each mark's own z is measured. With the plane
    known that way, two marks fix the transform (``min_marks``; their distance is then the only check),
    three or more over-determine it. ``board_drawing_m`` (3, 2): O, A, B in the drawing, for
    ``marks_drawing_m``.

    Raises :class:`RegistrationError` with fewer than ``min_marks`` marks, coincident drawing marks,
    or (with ``max_residual_m``) a mark farther than that from where the fit puts it -- a wrong
    association (two marks swapped), a mis-detected mark or a mark lifted with a wrong depth; the
    message names the worst mark and its residual.
    """
    labels = tuple(str(lb) for lb in labels)
    D = np.asarray(drawing_xy_m, dtype=np.float64).reshape(-1, 2)
    W = np.asarray(world_m, dtype=np.float64).reshape(-1, 3)
    if not (len(labels) == len(D) == len(W)):
        raise RegistrationError(f"{len(labels)} labels, {len(D)} drawing and {len(W)} world positions: need one each")
    if len(set(labels)) != len(labels):
        raise RegistrationError(f"a mark is used twice: {', '.join(labels)}")
    if len(labels) < max(min_marks, 2):
        seen = ", ".join(labels) if labels else "none"
        raise RegistrationError(f"{len(labels)} mark(s) associated ({seen}), need {max(min_marks, 2)}")
    if not (np.isfinite(D).all() and np.isfinite(W).all()):
        raise RegistrationError("a mark has no position (NaN): one without depth?")
    spread = float(np.max(np.linalg.norm(D - D.mean(axis=0), axis=1)))
    if spread < min_separation_m:
        raise RegistrationError(f"the marks {', '.join(labels)} lie within {spread * 1000:.1f} mm of each other in the "
                                "drawing: their direction is undetermined")
    fit = fit_rigid_2d(D, W[:, :2])
    res = fit.residuals_m
    worst = int(np.argmax(res))
    if max_residual_m is not None and res[worst] > max_residual_m:
        raise RegistrationError(
            f"mark {labels[worst]} is {res[worst] * 1000:.1f} mm from where the fit over "
            f"{', '.join(labels)} puts it (limit {max_residual_m * 1000:.1f} mm; RMS {fit.rms_m * 1000:.1f} mm): "
            "a wrong association (marks swapped?), a mis-detected mark or a wrong depth; refused"
        )
    board = np.asarray(board_drawing_m, dtype=np.float64).reshape(3, 2)
    oab_w = np.full((3, 3), np.nan)
    for i, name in enumerate(BOARD_LABELS):
        if name in labels:
            oab_w[i] = W[labels.index(name)]
    angle = _angle_deg(oab_w[1, :2] - oab_w[0, :2], oab_w[2, :2] - oab_w[0, :2]) if np.isfinite(oab_w).all() \
        else float("nan")
    return MarkRegistration(
        M_local2world=fit.M_local2world, marks_world_m=oab_w, marks_drawing_m=board, residual_m=fit.rms_m,
        angle_AOB_deg=angle, distance_errors_m=np.full(3, np.nan), scale_error=float("nan"), method="least_squares",
        labels_used=labels, marks_used_world_m=W, marks_used_drawing_m=D, mark_residuals_m=res,
        residual_max_m=float(res[worst]),
    )


def layout_reference_marks_m(layout) -> dict[str, np.ndarray]:
    """The reference marks of a stud_welding_msgs/StudLayout message (``reference_mark_labels``,
    ``reference_marks``): label -> drawing (x, y), metres, in the layout's order; {} for a layout
    without them (or a message from before they existed)."""
    labels = list(getattr(layout, "reference_mark_labels", []))
    points = list(getattr(layout, "reference_marks", []))
    if len(labels) != len(points):
        raise RegistrationError(f"layout has {len(labels)} reference mark labels but {len(points)} positions")
    return {str(lb): np.array([p.x, p.y], dtype=np.float64) for lb, p in zip(labels, points)}
