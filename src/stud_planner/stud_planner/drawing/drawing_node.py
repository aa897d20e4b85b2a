"""Drawing node: `ros2 run stud_planner drawing --ros-args -p drawing_file:=part.dxf`.

Reads the DXF (stud_planner.drawing) and publishes ``/drawing/layout`` (StudLayout,
reliable + transient local, so a late subscriber such as the HMI or a matcher started
later still gets it) and ``/drawing/poses`` (PoseArray in the ``drawing`` frame, for
visualisation). ``/drawing/load`` (LoadDrawing) reloads the file or loads another one. A
bad file is reported in the log and on /diagnostics; the node keeps running and keeps
publishing the last good layout (none, if no file was good yet). That includes a drawing that asks
for more block expansion than ``drawing_limits.*`` allow (:class:`DrawingLimits`: the reason names
the block, its nesting level and the count, and the parameter that raises the limit).
"""
from __future__ import annotations

from geometry_msgs.msg import PoseArray
from rclpy.node import Node
from stud_welding_msgs.msg import StudLayout
from stud_welding_msgs.srv import LoadDrawing

from stud_common import names, ros_io
from stud_common.ros_io import Param
from stud_planner.drawing import DrawingError, DrawingLimitError, DrawingLimits, LayoutOptions, read_layout
from stud_planner.msg_convert import layout_poses, layout_to_msg

PARAMS = [
    Param("drawing_file", "", "DXF drawing with stud circles and the marks O, A, B"),
    Param("stud_layers", ["STUDS"], "layer names or glob patterns of the stud circles (case-insensitive)"),
    Param("mark_layer", "MARKS", "layer (or glob pattern) of the O, A, B mark circles"),
    Param("units_if_unitless", "mm", "unit of a drawing without $INSUNITS",
          choices=("mm", "cm", "m", "in", "ft", "dm", "um")),
    Param("min_diameter_m", 0.0, "ignore stud circles smaller than this [m] (0: no limit)", min=0.0, max=1.0),
    Param("max_diameter_m", 0.0, "ignore stud circles larger than this [m] (0: no limit)", min=0.0, max=1.0),
    Param("min_spacing_m", -1.0, "warn about studs closer than this [m]; -1: 2.5 x median diameter; 0: off",
          min=-1.0, max=10.0),
    Param("gun_spacing_m", 0.0, "warn about stud pairs closer than the weld gun's foot needs beside a welded stud "
          "(the arm driver's min_stud_spacing_m: it welds one of each pair, refuses the other) [m]; 0: off",
          min=0.0, max=0.5),
    Param("include_hidden_layers", False, "also read frozen or off layers (skipped by default, as CAD hides them)"),
]
LIMITS_NS = "drawing_limits"
#: ``drawing_limits.<name>``: the work budget of block expansion (:class:`DrawingLimits`, its defaults)
LIMIT_PARAMS = [Param(f"{LIMITS_NS}.{name}", default, f"drawing limit: {text}; a drawing beyond it is refused "
                      "(a change applies to the next /drawing/load)", min=1)
                for name, (default, text) in DrawingLimits.describe().items()]
PARAMS += LIMIT_PARAMS


def limits_from(p: dict) -> DrawingLimits:
    """DrawingLimits from the declared parameter values (:data:`LIMIT_PARAMS`)."""
    return DrawingLimits(**{name: p[f"{LIMITS_NS}.{name}"] for name in DrawingLimits.describe()})


def options_from(p: dict) -> LayoutOptions:
    """LayoutOptions from the declared parameter values (:data:`PARAMS`; 0 / -1 mean "no limit" / "default")."""
    return LayoutOptions(
        stud_layers=list(p["stud_layers"]), mark_layer=p["mark_layer"], units_if_unitless=p["units_if_unitless"],
        min_diameter_m=p["min_diameter_m"] or None, max_diameter_m=p["max_diameter_m"] or None,
        min_spacing_m=None if p["min_spacing_m"] < 0 else p["min_spacing_m"],
        include_hidden_layers=p["include_hidden_layers"], gun_spacing_m=p["gun_spacing_m"], limits=limits_from(p))


class DrawingNode(Node):
    def __init__(self) -> None:
        super().__init__("drawing")
        self.p = ros_io.declare_params(self, PARAMS)
        self.pub_layout = self.create_publisher(StudLayout, names.DRAWING_LAYOUT, ros_io.LATCHED_QOS)
        self.pub_poses = self.create_publisher(PoseArray, names.DRAWING_POSES, ros_io.LATCHED_QOS)
        self.diag = ros_io.Diagnostics(self)
        self.create_service(LoadDrawing, names.DRAWING_LOAD, self._on_load)
        self.create_timer(1.0, self.diag.publish)
        if self.p["drawing_file"]:
            self.load(self.p["drawing_file"])
        else:
            self.diag.set(self.diag.WARN, "no drawing_file set: call /drawing/load")
            self.get_logger().warn("no drawing_file parameter: waiting for a /drawing/load request")

    def load(self, path: str) -> tuple[bool, str, int]:
        p = self.p
        try:
            layout = read_layout(path, options_from(p))
        except DrawingError as exc:
            why = str(exc)
            if isinstance(exc, DrawingLimitError):
                why += f" (a genuine drawing? raise the parameter {LIMITS_NS}.{exc.limit})"
            self.get_logger().error(why)
            self.diag.set(self.diag.ERROR, why, file=path)
            self.diag.publish()
            return False, why, 0
        msg = layout_to_msg(layout, self.get_clock().now().to_msg())
        self.pub_layout.publish(msg)
        self.pub_poses.publish(layout_poses(msg))
        for warning in layout.warnings:
            self.get_logger().warn(f"{path}: {warning}")
        summary = (f"{path}: {len(layout.studs)} studs on {', '.join(layout.stud_layers)}, units "
                   f"{layout.source_units}, marks by {layout.marks_rule}, {len(layout.warnings)} warnings")
        self.get_logger().info(summary)
        level = self.diag.WARN if layout.warnings else self.diag.OK
        self.diag.set(level, summary, file=path, studs=len(layout.studs), warnings=len(layout.warnings))
        self.diag.publish()
        return True, summary, len(layout.studs)

    def _on_load(self, request, response):
        path = request.drawing_file or self.p["drawing_file"]
        if not path:
            response.success, response.message = False, "no drawing_file given and none loaded before"
            return response
        response.success, response.message, response.stud_count = self.load(path)
        if response.success:
            self.p["drawing_file"] = path
        return response


def main(args=None) -> int:
    """`ros2 run stud_planner drawing`: spin until Ctrl-C; the process exit code."""
    return ros_io.spin_node(DrawingNode, args)


if __name__ == "__main__":
    raise SystemExit(main())
