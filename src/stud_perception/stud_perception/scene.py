"""Deterministic synthetic RGB-D scenes with exact ground truth: the scene description.

Used by the tests, the benchmarks, the simulated camera node and the demo. A scene is the
paper's set-up: a working plane (world z = 0, z up, metres), a marking board (a flat raised
plate carrying the dark circular marks O, A, B) and one curved steel component (a dome, a
horizontal cylinder section, a trough, a cambered girder flange, a tilted plate or a flat plate)
with the stud positions drawn on it as small dark circles or crosses, and optionally reference
marks (dark discs like O, A, B) painted along a long part. docs/SCENES.md has the file form.

Frames: the drawing frame has its origin at mark O, x toward A, y toward B (metres); the
board is printed in that frame and ``SceneSpec.drawing_to_world`` (a 2D rigid pose) places it
on the working plane, so the true ``M_local2world`` of a scene is exactly that pose. Stud
positions are given in the drawing frame, as in a layout drawing.

The synthetic scene in modules by concern:

- ``scene_solids``: :class:`~stud_perception.scene_solids.Pose2D`, the solids (``Dome``,
  ``Cylinder``, ``Trough``, ``Girder``, ``Plate``) and :class:`~stud_perception.scene_solids.SceneError`;
- ``scene`` (this module): :class:`MarkingBoard`, :class:`ReferenceMark`, :class:`SceneSpec`, the exact top surface
  (:func:`surface_height`, :func:`surface_normal`) and the bundled scenes;
- ``scene_file``: the plain-dict / JSON / YAML form (``scene_from_dict``, ``load_scene``);
- ``scene_render``: the ray caster (``render``, ``RenderedView``), shading and painted marks;
- ``scene_sensor``: what the RGB-D sensor does to the ideal view (depth noise, holes, specular
  dropout);
- ``scene_cameras``: cameras for synthetic views (``view_camera``, ``demo_camera``) and lens
  distortion (``distort_view``).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from stud_perception.scene_solids import Component, Dome, Girder, Plate, Pose2D, SceneError, finite_pair
from stud_perception.welded_studs import (
    DEFAULT_COLLAR_HEIGHT_M,
    DEFAULT_COLLAR_WIDTH_M,
    DEFAULT_STUD_DIAMETER_M,
    DEFAULT_STUD_LENGTH_M,
)

# Surface ids of :attr:`stud_perception.scene_render.RenderedView.surface_id`.
SURFACE_NONE = -1
SURFACE_TABLE = 0
SURFACE_BOARD = 1
SURFACE_COMPONENT = 2
SURFACE_OBSTACLE = 3
SURFACE_STUD = 4  # a welded stud (stud_perception.welded_studs)
SURFACE_COLLAR = 5  # a welded stud's weld collar (flash)


# -- scene description ------------------------------------------------------------------------
@dataclass(frozen=True)
class MarkingBoard:
    """The marking board: a flat plate of ``thickness_m`` with dark filled circles O, A, B of
    ``mark_diameter_m`` at ``marks_drawing_m`` (drawing frame, metres, rows O, A, B). The plate
    covers the marks' bounding box plus ``margin_m`` beyond each mark's edge."""

    marks_drawing_m: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.13, 0.0), (0.0, 0.10))
    mark_diameter_m: float = 0.02
    thickness_m: float = 0.005
    margin_m: float = 0.012

    def __post_init__(self) -> None:
        marks = np.asarray(self.marks_drawing_m, dtype=np.float64)
        if marks.shape != (3, 2):
            raise SceneError(f"board marks_drawing_m must be 3 (x, y) pairs O, A, B, got shape {marks.shape}")
        object.__setattr__(self, "marks_drawing_m", tuple(tuple(float(c) for c in m) for m in marks))
        if self.mark_diameter_m <= 0 or self.thickness_m <= 0 or self.margin_m < 0:
            raise SceneError(
                f"board needs positive mark_diameter_m and thickness_m, margin_m >= 0, got "
                f"{self.mark_diameter_m}, {self.thickness_m}, {self.margin_m}"
            )


@dataclass(frozen=True)
class ReferenceMark:
    """A reference mark painted on the part (or the table) beside the board's O, A, B: a dark disc
    of the board marks' diameter centred at ``drawing_xy_m`` (drawing frame, metres), named
    ``label`` (``M1``, ``M2``, ... in a drawing)."""

    label: str
    drawing_xy_m: tuple[float, float]

    def __post_init__(self) -> None:
        if not isinstance(self.label, str) or not self.label.strip() or self.label.strip() in ("O", "A", "B"):
            raise SceneError(f"reference_marks label must be a name other than O, A, B (e.g. 'M1'), got "
                             f"{self.label!r}")
        object.__setattr__(self, "label", self.label.strip())
        object.__setattr__(self, "drawing_xy_m",
                           finite_pair(self.drawing_xy_m, f"reference_marks {self.label} drawing_xy_m"))


@dataclass(frozen=True)
class SceneSpec:
    """Everything a view of the work cell shows (world frame, metres).

    ``drawing_to_world`` places the drawing frame (and with it the board) on the plane;
    ``studs_drawing_m`` (N, 2) are stud positions in the drawing frame, ``stud_ids`` their
    names; ``stud_mark_style`` is ``circle``, ``cross`` or ``none``. ``obstacles``: flat boxes
    standing on the plane (stiffeners, webs, flanges: world frame, their tops ``height_m`` above
    the plane) that a welding gun must not hit. ``reference_marks``: dark discs of the board marks'
    diameter painted along the part (or on the table) at drawing positions, for registering a long part
    station by station. ``specular_lobe_deg``: the component is shiny
    steel -- a structured-light camera gets no depth where the surface mirrors its projector into
    the camera, within this angle (0: a matte part). ``stud_length_m`` / ``stud_diameter_m``: the
    welded studs' size, ``collar_height_m`` / ``collar_width_m`` their weld collars' (0: none),
    ``weld_defects``: {stud id: WeldDefect} (stud_perception.welded_studs).
    """

    component: Component | None
    board: MarkingBoard = field(default_factory=MarkingBoard)
    drawing_to_world: Pose2D = field(default_factory=Pose2D)
    studs_drawing_m: tuple[tuple[float, float], ...] = ()
    stud_ids: tuple[str, ...] = ()
    stud_mark_diameter_m: float = 0.008
    stud_mark_style: str = "circle"
    obstacles: tuple[Plate, ...] = ()
    specular_lobe_deg: float = 0.0
    stud_length_m: float = DEFAULT_STUD_LENGTH_M
    stud_diameter_m: float = DEFAULT_STUD_DIAMETER_M
    weld_defects: dict = field(default_factory=dict)
    reference_marks: tuple[ReferenceMark, ...] = ()
    collar_height_m: float = DEFAULT_COLLAR_HEIGHT_M
    collar_width_m: float = DEFAULT_COLLAR_WIDTH_M

    def __post_init__(self) -> None:
        object.__setattr__(self, "reference_marks", tuple(self.reference_marks))
        seen: set[str] = set()
        for mark in self.reference_marks:
            if not isinstance(mark, ReferenceMark):
                raise SceneError(f"reference_marks must hold ReferenceMark entries, got {mark!r}")
            if mark.label in seen:
                raise SceneError(f"reference_marks label {mark.label!r} is used twice")
            seen.add(mark.label)
        if not (0.001 <= self.stud_length_m <= 1.0 and 0.001 <= self.stud_diameter_m <= 0.1):
            raise SceneError(f"stud_length_mm={self.stud_length_m * 1e3:g} and stud_diameter_mm="
                             f"{self.stud_diameter_m * 1e3:g} must be in [1, 1000] and [1, 100] mm")
        if not (0.0 <= self.collar_height_m <= 0.05 and 0.0 <= self.collar_width_m <= 0.05):
            raise SceneError(f"collar_height_mm={self.collar_height_m * 1e3:g} and collar_width_mm="
                             f"{self.collar_width_m * 1e3:g} must be in [0, 50] mm")
        object.__setattr__(self, "obstacles", tuple(self.obstacles))
        for i, ob in enumerate(self.obstacles):
            if not isinstance(ob, Plate) or ob.tilt_rad != 0:
                raise SceneError(f"obstacle {i} must be a flat box (plane kind), got {ob!r}")
        if not 0.0 <= self.specular_lobe_deg < 45.0:
            raise SceneError(f"specular_lobe_deg must be in [0, 45), got {self.specular_lobe_deg}")
        studs = np.asarray(self.studs_drawing_m, dtype=np.float64).reshape(-1, 2)
        object.__setattr__(self, "studs_drawing_m", tuple(tuple(float(c) for c in p) for p in studs))
        ids = tuple(str(i) for i in self.stud_ids) or tuple(f"S{i + 1:04d}" for i in range(len(studs)))
        if len(ids) != len(studs):
            raise SceneError(f"{len(ids)} stud ids for {len(studs)} stud positions")
        object.__setattr__(self, "stud_ids", ids)
        if self.stud_mark_style not in ("circle", "cross", "none"):
            raise SceneError(f"stud_mark_style must be circle, cross or none, got {self.stud_mark_style!r}")
        if self.stud_mark_diameter_m <= 0:
            raise SceneError(f"stud_mark_diameter_m must be positive, got {self.stud_mark_diameter_m}")

    # -- derived geometry ---------------------------------------------------------------------
    @property
    def M_local2world(self) -> np.ndarray:
        """True drawing -> world transform (3x3 homogeneous, metres), the target of Eq. 2-3."""
        return self.drawing_to_world.matrix()

    @property
    def marks_world_m(self) -> np.ndarray:
        """(3, 3) world centres of O, A, B on the board's top face."""
        xy = self.drawing_to_world.apply(np.asarray(self.board.marks_drawing_m))
        return np.column_stack([xy, np.full(3, self.board.thickness_m)])

    @property
    def reference_marks_world_m(self) -> np.ndarray:
        """(K, 3) world centres of the reference marks (scene order) on the surface under them."""
        xy = self.drawing_to_world.apply(np.array([m.drawing_xy_m for m in self.reference_marks]).reshape(-1, 2))
        return np.column_stack([xy, surface_height(self, xy[:, 0], xy[:, 1])])

    @property
    def reference_marks_drawing_m(self) -> dict[str, tuple[float, float]]:
        """The reference marks as the drawing gives them: label -> drawing (x, y), metres, scene order."""
        return {m.label: m.drawing_xy_m for m in self.reference_marks}

    @property
    def studs_world_xy_m(self) -> np.ndarray:
        """(N, 2) stud positions on the working plane (world XY)."""
        return self.drawing_to_world.apply(np.asarray(self.studs_drawing_m).reshape(-1, 2))

    @property
    def board_plate(self) -> Plate:
        marks = np.asarray(self.board.marks_drawing_m)
        pad = self.board.mark_diameter_m / 2 + self.board.margin_m
        lo, hi = marks.min(axis=0) - pad, marks.max(axis=0) + pad
        centre = self.drawing_to_world.apply((lo + hi) / 2)
        return Plate(
            centre_xy_m=(float(centre[0]), float(centre[1])),
            size_m=(float(hi[0] - lo[0]), float(hi[1] - lo[1])),
            yaw_rad=self.drawing_to_world.yaw_rad,
            height_m=self.board.thickness_m,
        )


