"""Protocol layer: byte-level framing, command builders, reply parsing, units, error text."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rm65_driver.protocol import messages as P

PRETTY_ROS1 = (  # what cJSON_Print + "\r\n" produces in the official ROS1 driver
    b'{\n\t"command":\t"movej",\n\t"joint":\t[10100, 200, 20300, 30400, 500, 20600],\n'
    b'\t"v":\t50,\n\t"r":\t0,\n\t"trajectory_connect":\t0\n}\r\n'
)


def test_encode_is_compact_json_with_crlf_like_the_sdk():
    data = P.encode({"command": "set_arm_stop"})
    assert data == b'{"command":"set_arm_stop"}\r\n'


def test_decoder_splits_several_messages_in_one_read():
    d = P.FrameDecoder()
    msgs = d.feed(b'{"a":1}\r\n{"b":2}\r\n{"c":3}\r\n')
    assert msgs == [{"a": 1}, {"b": 2}, {"c": 3}]
    assert d.pending_bytes == 0


def test_decoder_reassembles_a_message_split_across_reads_even_inside_the_terminator():
    d = P.FrameDecoder()
    assert d.feed(b'{"command":"mo') == []
    assert d.feed(b'vej","v":5}\r') == []
    assert d.pending_bytes > 0
    assert d.feed(b'\n{"x"') == [{"command": "movej", "v": 5}]
    assert d.feed(b":1}\r\n") == [{"x": 1}]


def test_decoder_accepts_pretty_printed_json_with_bare_newlines_and_tabs():
    d = P.FrameDecoder()
    msgs = d.feed(PRETTY_ROS1)
    assert msgs == [{"command": "movej", "joint": [10100, 200, 20300, 30400, 500, 20600], "v": 50, "r": 0,
                     "trajectory_connect": 0}]
    assert P.encode(msgs[0], pretty=True).count(b"\n") > 2  # our pretty encoder has inner newlines too
    assert d.feed(P.encode(msgs[0], pretty=True)) == msgs


def test_decoder_does_not_split_on_a_bare_newline():
    d = P.FrameDecoder()
    assert d.feed(b'{"a":\n1}\n') == []  # no \r\n yet: still one incomplete frame
    assert d.feed(b"\r\n") == [{"a": 1}]


def test_garbage_lines_are_skipped_and_reported_without_losing_neighbours():
    d = P.FrameDecoder()
    msgs = d.feed(b'{"a":1}\r\nGARBAGE\xff\r\n[1,2]\r\n\r\n{"b":2}\r\n')
    assert msgs == [{"a": 1}, {"b": 2}]
    assert d.bad_count == 2
    assert "GARBAGE" in d.bad_frames[0]


def test_oversized_frame_without_terminator_is_dropped():
    d = P.FrameDecoder(max_frame_bytes=64)
    assert d.feed(b"x" * 100) == []
    assert d.bad_count == 1 and d.pending_bytes == 0
    assert d.feed(b'{"ok":true}\r\n') == [{"ok": True}]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=1, max_value=40), min_size=1, max_size=30), st.booleans())
def test_any_read_boundaries_give_the_same_messages(cuts, pretty):
    msgs = [{"command": "movel", "pose": [1, -2, 3, 4, 5, 6], "v": 20}, {"state": "current_trajectory_state",
            "trajectory_state": True}, {"command": "get_current_arm_state"}]
    stream = b"".join(P.encode(m, pretty=pretty) for m in msgs)
    d = P.FrameDecoder()
    out, pos = [], 0
    for c in cuts:
        out += d.feed(stream[pos:pos + c])
        pos += c
    out += d.feed(stream[pos:])
    assert out == msgs


def test_decode_frame_raises_a_clear_error():
    with pytest.raises(P.ProtocolError, match="not JSON"):
        P.decode_frame(b"{nope")
    with pytest.raises(P.ProtocolError, match="object"):
        P.decode_frame(b"[1]")


# -- units ---------------------------------------------------------------------------------


def test_units_at_the_edge_match_the_doc_examples():
    assert P.joints_to_wire(np.radians([90, -10.1, 0, 0, 0, 0.001])) == [90000, -10100, 0, 0, 0, 1]
    assert P.pose_to_wire([0.1, 0.2, 0.03, 0.4, 0.5, 0.6]) == [100000, 200000, 30000, 400, 500, 600]
    np.testing.assert_allclose(P.pose_from_wire([100000, 200000, 30000, 400, 500, 600]),
                               [0.1, 0.2, 0.03, 0.4, 0.5, 0.6])
    np.testing.assert_allclose(np.degrees(P.joints_from_wire([107149, -84991])), [107.149, -84.991])


def test_non_finite_values_are_never_sent():
    with pytest.raises(ValueError, match="non-finite"):
        P.movej([0, 0, np.nan, 0, 0, 0], 10)


# -- builders: exactly the documented / SDK wire shapes ---------------------------------------


def test_motion_builders_match_the_sdk_wire_format():
    assert P.movej(np.radians([10, 20, 30, 40, 50, 60]), 20) == json.loads(
        '{"command":"movej","v":20,"joint":[10000,20000,30000,40000,50000,60000],"trajectory_connect":0,"r":0}')
    assert P.movej_p([0.1, 0.2, 0.3, 3.14, 0, 0], 20) == json.loads(
        '{"command":"movej_p","v":20,"pose":[100000,200000,300000,3140,0,0],"trajectory_connect":0,"r":0}')
    assert P.movel([0.1, 0.2, 0.3, 3.14, 0, 0], 20) == json.loads(
        '{"command":"movel","v":20,"pose":[100000,200000,300000,3140,0,0],"trajectory_connect":0,"r":0}')
    with pytest.raises(ValueError):
        P.movel([0] * 6, 0)
    with pytest.raises(ValueError):
        P.movej([0] * 6, 101)


def test_stop_io_and_frame_builders_match_the_doc():
    assert P.set_arm_stop() == {"command": "set_arm_stop"}
    assert P.set_arm_slow_stop() == {"command": "set_arm_slow_stop"}
    assert P.set_arm_pause() == {"command": "set_arm_pause"}
    assert P.set_arm_continue() == {"command": "set_arm_continue"}
    assert P.set_DO_state(1, True) == {"command": "set_DO_state", "IO_Num": 1, "state": 1}
    assert P.set_IO_mode(1, 1) == {"command": "set_IO_mode", "IO_Num": 1, "IO_mode": 1}
    assert P.set_tool_DO_state(2, 0) == {"command": "set_tool_DO_state", "IO_Num": 2, "state": 0}
    assert P.set_tool_IO_mode(1, 1) == {"command": "set_tool_IO_mode", "IO_Num": 1, "state": 1}
    assert P.get_IO_state(3) == {"command": "get_IO_state", "IO_Num": 3}
    assert P.set_manual_tool_frame("weld", [0, 0, 0.12, 0, 0, 0], 1.0, [0, 0, 0.05]) == {
        "command": "set_manual_tool_frame", "tool_name": "weld", "tool_pose": [0, 0, 120000, 0, 0, 0],
        "payload": 1000, "position": [0, 0, 50000]}
    assert P.set_manual_work_frame("table", [0.3, 0, 0, 0, 0, 0]) == {
        "command": "set_manual_work_frame", "frame_name": "table", "frame_pose": [300000, 0, 0, 0, 0, 0]}
    assert P.set_change_tool_frame("weld") == {"command": "set_change_tool_frame", "tool_name": "weld"}
    assert P.set_change_work_frame("Base") == {"command": "set_change_work_frame", "frame_name": "Base"}
    with pytest.raises(ValueError, match="10 characters"):
        P.set_change_tool_frame("a_very_long_name")
    assert P.HANDSHAKE_COMMANDS[0] == "get_arm_software_info" and P.HANDSHAKE_COMMANDS[-1] == "get_DH_data"
    assert len(P.HANDSHAKE_COMMANDS) == 11


# -- replies ---------------------------------------------------------------------------------


def test_reply_matching_by_tag_and_result_key():
    assert P.reply_tag({"state": "current_arm_state"}) == "current_arm_state"
    assert P.reply_tag({"command": "arm_software_info", "Product_version": "RM65-BI"}) == "arm_software_info"
    assert "current_arm_state" in P.expected_reply_tags("get_current_arm_state")
    assert "arm_software_info" in P.expected_reply_tags("get_arm_software_info")
    assert P.reply_ok("movej", {"command": "movej", "receive_state": True})
    assert not P.reply_ok("movel", {"command": "movel", "receive_state": False})
    assert not P.reply_ok("set_arm_stop", {"command": "set_arm_stop", "arm_stop": False})
    assert not P.reply_ok("set_DO_state", {"command": "set_DO_state", "set_state": False})
    assert P.is_trajectory_event({"state": "current_trajectory_state", "trajectory_state": True})
    ev = P.parse_trajectory_event({"state": "current_trajectory_state", "trajectory_state": False, "device": 0,
                                   "trajectory_connect": 0})
    assert ev == P.TrajectoryEvent(False, 0, 0)


@pytest.mark.parametrize(
    "arm_state, codes, fmt",
    [
        ({"err": [0]}, (), "list"),
        ({"err": [0x1003, 0]}, (0x1003,), "list"),
        ({"err": 0x100D}, (0x100D,), "scalar"),
        ({"arm_err": 0x1002, "sys_err": 0x5007}, (0x1002, 0x5007), "arm_sys"),
    ],
)
def test_arm_state_is_parsed_in_all_three_documented_error_formats(arm_state, codes, fmt):
    msg = {"state": "current_arm_state",
           "arm_state": {"joint": [107149, -84991, 112484, -130772, 64784, 85805],
                         "pose": [150269, -219514, 597973, 782, 409, 1043], **arm_state}}
    r = P.parse_arm_state(msg)
    assert r.error_codes == codes and r.err_format == fmt
    np.testing.assert_allclose(np.degrees(r.joints_rad), [107.149, -84.991, 112.484, -130.772, 64.784, 85.805])
    np.testing.assert_allclose(r.pose, [0.150269, -0.219514, 0.597973, 0.782, 0.409, 1.043])


def test_arm_state_builder_round_trips():
    for fmt in ("list", "scalar", "arm_sys"):
        msg = P.arm_state_message(np.radians([1, 2, 3, 4, 5, 6]), [0.1, 0.2, 0.3, 0.1, 0.2, 0.3], [0x1003], fmt)
        assert P.parse_arm_state(msg).error_codes == (0x1003,)


def test_bad_arm_state_raises_protocol_error():
    with pytest.raises(P.ProtocolError):
        P.parse_arm_state({"state": "current_arm_state", "arm_state": {"joint": [0] * 6, "pose": [0] * 6}})
    with pytest.raises(P.ProtocolError):
        P.parse_arm_state({"state": "current_arm_state", "arm_state": {"joint": [0] * 5, "pose": [0] * 6, "err": [0]}})


def test_error_codes_decode_to_text():
    assert P.describe_error(0x1003) == "0x1003: target unreachable (singularity)"
    assert P.describe_error(0x100D).endswith("collision detected")
    assert "unknown" in P.describe_error(0x7777)
    assert P.describe_joint_flags(0x0041) == ["FOC error", "over-current"]
