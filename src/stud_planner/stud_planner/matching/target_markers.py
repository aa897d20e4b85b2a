"""The matcher's weld targets as RViz/Foxglove markers: an arrow along each normal and the stud id.

Colours say the state, one palette with the overlay (:data:`stud_planner.matching.view_targets.STATUS_BGR`):
green ``ok`` (planned, to be welded), and a colour per refusal (``no_depth``, ``normal_uncertain``,
``no_normal``, ...). The matcher cannot know what was welded: :data:`WELDED_RGBA` is the colour a later
node (one that follows the weld job) gives a stud once it is welded, re-publishing the same
namespaces and ids so its markers replace the matcher's. Out-of-view studs get no marker.

Namespaces: ``weld_targets`` (arrows, id = stud index), ``weld_target_ids`` (TEXT_VIEW_FACING, the
stud id and, when refused, the reason, just above the surface point).
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point, Pose, Quaternion, Vector3
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from stud_planner.matching.view_targets import STATUS_BGR, STATUS_OK, STATUS_OUT_OF_VIEW, STATUS_TEXT, ViewTargets

ARROW_NS, TEXT_NS = "weld_targets", "weld_target_ids"
#: A welded stud (blue), for the node that recolours after the weld job.
WELDED_RGBA = (0.15, 0.45, 1.0, 1.0)
_UNKNOWN_BGR = (0, 0, 255)


def status_rgba(status: int) -> tuple[float, float, float, float]:
    """RViz colour (r, g, b, a in 0..1) of a target status: the overlay's :data:`STATUS_BGR`; an unknown one red."""
    b, g, r = STATUS_BGR.get(int(status), _UNKNOWN_BGR)
    return (r / 255.0, g / 255.0, b / 255.0, 1.0)


def target_markers(targets: ViewTargets, header: Header, arrow_length_m: float = 0.05,
                   text_height_m: float = 0.012) -> MarkerArray:
    """DELETEALL, then per in-view stud with a position: its id as text, and an arrow of
    ``arrow_length_m`` along the normal where there is one. Sizes in metres, frame of ``header``."""
    out = MarkerArray(markers=[Marker(header=header, action=Marker.DELETEALL)])
    finite_p = np.all(np.isfinite(targets.position_w), axis=1)
    finite_n = np.all(np.isfinite(targets.normal_w), axis=1)
    shown = (targets.status != STATUS_OUT_OF_VIEW) & finite_p
    for i in np.flatnonzero(shown).tolist():
        status = int(targets.status[i])
        r, g, b, a = status_rgba(status)
        color = ColorRGBA(r=r, g=g, b=b, a=a)
        p = targets.position_w[i].tolist()
        n = targets.normal_w[i].tolist() if finite_n[i] else [0.0, 0.0, 1.0]
        if finite_n[i]:
            out.markers.append(Marker(
                header=header, ns=ARROW_NS, id=i, type=Marker.ARROW, action=Marker.ADD,
                points=[Point(x=p[0], y=p[1], z=p[2]), Point(x=p[0] + arrow_length_m * n[0],
                                                          y=p[1] + arrow_length_m * n[1],
                                                          z=p[2] + arrow_length_m * n[2])],
                scale=Vector3(x=0.003, y=0.006, z=0.01), color=color))
        label = targets.ids[i] if status == STATUS_OK else f"{targets.ids[i]} {STATUS_TEXT.get(status, status)}"
        lift = arrow_length_m + text_height_m
        out.markers.append(Marker(
            header=header, ns=TEXT_NS, id=i, type=Marker.TEXT_VIEW_FACING, action=Marker.ADD,
            pose=Pose(position=Point(x=p[0] + lift * n[0], y=p[1] + lift * n[1], z=p[2] + lift * n[2]),
                      orientation=Quaternion(w=1.0)),
            scale=Vector3(z=text_height_m), color=color, text=label))
    return out