# -- vectorised ground-truth surface -----------------------------------------------------------
def _top_surface(scene: SceneSpec, x, y):
    """(height z (...), surface id (...)) of the topmost surface above world (x, y)."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    z = np.zeros(x.shape)
    sid = np.full(x.shape, SURFACE_TABLE, dtype=np.int8)
    zb, inb = scene.board_plate.top_height(x, y)
    z = np.where(inb, zb, z)
    sid[inb] = SURFACE_BOARD
    solids = [(SURFACE_COMPONENT, scene.component)] if scene.component is not None else []
    for surf, solid in solids + [(SURFACE_OBSTACLE, ob) for ob in scene.obstacles]:
        zc, inc = solid.top_height(x, y)
        higher = inc & (zc >= z)
        z = np.where(higher, zc, z)
        sid[higher] = surf
    return z, sid


def surface_height(scene: SceneSpec, x, y) -> np.ndarray:
    """World z (metres) of the top surface above world (x, y); vectorised over any shape."""
    return _top_surface(scene, x, y)[0]


def surface_normal(scene: SceneSpec, x, y) -> np.ndarray:
    """Unit outward normal (..., 3) of the top surface above world (x, y)."""
    _, sid = _top_surface(scene, x, y)
    x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
    n = np.zeros(x.shape + (3,))
    n[..., 2] = 1.0
    on_comp = sid == SURFACE_COMPONENT
    if scene.component is not None and on_comp.any():
        n[on_comp] = scene.component.top_normal(x[on_comp], y[on_comp])
    return n



# -- bundled scenes -------------------------------------------------------------------------------
_DEMO_DOME = Dome(centre_xy_m=(0.09, 0.02), base_radius_m=0.20, height_m=0.05)
# Board frame (= drawing frame): O at (-0.135, -0.11), x toward +Y world, so y points to -X.
_DEMO_POSE = Pose2D(x_m=-0.135, y_m=-0.11, yaw_rad=math.pi / 2)


def demo_dome_scene() -> SceneSpec:
    """The paper's set-up: a 50 mm high dome (base radius 0.2 m; normals 0 deg at the apex,
    ~14 deg at the outer studs) with 17 studs, and the marking board beside it
    (|OA| = 130 mm, |OB| = 100 mm, 20 mm marks, 5 mm plate). Pair with
    :func:`~stud_perception.scene_cameras.demo_camera`."""
    # Studs: apex, a ring of 8 at 50 mm and a ring of 8 at 100 mm (world, around the apex).
    ang = np.arange(8) * (2 * math.pi / 8)
    ring1 = np.column_stack([0.05 * np.cos(ang), 0.05 * np.sin(ang)])
    ring2 = np.column_stack([0.10 * np.cos(ang + math.pi / 8), 0.10 * np.sin(ang + math.pi / 8)])
    world = np.vstack([[0.0, 0.0], ring1, ring2]) + np.asarray(_DEMO_DOME.centre_xy_m)
    drawing = _DEMO_POSE.apply_inverse(world)
    return SceneSpec(
        component=_DEMO_DOME,
        board=MarkingBoard(),
        drawing_to_world=_DEMO_POSE,
        studs_drawing_m=tuple(map(tuple, np.round(drawing, 6))),
        stud_mark_diameter_m=0.008,
    )


def grid_stud_scene(
    n_studs: int,
    base: SceneSpec | None = None,
    extent_m: tuple[float, float] = (0.24, 0.18),
    centre_world_xy_m: tuple[float, float] | None = None,
) -> SceneSpec:
    """``base`` (default: the demo dome) with ``n_studs`` studs on a near-square world grid of
    ``extent_m`` (x, y) centred on ``centre_world_xy_m`` (default: the component's centre), for
    scaling benchmarks (tested up to 10,000). Stud marks shrink with the grid pitch so
    neighbouring marks never merge."""
    if n_studs < 1:
        raise SceneError(f"n_studs must be >= 1, got {n_studs}")
    base = base if base is not None else demo_dome_scene()
    if centre_world_xy_m is None:
        centre_world_xy_m = base.component.centre_xy_m if base.component is not None else (0.0, 0.0)
    ex, ey = extent_m
    cols = max(1, math.ceil(math.sqrt(n_studs * ex / ey)))
    rows = math.ceil(n_studs / cols)
    gx = np.linspace(-ex / 2, ex / 2, cols) if cols > 1 else np.zeros(1)
    gy = np.linspace(-ey / 2, ey / 2, rows) if rows > 1 else np.zeros(1)
    yy, xx = np.meshgrid(gy, gx, indexing="ij")
    world = np.column_stack([xx.ravel(), yy.ravel()])[:n_studs] + np.asarray(centre_world_xy_m)
    pitch = min(ex / max(cols - 1, 1), ey / max(rows - 1, 1))
    drawing = base.drawing_to_world.apply_inverse(world)
    return dataclasses.replace(
        base,
        studs_drawing_m=tuple(map(tuple, drawing)),
        stud_ids=tuple(f"S{i + 1:05d}" for i in range(n_studs)),
        stud_mark_diameter_m=min(base.stud_mark_diameter_m, 0.5 * pitch),
    )



def girder_scene(
    length_m: float = 6.0,
    width_m: float = 0.4,
    camber_m: float = 0.03,
    cross_slope_deg: float = 2.5,
    height_m: float = 0.12,
    row_pitch_m: float = 0.2,
    studs_per_row: int = 3,
    stud_spacing_m: float = 0.1,
    mark_pitch_m: float = 0.2,
    mark_offset_m: float = 0.13,
    start_xy_m: tuple[float, float] = (0.3, 0.0),
    board_origin_xy_m: tuple[float, float] | None = None,
) -> SceneSpec:
    """A long part along the rail (world x): a cambered, cross-sloped girder flange
    (:class:`~stud_perception.scene_solids.Girder`, heading +X from ``start_xy_m``) with rows of
    ``studs_per_row`` studs ``stud_spacing_m`` apart across it every ``row_pitch_m`` (as bridge decks
    use), the marking board on the table beside its start (O 0.1 m before it, A along the rail), and
    reference marks ``M1``, ``M2``, ... every ``mark_pitch_m`` along it, alternately ``mark_offset_m``
    right and left of its centreline (with the default pitches half a row pitch from the stud rows), so a camera
    view of the demo's field (0.46 x 0.345 m, the long side along the rail) sees two or three of them anywhere
    along the part. ``board_origin_xy_m``: where the board's O lies in world (A along +X, B along +Y);
    default 0.1 m before the start, 0.15 m beside the girder's right edge.

    The drawing frame is the board's: x along the rail, y across; the studs' and marks' drawing
    positions are their plan positions."""
    girder = Girder(start_xy_m, 0.0, length_m, width_m, camber_m, math.radians(cross_slope_deg), height_m)
    board = MarkingBoard()
    # O on the table beside the girder's start, the board 28 mm clear of its edge: one view sees O, A, B and M1
    if board_origin_xy_m is None:
        board_origin_xy_m = (start_xy_m[0] - 0.1, start_xy_m[1] - width_m / 2 - 0.15)
    pose = Pose2D(x_m=float(board_origin_xy_m[0]), y_m=float(board_origin_xy_m[1]), yaw_rad=0.0)
    u_rows = np.arange(row_pitch_m / 2, length_m - row_pitch_m / 4, row_pitch_m)
    v_studs = (np.arange(studs_per_row) - (studs_per_row - 1) / 2) * stud_spacing_m
    uu, vv = np.meshgrid(u_rows, v_studs, indexing="ij")
    world = np.column_stack([start_xy_m[0] + uu.ravel(), start_xy_m[1] + vv.ravel()])
    u_marks = np.arange(mark_pitch_m, length_m - mark_pitch_m / 4, mark_pitch_m)
    v_marks = np.where(np.arange(len(u_marks)) % 2 == 0, -mark_offset_m, mark_offset_m)
    marks_w = np.column_stack([start_xy_m[0] + u_marks, start_xy_m[1] + v_marks])
    marks_d = pose.apply_inverse(marks_w)
    return SceneSpec(
        component=girder, board=board, drawing_to_world=pose,
        studs_drawing_m=tuple(map(tuple, np.round(pose.apply_inverse(world), 6))),
        stud_mark_diameter_m=0.008,
        reference_marks=tuple(ReferenceMark(f"M{i + 1}", (float(round(x, 6)), float(round(y, 6))))
                              for i, (x, y) in enumerate(marks_d)),
    )
