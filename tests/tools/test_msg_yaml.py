"""Messages to YAML and back as ros2cli shows and fills them (no ROS graph needed)."""
from __future__ import annotations

import pytest
from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseArray
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from stud_welding_msgs.action import WeldJob

from ros2_lite.msg_yaml import InterfaceError, interface_class, message_to_yaml, set_message_fields


def test_yaml_keeps_field_order_nests_messages_and_lists():
    msg = PoseArray()
    set_message_fields(msg, {"header": {"frame_id": "world"}, "poses": [{"position": {"x": 1, "y": 2.5}}]})
    text = message_to_yaml(msg)
    assert text.startswith("header:\n  stamp:\n    sec: 0\n    nanosec: 0\n  frame_id: world\nposes:\n- position:\n")
    assert "    x: 1.0\n    y: 2.5\n" in text  # the int became a float, as the field is float64


def test_arrays_and_strings_are_truncated_and_can_be_left_out():
    js = JointState(name=["a" * 10], position=[float(i) for i in range(5)])
    text = message_to_yaml(js, truncate_length=3)
    assert "- aaa...\n" in text and "- 2.0\n- '...'\n" in text
    assert "position" not in message_to_yaml(js, no_arr=True)
    assert "frame_id" not in message_to_yaml(js, no_str=True)


def test_now_and_auto_stamp_time_fields_when_publishing():
    js = JointState()
    set_message_fields(js, {"header": "auto"}, now=lambda: Time(sec=5, nanosec=7))
    assert (js.header.stamp.sec, js.header.stamp.nanosec) == (5, 7)
    with pytest.raises(InterfaceError, match="only understood when publishing"):
        set_message_fields(JointState(), {"header": {"stamp": "now"}})


@pytest.mark.parametrize("values, reason", [
    ({"nope": 1}, "has no field 'nope'"),
    ({"data": {"x": 1}}, "field 'data': a string field needs text"),
])
def test_values_that_do_not_fit_name_the_field(values, reason):
    with pytest.raises(InterfaceError, match=reason):
        set_message_fields(String(), values)


def test_interface_names_resolve_like_ros2cli():
    assert interface_class("std_msgs/String") is String
    assert interface_class("stud_welding_msgs/action/WeldJob", "action") is WeldJob
    with pytest.raises(InterfaceError, match="message type is invalid"):
        interface_class("std_msgs/msg/Nope")
