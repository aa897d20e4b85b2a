"""What a viewer gets from the matcher: id-labelled, state-coloured markers and a JPEG overlay that is
encoded only while someone watches it."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import CompressedImage
from visualization_msgs.msg import Marker, MarkerArray

from rosproc import ros2_run, wait_for
from stud_common import ros_io
from stud_planner.matching.target_markers import ARROW_NS, TEXT_NS, status_rgba
from stud_planner.matching.view_targets import STATUS_OK
from test_matcher_node import COLOR, _camera_inputs, _shoot_until


def test_markers_carry_ids_and_status_colours_and_the_jpeg_overlay_follows_its_subscriber(
        ros_node, procs, tmp_path: Path):
    procs.append(ros2_run("stud_planner", "matcher", tmp_path / "matcher.log"))
    pubs, shot = _camera_inputs(ros_node)
    markers: list[MarkerArray] = []
    jpegs: list[CompressedImage] = []
    ros_node.create_subscription(MarkerArray, "/weld_targets/markers", markers.append, ros_io.RESULT_QOS)
    wait_for(lambda: ros_node.count_publishers("/weld_targets/markers") == 1, 60, spin=ros_node.spin,
             what="the matcher")
    assert ros_node.count_subscribers(COLOR) == 0
    sub = ros_node.create_subscription(CompressedImage, "/weld_targets/overlay/compressed", jpegs.append,
                                       ros_io.RESULT_QOS)
    wait_for(lambda: ros_node.count_subscribers(COLOR) == 1, 30, spin=ros_node.spin,
             what="colour taken for the compressed overlay")
    stamp = _shoot_until(ros_node, pubs, shot, range(1, 10), ("depth", "info", "pose", "color"), jpegs)
    wait_for(lambda: markers, 20, spin=ros_node.spin, what="markers")

    items = markers[-1].markers
    assert items[0].action == Marker.DELETEALL
    texts = {m.id: m for m in items if m.ns == TEXT_NS}
    arrows = {m.id: m for m in items if m.ns == ARROW_NS}
    assert texts and all(m.type == Marker.TEXT_VIEW_FACING and m.text for m in texts.values())
    ok = [m for m in texts.values() if " " not in m.text]  # an ok stud's label is its id alone
    assert ok and all(m.id in arrows for m in ok)
    green = status_rgba(STATUS_OK)
    assert all((m.color.r, m.color.g, m.color.b) == pytest.approx(green[:3], abs=1e-6) for m in ok)  # float32
    refused = [m for m in texts.values() if " " in m.text]
    assert all((m.color.r, m.color.g, m.color.b) != pytest.approx(green[:3], abs=1e-6) for m in refused)

    jpeg = next(j for j in jpegs if j.header.stamp == stamp)
    assert jpeg.format == "jpeg"
    image = cv2.imdecode(np.frombuffer(bytes(jpeg.data), np.uint8), cv2.IMREAD_COLOR)
    assert image.shape[:2] == (shot["color"].height, shot["color"].width)

    ros_node.destroy_subscription(sub)
    wait_for(lambda: ros_node.count_subscribers(COLOR) == 0, 20, spin=ros_node.spin,
             what="colour dropped with the last overlay subscriber")
