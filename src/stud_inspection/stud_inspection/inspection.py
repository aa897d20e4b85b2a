"""Post-weld inspection: measure every welded stud in 3D and judge it against the code.

After a station's welds the camera shoots the station again, from the same pose. A welded stud
is what is new in that shot: pixels whose depth came closer to the camera than in the shot before
the weld, standing above the part's surface there. The surface is the one the weld was planned on:
the target's weld point and normal from the shot before the weld (its tangent plane; over the few
centimetres a stud occupies a curved part departs from it by a fraction of a millimetre).

Per stud, from the points of its top cap -- the highest band of its new points, a robust plane
fit -- and its side come:
- the **axis**: the cap's normal (a stud's top face is perpendicular to its axis);
- the **base point**: where the axis through the cap's centre meets the surface;
- the **lean**: the angle between the axis and the surface normal;
- the **offset** of the base from the planned weld point, in the tangent plane (mm);
- the **standing height** above the surface along the axis (the burn-off check);
- the **collar** (flash) around its base: how much of the circle a collar of ``min_collar_height_mm``
  covers, of how much the camera sees, and its height (stud_inspection.collar).

Verdicts (:class:`Verdict`): ``pass``, ``fail`` (with the reasons: lean, offset, height, collar
beyond the limits), ``missing`` (the place is seen, nothing stands there), ``not_inspected`` (the
camera cannot judge: the stud's place outside the image, hidden behind something, no depth, its
cap partly cut off, too little of its collar seen -- with the reason; it never passes by default),
``not_welded``. New things that stand where no stud was planned are reported as unexpected objects.
The limits' values per stud-welding code are stud_inspection.qa_codes'.

Frames and units: `world`, metres in, millimetres and degrees in the results (as an inspector
reads them); depth images (H, W) metres, NaN = none. No ROS here.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field

import cv2
import numpy as np

from stud_common.rotations import float3, frame_from_normal
from stud_inspection.collar import CollarMeasurement, CollarSettings, measure_collar
from stud_perception.camera_model import CameraModel


class Verdict(str, enum.Enum):
    PASS = "pass"
    FAIL = "fail"
    MISSING = "missing"
    NOT_INSPECTED = "not_inspected"
    NOT_WELDED = "not_welded"


@dataclass(frozen=True)
class InspectionLimits:
    """What a good stud is, and how the camera looks for it (mm and degrees, as in a QA record).

    Judged: ``max_lean_deg`` (the code's 5 deg: the paper's Fig. 9, 13 mm top offset for an
    M16x150), ``position_tol_mm`` (the base's distance from the planned point), the height within
    ``height_tol_mm`` above and ``height_tol_below_mm`` (None: the same) below ``nominal_length_mm``
    (the stud's length after weld), a collar of at least ``min_collar_height_mm`` over
    ``min_collar_coverage_deg`` of the circle (0: no collar check) -- judged when the camera sees at
    least ``min_collar_seen_deg`` of it. Looking: ``stud_diameter_mm``; ``change_mm``: a pixel is new
    when it came this much closer and stands this much above the surface; ``min_cap_fraction`` of
    the cap's expected pixels must be seen to judge it; ``collar``: where the collar is looked for.
    """

    max_lean_deg: float = 5.0
    position_tol_mm: float = 2.0
    nominal_length_mm: float = 150.0
    height_tol_mm: float = 2.0
    stud_diameter_mm: float = 16.0
    search_offset_mm: float = 10.0
    search_lean_deg: float = 15.0
    change_mm: float = 5.0
    min_cap_fraction: float = 0.5
    min_cap_points: int = 30
    height_tol_below_mm: float | None = None
    min_collar_coverage_deg: float = 360.0
    min_collar_height_mm: float = 1.0
    min_collar_seen_deg: float = 180.0
    collar: CollarSettings = field(default_factory=CollarSettings)

    def __post_init__(self) -> None:
        for name in ("max_lean_deg", "position_tol_mm", "nominal_length_mm", "height_tol_mm", "stud_diameter_mm",
                     "search_offset_mm", "search_lean_deg", "change_mm", "min_collar_height_mm"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"inspection limit {name}={value}: expected a positive number")
        if self.height_tol_below_mm is not None and not (np.isfinite(self.height_tol_below_mm)
                                                         and self.height_tol_below_mm > 0):
            raise ValueError(f"inspection limit height_tol_below_mm={self.height_tol_below_mm}: expected a positive "
                             "number (or none: the same as height_tol_mm)")
        for name in ("min_collar_coverage_deg", "min_collar_seen_deg"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0 <= value <= 360):
                raise ValueError(f"inspection limit {name}={value}: expected degrees in [0, 360]")
        if not 0 < self.min_cap_fraction <= 1:
            raise ValueError(f"min_cap_fraction={self.min_cap_fraction}: expected a fraction in (0, 1]")

    @property
    def height_below_mm(self) -> float:
        """How far below the nominal length a stud may stand [mm]."""
        return self.height_tol_mm if self.height_tol_below_mm is None else self.height_tol_below_mm

    @property
    def checks_collar(self) -> bool:
        return self.min_collar_coverage_deg > 0

    def to_dict(self) -> dict:
        return {"max_lean_deg": self.max_lean_deg, "position_tol_mm": self.position_tol_mm,
                "nominal_length_mm": self.nominal_length_mm, "height_tol_mm": self.height_tol_mm,
                "height_tol_below_mm": self.height_below_mm, "stud_diameter_mm": self.stud_diameter_mm,
                "min_collar_coverage_deg": self.min_collar_coverage_deg,
                "min_collar_height_mm": self.min_collar_height_mm, "min_collar_seen_deg": self.min_collar_seen_deg}


@dataclass(frozen=True)
class StudMeasurement:
    """One stud's inspection; measured values are None when not measured."""

    verdict: Verdict
    reasons: tuple[str, ...] = ()
    position_m: tuple[float, float, float] | None = None  # the base point, world
    axis: tuple[float, float, float] | None = None        # unit, world, outward
    lean_deg: float | None = None
    offset_mm: tuple[float, float] | None = None          # (x, y) in the tangent frame at the planned point
    height_mm: float | None = None
    cap_points: int = 0
    collar: CollarMeasurement | None = None               # None: not measured (no stud, or no collar check)

    def measured_dict(self) -> dict | None:
        if self.position_m is None:
            return None
        assert self.axis is not None and self.offset_mm is not None  # measured together with the position
        return {"position_m": list(self.position_m), "axis": list(self.axis), "lean_deg": self.lean_deg,
                "offset_mm": list(self.offset_mm), "height_mm": self.height_mm, **collar_fields(self.collar)}


def collar_fields(c: CollarMeasurement | None) -> dict:
    """A collar measurement as the QA record's fields (all None when not measured)."""
    if c is None:
        return {"collar_seen_deg": None, "collar_coverage_deg": None, "collar_height_mm": None, "collar_gap_deg": None,
                "collar_gap_azimuth_deg": None}
    return {"collar_seen_deg": c.seen_deg, "collar_coverage_deg": c.covered_deg, "collar_height_mm": c.height_mm,
            "collar_gap_deg": c.gap_deg, "collar_gap_azimuth_deg": c.gap_azimuth_deg}


@dataclass(frozen=True)
class UnexpectedObject:
    """Something new standing where no stud was planned: its highest point (world), how far that
    stands above the part (along world z, mm) and its size in pixels."""

    position_m: tuple[float, float, float]
    height_mm: float
    pixels: int


@dataclass(frozen=True)
class Inspection:
    studs: tuple[StudMeasurement, ...]
    unexpected: tuple[UnexpectedObject, ...] = ()
    limits: InspectionLimits = field(default_factory=InspectionLimits)


def _robust_plane(X: np.ndarray, passes: int = 4, k: float = 3.0, floor_m: float = 0.0015):
    """Unit normal (3,), centroid (3,) and inlier mask of a robust PCA plane through X (n, 3).

    The rejection threshold never drops below ``floor_m``: depth quantised to the millimetre puts
    most residuals of a nearly flat patch at 0, and a threshold from their median would keep a
    single quantisation level -- a plane tilted to nothing."""
    inl = np.ones(len(X), dtype=bool)
    for _ in range(passes):
        c = X[inl].mean(axis=0)
        _, vecs = np.linalg.eigh(np.cov((X[inl] - c).T))
        n = vecs[:, 0]
        r = np.abs((X - c) @ n)
        thr = max(k * 1.4826 * float(np.median(r[inl])), floor_m)
        new = r <= thr
        if new.sum() < 3 or np.array_equal(new, inl):
            break
        inl = new
    c = X[inl].mean(axis=0)
    return n, c, inl


def _circle_centre(q: np.ndarray, sectors: int = 24) -> np.ndarray | None:
    """Centre (2,) of a disc from its points q (k, 2) (roughly centred on 0): a least-squares circle
    through its edge -- in each angular sector the outermost point. The edge, unlike the points'
    centroid, does not move when part of the disc's area is missed or a sliver of the stud's side
    is caught at the rim (it lies at the radius too)."""
    ang = np.arctan2(q[:, 1], q[:, 0])
    rad = np.hypot(q[:, 0], q[:, 1])
    sector = np.floor((ang + np.pi) / (2 * np.pi) * sectors).astype(int) % sectors
    edge = []
    for k in range(sectors):
        m = sector == k
        if m.any():
            edge.append(q[m][np.argmax(rad[m])])
    if len(edge) < sectors * 2 // 3:
        return None
    E = np.asarray(edge)
    A = np.column_stack([2 * E, np.ones(len(E))])
    sol, *_ = np.linalg.lstsq(A, (E**2).sum(axis=1), rcond=None)
    return sol[:2]


def _top_cap(X: np.ndarray, h: np.ndarray, n: np.ndarray, radius: float, iterations: int = 4):
    """The stud's top cap among its points X (k, 3) (heights h above the surface along n): its unit
    normal (the stud's axis, outward), centre and points.

    The cap is the disc at the top of the stud, perpendicular to its axis; a camera that sees the
    stud from aside sees its side too, up to the rim. So the cap's plane is fitted to the points
    near the top *along the current axis estimate* and within 0.9 radius of it (the side lies at the
    radius), its centre is the circle through the cap's edge (:func:`_circle_centre`), and both are
    refined a few times, starting from the surface normal and the top points' centroid."""
    top = h > h.max() - 0.004
    centre = X[top].mean(axis=0)
    axis = n
    half_band = None
    cap = top
    for _ in range(iterations):
        s = (X - centre) @ axis
        d = X - centre - s[:, None] * axis
        radial = np.linalg.norm(d, axis=1)
        inner = radial < 0.9 * radius
        if half_band is None:  # the first cut, from the top, is generous; later ones are symmetric
            cap = inner & (s > s[inner].max(initial=0.0) - 0.006)
        else:  # about the cap's plane: a one-sided cut would keep the noise on one side
            cap = inner & (np.abs(s) < half_band)
        if cap.sum() < 3:
            break
        axis, c_plane, inl = _robust_plane(X[cap])
        axis = axis if axis @ n > 0 else -axis
        half_band = max(3.0 * 1.4826 * float(np.median(np.abs((X[cap] - c_plane) @ axis))), 0.0015)
        centre = centre + ((c_plane - centre) @ axis) * axis  # onto the cap's plane
        # the whole cap (in the plane's band, out to the radius and a little) for its edge
        s = (X - centre) @ axis
        d = X - centre - s[:, None] * axis
        disc = (np.abs(s) < half_band) & (np.linalg.norm(d, axis=1) < radius + 0.002)
        R = frame_from_normal(axis)
        q = d[disc] @ R[:, :2]
        found = _circle_centre(q)
        if found is not None:
            centre = centre + R[:, :2] @ found
    return axis, centre, X[cap]


def _refine_with_side(X: np.ndarray, cap: np.ndarray, axis: np.ndarray, centre: np.ndarray, radius: float,
                      iterations: int = 6, min_side_points: int = 40, min_span_m: float = 0.015):
    """The stud's axis and cap centre refined by its side as well as its cap: (axis, centre).

    The cap alone is a 16 mm disc: its normal -- the axis -- is what the noise moves most, and the
    base point, found down the axis a stud length away, moves with it (at 0.5 mm depth noise
    correlated over 1.5 px, 1-2 deg of axis and 1-1.8 mm of base on a 50 mm stud). Where the camera
    sees the stud's side along enough of its length (``min_span_m``, ``min_side_points``), the axis
    is fitted to both: the cap points ``cap`` (k, 3) on a plane perpendicular to it, the side points
    of X at the stud's radius from it (Gauss-Newton over the axis' two tilts and the centre's three
    coordinates, side points beyond 3 MAD dropped). Else the cap's own estimate stands."""
    for _ in range(2):  # the side, about the current estimate; once more about the refined one
        s = (X - centre) @ axis
        radial = np.linalg.norm(X - centre - s[:, None] * axis, axis=1)
        side = X[(s < -0.004) & (np.abs(radial - radius) < 0.002)]
        if len(side) < min_side_points or float(np.ptp((side - centre) @ axis)) < min_span_m:
            return axis, centre
        R = frame_from_normal(axis)
        e1, e2 = R[:, 0], R[:, 1]

        def residuals(theta: np.ndarray, side_pts: np.ndarray) -> np.ndarray:
            a = axis + theta[0] * e1 + theta[1] * e2
            a = a / np.linalg.norm(a)
            c = centre + theta[2] * e1 + theta[3] * e2 + theta[4] * axis
            d = side_pts - c
            t = d @ a
            return np.concatenate([(cap - c) @ a, np.linalg.norm(d - t[:, None] * a, axis=1) - radius])

        theta = np.zeros(5)
        for _ in range(iterations):
            r = residuals(theta, side)
            J = np.empty((r.size, 5))
            for k in range(5):
                step = np.zeros(5)
                step[k] = 1e-6
                J[:, k] = (residuals(theta + step, side) - r) / 1e-6
            delta = np.linalg.lstsq(J, -r, rcond=None)[0]
            theta = theta + delta
            if np.max(np.abs(delta)) < 1e-9:
                break
        r_side = residuals(theta, side)[len(cap):]
        keep = np.abs(r_side) <= max(3.0 * 1.4826 * float(np.median(np.abs(r_side))), 0.001)
        side = side[keep]
        a = axis + theta[0] * e1 + theta[1] * e2
        axis, centre = a / np.linalg.norm(a), centre + theta[2] * e1 + theta[3] * e2 + theta[4] * axis
    return axis, centre


def _cylinder_box(camera: CameraModel, p: np.ndarray, n: np.ndarray, radius_m: float, length_m: float):
    """Pixel box (u0, u1, v0, v1) of the search cylinder (radius, length along n from p), clipped to
    the image, and whether the stud's base and top (a good stud's) project inside the image; None when
    the cylinder's place is not in front of the camera."""
    R = frame_from_normal(n)
    ring = np.array([[np.cos(a), np.sin(a)] for a in np.linspace(0, 2 * np.pi, 12, endpoint=False)])
    pts = np.vstack([p + radius_m * ring @ R[:, :2].T, p + length_m * n + radius_m * ring @ R[:, :2].T])
    u, v, z = camera.world_to_pixel(pts)
    ends_u, ends_v, ends_z = camera.world_to_pixel(np.vstack([p, p + length_m / 1.3 * n]))
    if np.any(ends_z <= 0):
        return None
    good = np.isfinite(u) & np.isfinite(v) & (z > 0)
    u, v = np.clip(u[good], 0, camera.width), np.clip(v[good], 0, camera.height)
    box = (int(np.floor(u.min())), int(np.ceil(u.max())) + 1, int(np.floor(v.min())), int(np.ceil(v.max())) + 1)
    box = (max(box[0], 0), min(box[1], camera.width), max(box[2], 0), min(box[3], camera.height))
    inside = bool(np.all(camera.in_image(ends_u, ends_v, margin=8.0)))
    return box, inside


def _new_points(before: np.ndarray, after: np.ndarray, box, change_m: float):
    """Pixels of ``box`` whose depth came ``change_m`` closer (or appeared), with their (u, v, depth)."""
    u0, u1, v0, v1 = box
    b, a = before[v0:v1, u0:u1], after[v0:v1, u0:u1]
    with np.errstate(invalid="ignore"):
        new = np.isfinite(a) & (a > 0) & (~np.isfinite(b) | (b <= 0) | (a < b - change_m))
    vv, uu = np.nonzero(new)
    return uu + u0, vv + v0, a[vv, uu]


@dataclass
class _Look:
    """The new points about one stud's planned axis (all (k,) arrays but the box)."""

    box: tuple
    whole: bool
    u: np.ndarray
    v: np.ndarray
    X: np.ndarray
    h: np.ndarray
    score: np.ndarray  # distance from the planned axis over the search cone's radius there (< 1: inside)


def _look(p, n, before, after, camera: CameraModel, lim: InspectionLimits) -> _Look | None:
    length = lim.nominal_length_mm * 1e-3
    radius = lim.stud_diameter_mm * 0.5e-3
    reach = radius + lim.search_offset_mm * 1e-3 + 1.3 * length * np.tan(np.radians(lim.search_lean_deg))
    found = _cylinder_box(camera, p, n, reach, 1.3 * length)
    if found is None:
        return None
    box, whole = found
    u, v, d = _new_points(before, after, box, lim.change_mm * 1e-3)
    X = camera.pixel_to_world(u.astype(np.float64), v.astype(np.float64), d) if u.size else np.zeros((0, 3))
    h = (X - p) @ n
    rho = np.linalg.norm(X - p - h[:, None] * n, axis=1)
    cone = radius + lim.search_offset_mm * 1e-3 + np.maximum(h, 0.0) * np.tan(np.radians(lim.search_lean_deg))
    inside = (h > -lim.change_mm * 1e-3) & (h < 1.5 * length)  # its foot, below the change threshold, too
    return _Look(box, whole, u, v, X, h, np.where(inside, rho / cone, np.inf))


def _collar_verdict(c: CollarMeasurement, lim: InspectionLimits) -> tuple[str | None, str | None]:
    """(a fail reason, a reason it cannot be judged) of a measured collar; (None, None): it passes."""
    if c.seen_deg < lim.min_collar_seen_deg:
        return None, (f"collar: only {c.seen_deg:.0f} deg of it seen (the rest hidden behind the stud), "
                      f"{lim.min_collar_seen_deg:g} deg needed to judge it")
    if c.covered_deg == 0:
        highest = np.nanmax(c.sector_heights_mm)
        return f"no collar of {lim.min_collar_height_mm:g} mm seen (at most {highest:.1f} mm high)", None
    if c.uncovered_seen_deg > 360.0 - lim.min_collar_coverage_deg:
        return (f"collar {c.covered_deg:.0f} deg of the {c.seen_deg:.0f} deg seen: a {c.gap_deg:.0f} deg gap "
                f"({lim.min_collar_coverage_deg:g} deg of at least {lim.min_collar_height_mm:g} mm required)"), None
    return None, None


def _judge_one(p, n, look: _Look, mine: np.ndarray, before, after, camera: CameraModel,
               lim: InspectionLimits) -> StudMeasurement:
    """One stud from its own new points (``mine``: the ones nearer its axis than any other stud's)."""
    length = lim.nominal_length_mm * 1e-3
    radius = lim.stud_diameter_mm * 0.5e-3
    if not look.whole:
        return StudMeasurement(Verdict.NOT_INSPECTED, ("at the image border: its place is partly outside the image",))
    mine = mine & (look.h > lim.change_mm * 1e-3)
    if mine.sum() < lim.min_cap_points:
        # Missing only where the camera sees the place free: the weld point and where a good stud's
        # top would be. Something closer than either, on the line of sight, hides the place.
        for what, point in (("weld point", p), ("top", p + length * n)):
            pu, pv, pz = camera.world_to_pixel(point)
            r_px = max(2, int(radius * camera.fx / max(float(pz), 1e-6)))
            ui, vi = int(round(float(pu))), int(round(float(pv)))
            patch = after[max(vi - r_px, 0):vi + r_px + 1, max(ui - r_px, 0):ui + r_px + 1]
            valid = patch[np.isfinite(patch) & (patch > 0)]
            if valid.size < 0.3 * patch.size:
                return StudMeasurement(Verdict.NOT_INSPECTED, (f"no depth where the stud's {what} should be",))
            if np.mean(valid < float(pz) - 0.01) > 0.3:
                return StudMeasurement(Verdict.NOT_INSPECTED, (f"hidden behind another object (its {what})",))
        return StudMeasurement(Verdict.MISSING, ("no stud stands at the weld point",))
    a, c, cap_pts = _top_cap(look.X[mine], look.h[mine], n, radius)
    a, c = _refine_with_side(look.X[mine], cap_pts, a, c, radius)
    # the cap must be seen nearly whole, or its centre (and so the base) is biased
    dist = float(np.linalg.norm(camera.world_to_camera(c[None])[0]))
    view_cos = abs(float(a @ (camera.position_w - c))) / max(dist, 1e-9)
    expected = np.pi * (radius * camera.fx / max(float(camera.world_to_camera(c[None])[0, 2]), 1e-6)) ** 2 * view_cos
    expected *= 0.81  # the inner disc, 0.9 of the radius, is what the cap fit uses
    if len(cap_pts) < max(lim.min_cap_points, lim.min_cap_fraction * expected):
        return StudMeasurement(Verdict.NOT_INSPECTED,
                               (f"its top is only partly seen ({len(cap_pts)} of ~{expected:.0f} "
                                "points: hidden or cut off)",), cap_points=len(cap_pts))
    cos_an = float(a @ n)
    h_base = float((c - p) @ n) / cos_an
    base = c - h_base * a
    R = frame_from_normal(n)
    off = (base - p) @ R[:, :2] * 1e3
    lean = float(np.degrees(np.arccos(np.clip(cos_an, -1.0, 1.0))))
    height = h_base * 1e3
    reasons = []
    if lean > lim.max_lean_deg:
        reasons.append(f"lean {lean:.1f} deg > {lim.max_lean_deg:g} deg")
    if np.hypot(*off) > lim.position_tol_mm:
        reasons.append(f"offset {np.hypot(*off):.1f} mm > {lim.position_tol_mm:g} mm")
    if not -lim.height_below_mm <= height - lim.nominal_length_mm <= lim.height_tol_mm:
        tol = (f"+- {lim.height_tol_mm:g}" if lim.height_below_mm == lim.height_tol_mm
               else f"+{lim.height_tol_mm:g}/-{lim.height_below_mm:g}")
        reasons.append(f"height {height:.1f} mm, expected {lim.nominal_length_mm:g} {tol} mm")
    collar, unjudged = None, None
    if lim.checks_collar:
        collar = measure_collar(before, after, camera, base, a, n, radius, lim.min_collar_height_mm, lim.collar)
        fail, unjudged = _collar_verdict(collar, lim)
        if fail:
            reasons.append(fail)
    verdict = Verdict.FAIL if reasons else Verdict.NOT_INSPECTED if unjudged else Verdict.PASS
    return StudMeasurement(verdict, tuple(reasons) or ((unjudged,) if unjudged else ()),
                           float3(base), float3(a), lean, (float(off[0]), float(off[1])),
                           height, len(cap_pts), collar)


def inspect_studs(planned_w: np.ndarray, normals_w: np.ndarray, welded: np.ndarray, before_depth_m: np.ndarray,
                  after_depth_m: np.ndarray, camera: CameraModel,
                  limits: InspectionLimits = InspectionLimits(), min_object_px: int = 40) -> Inspection:
    """Inspect N studs planned at ``planned_w`` (N, 3) on surfaces of unit normals ``normals_w``
    (N, 3); ``welded`` (N,) which the arm welded; the depth of the same camera pose before and
    after the welds (H, W metres, NaN = none). Returns a measurement per stud, in order, and the
    unexpected objects (new things of ``min_object_px`` or more pixels no planned stud explains).

    Every new pixel belongs to the one welded stud whose planned axis it lies nearest (relative to
    the search cone there): a neighbour's body is never taken for a stud's own, so a stud hidden
    behind another is not judged by the other's top."""
    P = np.asarray(planned_w, dtype=np.float64).reshape(-1, 3)
    N = np.asarray(normals_w, dtype=np.float64).reshape(-1, 3)
    before = np.asarray(before_depth_m, dtype=np.float64)
    after = np.asarray(after_depth_m, dtype=np.float64)
    welded = np.asarray(welded, dtype=bool)
    usable = welded & np.all(np.isfinite(P), axis=1) & np.all(np.isfinite(N), axis=1)
    looks: dict[int, _Look | None] = {}
    best = np.full(after.shape, np.inf)
    for i in map(int, np.flatnonzero(usable)):
        look = looks[i] = _look(P[i], N[i] / np.linalg.norm(N[i]), before, after, camera, limits)
        if look is not None:
            np.minimum.at(best, (look.v, look.u), look.score)
    taken = np.isfinite(best) & (best < 1.0)
    out = []
    for i in range(len(P)):
        if not welded[i]:
            out.append(StudMeasurement(Verdict.NOT_WELDED))
        elif not usable[i]:
            out.append(StudMeasurement(Verdict.NOT_INSPECTED, ("no planned weld pose to compare with",)))
        elif looks[i] is None:
            out.append(StudMeasurement(Verdict.NOT_INSPECTED, ("its place is not in front of the camera",)))
        elif (look := looks[i]) is not None:
            mine = (look.score < 1.0) & (look.score <= best[look.v, look.u])
            out.append(_judge_one(P[i], N[i] / np.linalg.norm(N[i]), look, mine, before, after, camera, limits))
    return Inspection(tuple(out), _unexpected(before, after, taken, camera, limits, min_object_px), limits)


def _unexpected(before, after, taken, camera: CameraModel, lim: InspectionLimits, min_px: int):
    """New things no stud explains: connected regions of pixels that came closer, not claimed by a stud."""
    with np.errstate(invalid="ignore"):
        new = np.isfinite(after) & np.isfinite(before) & (after < before - lim.change_mm * 1e-3) & ~taken
    count, labels, stats, _ = cv2.connectedComponentsWithStats(new.astype(np.uint8), connectivity=8)
    found = []
    for k in range(1, count):
        if stats[k, cv2.CC_STAT_AREA] < min_px:
            continue
        vv, uu = np.nonzero(labels == k)
        X = camera.pixel_to_world(uu.astype(np.float64), vv.astype(np.float64), after[vv, uu])
        Xb = camera.pixel_to_world(uu.astype(np.float64), vv.astype(np.float64), before[vv, uu])
        rise = X[:, 2] - Xb[:, 2]  # how far it stands above the part, along world z
        top = X[int(np.argmax(rise))]
        found.append(UnexpectedObject(float3(top), float(rise.max() * 1e3), int(len(uu))))
    return tuple(found)


#: Overlay colours (BGR) per verdict.
VERDICT_BGR = {Verdict.PASS: (40, 200, 40), Verdict.FAIL: (0, 0, 230), Verdict.MISSING: (200, 0, 200),
               Verdict.NOT_INSPECTED: (0, 200, 255), Verdict.NOT_WELDED: (160, 160, 160)}


def draw_inspection_overlay(color_bgr: np.ndarray, ids: list[str], planned_w: np.ndarray, inspection: Inspection,
                            camera: CameraModel) -> np.ndarray:
    """The shot after the welds with every stud outlined at its planned weld point and coloured by
    its verdict, its lean and offset printed; unexpected objects crossed out in red."""
    img = color_bgr.copy()
    scale = max(1.0, img.shape[1] / 1280)
    for sid, p, m in zip(ids, np.asarray(planned_w, dtype=np.float64).reshape(-1, 3), inspection.studs):
        u, v, z = camera.world_to_pixel(p)
        if not (np.isfinite(u) and np.isfinite(v)):
            continue
        colour = VERDICT_BGR[m.verdict]
        centre = (int(round(float(u))), int(round(float(v))))
        r = int(max(6, inspection.limits.stud_diameter_mm * 0.5e-3 * camera.fx / max(float(z), 1e-6)))
        cv2.circle(img, centre, r, colour, 2, cv2.LINE_AA)
        text = f"{sid} {m.verdict.value}"
        if m.lean_deg is not None and m.offset_mm is not None:
            text += f" {m.lean_deg:.1f}deg {np.hypot(*m.offset_mm):.1f}mm"
        cv2.putText(img, text, (centre[0] + r + 3, centre[1]), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * scale, colour, 1,
                    cv2.LINE_AA)
    for obj in inspection.unexpected:
        u, v, _ = camera.world_to_pixel(np.asarray(obj.position_m))
        if np.isfinite(u) and np.isfinite(v):
            c, k = (int(u), int(v)), int(12 * scale)
            cv2.line(img, (c[0] - k, c[1] - k), (c[0] + k, c[1] + k), (0, 0, 255), 2, cv2.LINE_AA)
            cv2.line(img, (c[0] - k, c[1] + k), (c[0] + k, c[1] - k), (0, 0, 255), 2, cv2.LINE_AA)
            cv2.putText(img, "unexpected", (c[0] + k, c[1]), cv2.FONT_HERSHEY_SIMPLEX, 0.45 * scale, (0, 0, 255), 1,
                        cv2.LINE_AA)
    return img


__all__ = ["Inspection", "InspectionLimits", "StudMeasurement", "UnexpectedObject", "VERDICT_BGR", "Verdict",
           "collar_fields", "draw_inspection_overlay", "inspect_studs"]
