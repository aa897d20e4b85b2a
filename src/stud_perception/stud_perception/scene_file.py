"""The synthetic scene's plain-dict form (as loaded from YAML/JSON) and scene files."""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from stud_perception.scene import MarkingBoard, ReferenceMark, SceneSpec
from stud_perception.scene_solids import Component, Cylinder, Dome, Girder, Plate, Pose2D, SceneError, Trough
from stud_perception.welded_studs import (
    DEFAULT_COLLAR_HEIGHT_M,
    DEFAULT_COLLAR_WIDTH_M,
    DEFAULT_STUD_DIAMETER_M,
    DEFAULT_STUD_LENGTH_M,
    WeldDefectError,
    parse_weld_defects,
)


# -- plain-dict / file form -----------------------------------------------------------------------
def _take(d: dict, name: str, allowed: set[str]) -> dict:
    if not isinstance(d, dict):
        raise SceneError(f"scene {name} must be a mapping, got {type(d).__name__}")
    unknown = set(d) - allowed
    if unknown:
        raise SceneError(f"unknown key(s) {sorted(unknown)} in scene {name}; allowed: {sorted(allowed)}")
    return d


def _component_from_dict(d: dict | None) -> Component | None:
    if d is None:
        return None
    kind = d.get("kind")
    try:
        if kind == "dome":
            _take(d, "component (dome)", {"kind", "centre_xy_m", "base_radius_m", "height_m"})
            return Dome(d["centre_xy_m"], _number(d, kind, "base_radius_m"), _number(d, kind, "height_m"))
        if kind == "cylinder":
            _take(d, "component (cylinder)",
                  {"kind", "centre_xy_m", "radius_m", "axis_yaw_deg", "length_m", "height_m"})
            return Cylinder(
                d["centre_xy_m"], _number(d, kind, "radius_m"), math.radians(_number(d, kind, "axis_yaw_deg", 0.0)),
                _number(d, kind, "length_m"), _number(d, kind, "height_m"),
            )
        if kind == "trough":
            _take(d, "component (trough)",
                  {"kind", "centre_xy_m", "radius_m", "axis_yaw_deg", "length_m", "width_m", "rim_height_m"})
            return Trough(
                d["centre_xy_m"], _number(d, kind, "radius_m"), math.radians(_number(d, kind, "axis_yaw_deg", 0.0)),
                _number(d, kind, "length_m"), _number(d, kind, "width_m"), _number(d, kind, "rim_height_m"),
            )
        if kind == "girder":
            _take(d, "component (girder)", {"kind", "start_xy_m", "yaw_deg", "length_m", "width_m", "camber_m",
                                             "cross_slope_deg", "height_m"})
            return Girder(
                d["start_xy_m"], math.radians(_number(d, "girder", "yaw_deg", 0.0)),
                _number(d, "girder", "length_m"), _number(d, "girder", "width_m"),
                _number(d, "girder", "camber_m", 0.0), math.radians(_number(d, "girder", "cross_slope_deg", 0.0)),
                _number(d, "girder", "height_m"),
            )
        if kind in ("tilted_plane", "plane"):
            keys = {"kind", "centre_xy_m", "size_m", "yaw_deg", "height_m"}
            if kind == "tilted_plane":
                keys.add("tilt_deg")
            _take(d, f"component ({kind})", keys)
            return Plate(
                d["centre_xy_m"], d["size_m"], math.radians(_number(d, kind, "yaw_deg", 0.0)),
                _number(d, kind, "height_m"),
                math.radians(_number(d, kind, "tilt_deg", 0.0)) if kind == "tilted_plane" else 0.0,
            )
    except KeyError as exc:
        raise SceneError(f"scene component ({kind}) misses key {exc.args[0]!r}") from None
    raise SceneError(f"unknown component kind {kind!r}: use dome, cylinder, trough, girder, tilted_plane or plane")


def _number(d: dict, what: str, key: str, default: float | None = None) -> float:
    """``d[key]`` as a finite float (``default`` when absent and one is given); names the key otherwise."""
    if key not in d and default is not None:
        return default
    value = d[key]  # KeyError: the caller names the missing key
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f"scene component ({what}) {key}={value!r}: expected a finite number")
    return float(value)


def _reference_marks(data) -> tuple[ReferenceMark, ...]:
    if data is None:
        return ()
    if not isinstance(data, list):
        raise SceneError(f"scene reference_marks must be a list of {{label, drawing_xy_m}}, got {type(data).__name__}")
    marks = []
    for i, m in enumerate(data):
        _take(m, f"reference_marks[{i}]", {"label", "drawing_xy_m"})
        if "label" not in m or "drawing_xy_m" not in m:
            missing = "label" if "label" not in m else "drawing_xy_m"
            raise SceneError(f"scene reference_marks[{i}] misses key {missing!r}")
        marks.append(ReferenceMark(m["label"], m["drawing_xy_m"]))
    return tuple(marks)


