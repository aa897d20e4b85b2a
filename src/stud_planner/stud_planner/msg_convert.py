"""stud_planner's message <-> core conversions (one place, so nodes stay thin).

Image/CameraInfo/Pose conversions are stud_perception.ros_io's; this module handles our
own interfaces: layouts, registrations and weld targets.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from geometry_msgs.msg import Point, Pose, PoseArray, Quaternion
from stud_welding_msgs.msg import Registration, Stud, StudLayout, WeldTarget

from stud_planner import dxf_layout


def layout_to_msg(layout: dxf_layout.StudLayout, stamp=None) -> StudLayout:
    msg = StudLayout()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.header.frame_id = "drawing"
    msg.source_file = layout.source_file
    msg.source_units = layout.source_units
    msg.mark_o = Point(x=layout.mark_o.x_m, y=layout.mark_o.y_m)
    msg.mark_a = Point(x=layout.mark_a.x_m, y=layout.mark_a.y_m)
    msg.mark_b = Point(x=layout.mark_b.x_m, y=layout.mark_b.y_m)
    msg.mark_diameter = float(layout.mark_diameter_m)
    msg.studs = [Stud(id=s.id, x=s.x_m, y=s.y_m, diameter=s.diameter_m, layer=s.layer) for s in layout.studs]
    msg.warnings = list(layout.warnings)
    return msg


@dataclass(frozen=True)
class LayoutView:
    """What the matcher and the registration need of a StudLayout message (numpy, metres, drawing frame)."""

    ids: list[str]
    xy_m: np.ndarray          # (N, 2)
    marks_m: np.ndarray       # (3, 2) O, A, B
    mark_diameter_m: float
    source_file: str


def layout_from_msg(msg: StudLayout) -> LayoutView:
    return LayoutView(
        ids=[s.id for s in msg.studs],
        xy_m=np.array([(s.x, s.y) for s in msg.studs], dtype=np.float64).reshape(-1, 2),
        marks_m=np.array([(m.x, m.y) for m in (msg.mark_o, msg.mark_a, msg.mark_b)], dtype=np.float64),
        mark_diameter_m=float(msg.mark_diameter),
        source_file=msg.source_file,
    )


def layout_poses(msg: StudLayout) -> PoseArray:
    """The studs as a PoseArray in the `drawing` frame (for RViz / Foxglove)."""
    arr = PoseArray()
    arr.header = msg.header
    arr.poses = [Pose(position=Point(x=s.x, y=s.y), orientation=Quaternion(w=1.0)) for s in msg.studs]
    return arr


def registration_from_msg(msg: Registration) -> np.ndarray:
    """Registration message -> M_local2world (3, 3)."""
    return np.asarray(msg.m_local2world, dtype=np.float64).reshape(3, 3)


def weld_target_msgs(targets, view_index: int) -> list[WeldTarget]:
    """All WeldTargets of a view_planning.ViewTargets, in stud order. NaN positions (no match) are
    sent as NaN so nobody mistakes them for 0; a NaN orientation becomes the identity.

    The hot path of the matcher node: arrays become Python lists once, and each message's own
    nested fields are filled in place (creating Pose/Point/... objects per stud cost more than the
    matching itself)."""
    quat = targets.quat_xyzw.copy()
    quat[~np.all(np.isfinite(quat), axis=1)] = (0.0, 0.0, 0.0, 1.0)
    columns = zip(targets.ids, targets.drawing_xy_m.tolist(), targets.position_w.tolist(),
                  targets.normal_w.tolist(), quat.tolist(), targets.matches.pixel_uv.tolist(),
                  targets.matches.iterations.tolist(), targets.matches.xy_residual_m.tolist(),
                  targets.inclination_deg.tolist(), targets.normal_rms_m.tolist(), targets.status.tolist(),
                  targets.status_text)
    out = []
    for sid, dxy, p, n, q, uv, it, err, incl, rms, status, text in columns:
        t = WeldTarget(stud_id=sid, drawing_x=dxy[0], drawing_y=dxy[1], pixel_u=uv[0], pixel_v=uv[1],
                       view_index=view_index, iterations=it, xy_error=err, inclination=incl, normal_rms=rms,
                       status=status, status_text=text)
        pos, ori, nrm = t.pose.position, t.pose.orientation, t.normal
        pos.x, pos.y, pos.z = p
        ori.x, ori.y, ori.z, ori.w = q
        nrm.x, nrm.y, nrm.z = n
        out.append(t)
    return out
