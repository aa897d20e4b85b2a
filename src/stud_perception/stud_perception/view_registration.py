"""Register the drawing on one RGB-D view: find O, A, B (markers.py), then M_local2world (Eq. 2-3).

The one function the registration node and the offline planner both call. Bad views are
not exceptions: the result says ``ok=False`` and why, so a node can publish ``valid=false``
and keep running.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import cv2
import numpy as np

from stud_perception.camera_model import CameraModel
from stud_perception.markers import MarkDetection, MarkDetectorConfig, detect_marks
from stud_perception.registration import MarkRegistration, RegistrationError, registration_from_marks


@dataclass(frozen=True, eq=False)
class ViewRegistration:
    """``registration`` is set when ``ok``; ``message`` says what was found or what went wrong.
    ``refused``: the marks were found and named but disagree with the drawing (a wrong association,
    a mis-detected mark): not a view that merely saw too little."""

    ok: bool
    message: str
    detection: MarkDetection
    registration: MarkRegistration | None
    refused: bool = False


def register_view(color_bgr: np.ndarray, depth_m: np.ndarray, camera: CameraModel, drawing_marks_m: np.ndarray,
                  config: MarkDetectorConfig = MarkDetectorConfig(),
                  method: Literal["eq3", "least_squares"] = "eq3") -> ViewRegistration:
    """Find the marks and register. ``drawing_marks_m`` (3, 2): O, A, B in the drawing (metres);
    ``config.mark_diameter_m`` should be the drawing's mark diameter."""
    detection = detect_marks(color_bgr, depth_m, camera, drawing_marks_m, config)
    if not detection.ok:
        return ViewRegistration(False, f"marks not found ({detection.status.value}): {detection.message}",
                                detection, None)
    O, A, B = detection.marks_world_m
    try:
        reg = registration_from_marks(O, A, B, drawing_marks=drawing_marks_m, tol_m=config.distance_tol_m,
                                      method=method)
    except RegistrationError as exc:
        return ViewRegistration(False, f"marks found but unusable: {exc}", detection, None)
    msg = (f"registered: residual {reg.residual_m * 1e3:.2f} mm, angle AOB {reg.angle_AOB_deg:.2f} deg, "
           f"yaw {np.degrees(reg.yaw_rad):.2f} deg")
    return ViewRegistration(True, msg, detection, reg)


def config_for_layout(config: MarkDetectorConfig, mark_diameter_m: float) -> MarkDetectorConfig:
    """The detector config with the drawing's mark diameter (when the drawing gives one)."""
    return replace(config, mark_diameter_m=mark_diameter_m) if mark_diameter_m > 0 else config


def draw_registration_overlay(color_bgr: np.ndarray, result: ViewRegistration, camera: CameraModel) -> np.ndarray:
    """Colour image with the mark candidates (grey), the chosen O, A, B and the drawing axes, and the
    reference marks a registration along a part used, with their residuals."""
    img = color_bgr.copy()
    det = result.detection
    for (u, v), r in zip(det.candidates_uv, det.candidates_radius_px):
        cv2.circle(img, (int(round(u)), int(round(v))), int(round(r)), (160, 160, 160), 1, cv2.LINE_AA)
    reg = result.registration
    if result.ok and reg is not None and np.isfinite(det.marks_pixels_uv).all():
        uv = det.marks_pixels_uv
        for name, (u, v) in zip("OAB", uv):
            cv2.drawMarker(img, (int(round(u)), int(round(v))), (0, 200, 255), cv2.MARKER_CROSS, 24, 2)
            cv2.putText(img, name, (int(u) + 12, int(v) - 12), cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 200, 255), 2)
        o = tuple(int(round(c)) for c in uv[0])
        cv2.arrowedLine(img, o, tuple(int(round(c)) for c in uv[1]), (0, 0, 255), 2, tipLength=0.05)  # x: red
        cv2.arrowedLine(img, o, tuple(int(round(c)) for c in uv[2]), (0, 255, 0), 2, tipLength=0.05)  # y: green
    if result.ok and reg is not None and not reg.extrapolated and len(reg.labels_used):
        # the other marks the fit used (reference marks along a part), with their residuals
        u, v, z = camera.world_to_pixel(reg.marks_used_world_m)
        for name, uu, vv, zz, res in zip(reg.labels_used, u, v, z, reg.mark_residuals_m):
            if name in ("O", "A", "B") or not (zz > 0 and camera.in_image(uu, vv)):
                continue
            cv2.drawMarker(img, (int(round(uu)), int(round(vv))), (0, 200, 255), cv2.MARKER_CROSS, 24, 2)
            cv2.putText(img, f"{name} {res * 1e3:.2f} mm", (int(uu) + 12, int(vv) - 12), cv2.FONT_HERSHEY_SIMPLEX,
                        0.7, (0, 200, 255), 2)
    colour = (0, 160, 0) if result.ok else (0, 0, 220)
    cv2.putText(img, result.message[:110], (10, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.7, colour, 2)
    return img