def _component_to_dict(c: Component | None) -> dict | None:
    if c is None:
        return None
    if isinstance(c, Dome):
        return {"kind": "dome", "centre_xy_m": list(c.centre_xy_m), "base_radius_m": c.base_radius_m,
                "height_m": c.height_m}
    if isinstance(c, Cylinder):
        return {
            "kind": "cylinder", "centre_xy_m": list(c.centre_xy_m), "radius_m": c.radius_m,
            "axis_yaw_deg": math.degrees(c.axis_yaw_rad), "length_m": c.length_m, "height_m": c.height_m,
        }
    if isinstance(c, Girder):
        return {
            "kind": "girder", "start_xy_m": list(c.start_xy_m), "yaw_deg": math.degrees(c.yaw_rad),
            "length_m": c.length_m, "width_m": c.width_m, "camber_m": c.camber_m,
            "cross_slope_deg": math.degrees(c.cross_slope_rad), "height_m": c.height_m,
        }
    if isinstance(c, Trough):
        return {
            "kind": "trough", "centre_xy_m": list(c.centre_xy_m), "radius_m": c.radius_m,
            "axis_yaw_deg": math.degrees(c.axis_yaw_rad), "length_m": c.length_m, "width_m": c.width_m,
            "rim_height_m": c.rim_height_m,
        }
    d = {"kind": c.kind, "centre_xy_m": list(c.centre_xy_m), "size_m": list(c.size_m),
         "yaw_deg": math.degrees(c.yaw_rad), "height_m": c.height_m}
    if c.tilt_rad != 0:
        d["tilt_deg"] = math.degrees(c.tilt_rad)
    return d


def scene_from_dict(d: dict[str, Any]) -> SceneSpec:
    """Build a scene from plain data (as loaded from YAML/JSON). Angles are in degrees there::

        {"component": {"kind": "dome", "centre_xy_m": [0.09, 0.02], "base_radius_m": 0.2, "height_m": 0.05},
         "board": {"marks_drawing_m": [[0, 0], [0.13, 0], [0, 0.1]], "mark_diameter_m": 0.02,
                   "thickness_m": 0.005, "margin_m": 0.018},
         "drawing_to_world": {"x_m": -0.135, "y_m": -0.11, "yaw_deg": 90},
         "studs": {"xy_m": [[0.1, 0.2]], "ids": ["S1"], "mark_diameter_m": 0.008, "mark_style": "circle"},
         "obstacles": [{"centre_xy_m": [0.1, 0.0], "size_m": [0.3, 0.012], "yaw_deg": 0, "height_m": 0.12}],
         "specular_lobe_deg": 3.0}

    Component kinds: ``dome`` (centre_xy_m, base_radius_m, height_m), ``cylinder`` (centre_xy_m,
    radius_m, axis_yaw_deg, length_m, height_m), ``trough`` (centre_xy_m, radius_m, axis_yaw_deg,
    length_m, width_m, rim_height_m), ``girder`` (start_xy_m, yaw_deg, length_m, width_m, camber_m,
    cross_slope_deg, height_m: a cambered flange plate,
    :class:`~stud_perception.scene_solids.Girder`), ``tilted_plane`` / ``plane`` (centre_xy_m,
    size_m, yaw_deg, height_m, tilt_deg); sizes in metres at any scale (a 6 m girder renders one
    view as fast as the demo dome: only what a view sees is traced). ``obstacles`` are flat boxes
    (stiffeners); ``specular_lobe_deg`` makes the component shiny (see
    :class:`~stud_perception.scene.SceneSpec`). ``reference_marks``: ``[{"label": "M1",
    "drawing_xy_m": [x, y]}, ...]``, dark discs of the board marks' diameter painted on whatever
    surface lies under them (part, table), placed through ``drawing_to_world`` like the studs.
    docs/SCENES.md describes every key.
    """
    _take(d, "", {"component", "board", "drawing_to_world", "studs", "obstacles", "specular_lobe_deg",
                  "stud_length_mm", "stud_diameter_mm", "weld_defects", "reference_marks", "collar_height_mm",
                  "collar_width_mm"})
    board_keys = {"marks_drawing_m", "mark_diameter_m", "thickness_m", "margin_m"}
    board = MarkingBoard(**_take(d.get("board", {}), "board", board_keys))
    pose_d = _take(d.get("drawing_to_world", {}), "drawing_to_world", {"x_m", "y_m", "yaw_deg"})
    pose = Pose2D(
        float(pose_d.get("x_m", 0.0)), float(pose_d.get("y_m", 0.0)), math.radians(float(pose_d.get("yaw_deg", 0.0)))
    )
    studs = _take(d.get("studs", {}), "studs", {"xy_m", "ids", "mark_diameter_m", "mark_style"})
    obstacles = d.get("obstacles", [])
    if not isinstance(obstacles, list):
        raise SceneError(f"scene obstacles must be a list of boxes, got {type(obstacles).__name__}")
    boxes = []
    for i, ob in enumerate(obstacles):
        _take(ob, f"obstacles[{i}]", {"centre_xy_m", "size_m", "yaw_deg", "height_m"})
        try:
            boxes.append(Plate(ob["centre_xy_m"], ob["size_m"], math.radians(float(ob.get("yaw_deg", 0.0))),
                               float(ob["height_m"])))
        except KeyError as exc:
            raise SceneError(f"scene obstacles[{i}] misses key {exc.args[0]!r}") from None
    return SceneSpec(
        component=_component_from_dict(d.get("component")),
        board=board,
        drawing_to_world=pose,
        studs_drawing_m=tuple(map(tuple, np.asarray(studs.get("xy_m", []), dtype=np.float64).reshape(-1, 2))),
        stud_ids=tuple(studs.get("ids", ())),
        stud_mark_diameter_m=float(studs.get("mark_diameter_m", 0.008)),
        stud_mark_style=str(studs.get("mark_style", "circle")),
        obstacles=tuple(boxes),
        specular_lobe_deg=float(d.get("specular_lobe_deg", 0.0)),
        stud_length_m=1e-3 * _mm(d, "stud_length_mm", DEFAULT_STUD_LENGTH_M * 1e3),
        stud_diameter_m=1e-3 * _mm(d, "stud_diameter_mm", DEFAULT_STUD_DIAMETER_M * 1e3),
        weld_defects=_weld_defects(d.get("weld_defects"), studs.get("ids", ()), len(studs.get("xy_m", []))),
        reference_marks=_reference_marks(d.get("reference_marks")),
        collar_height_m=1e-3 * _mm(d, "collar_height_mm", DEFAULT_COLLAR_HEIGHT_M * 1e3),
        collar_width_m=1e-3 * _mm(d, "collar_width_mm", DEFAULT_COLLAR_WIDTH_M * 1e3),
    )


def _mm(d: dict, name: str, default: float) -> float:
    value = d.get(name, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SceneError(f"scene {name}={value!r}: expected a number in mm")
    return float(value)


def _weld_defects(data, ids, n_studs: int) -> dict:
    ids = tuple(str(i) for i in ids) or tuple(f"S{i + 1:04d}" for i in range(n_studs))
    try:
        return parse_weld_defects(data, ids)
    except WeldDefectError as exc:
        raise SceneError(str(exc)) from None


def scene_to_dict(scene: SceneSpec) -> dict[str, Any]:
    """Plain-data form of ``scene`` (inverse of :func:`scene_from_dict`), JSON/YAML-serialisable."""
    b = scene.board
    return {
        "component": _component_to_dict(scene.component),
        "board": {"marks_drawing_m": [list(m) for m in b.marks_drawing_m], "mark_diameter_m": b.mark_diameter_m,
                  "thickness_m": b.thickness_m, "margin_m": b.margin_m},
        "drawing_to_world": {"x_m": scene.drawing_to_world.x_m, "y_m": scene.drawing_to_world.y_m,
                             "yaw_deg": math.degrees(scene.drawing_to_world.yaw_rad)},
        "studs": {"xy_m": [list(p) for p in scene.studs_drawing_m], "ids": list(scene.stud_ids),
                  "mark_diameter_m": scene.stud_mark_diameter_m, "mark_style": scene.stud_mark_style},
        "obstacles": [{"centre_xy_m": list(ob.centre_xy_m), "size_m": list(ob.size_m),
                       "yaw_deg": math.degrees(ob.yaw_rad), "height_m": ob.height_m} for ob in scene.obstacles],
        "specular_lobe_deg": scene.specular_lobe_deg,
        "stud_length_mm": scene.stud_length_m * 1e3, "stud_diameter_mm": scene.stud_diameter_m * 1e3,
        "collar_height_mm": scene.collar_height_m * 1e3, "collar_width_mm": scene.collar_width_m * 1e3,
        "weld_defects": {sid: defect.to_dict() for sid, defect in scene.weld_defects.items()},
        "reference_marks": [{"label": m.label, "drawing_xy_m": list(m.drawing_xy_m)} for m in scene.reference_marks],
    }


def load_scene(path: str | Path) -> SceneSpec:
    """Read a scene from a ``.json`` file, or ``.yaml``/``.yml`` when PyYAML is installed."""
    path = Path(path)
    text = path.read_text()
    if path.suffix.lower() in (".yaml", ".yml"):
        try:
            import yaml
        except ImportError:
            raise SceneError(f"{path}: PyYAML is not installed; install it or write the scene as JSON") from None
        data = yaml.safe_load(text)
    else:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise SceneError(f"{path}: not valid JSON ({exc})") from None
    return scene_from_dict(data)
