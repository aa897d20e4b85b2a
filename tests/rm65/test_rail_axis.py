"""The rail's axis model and its protocol messages (pure: units, range, time law, replies)."""
from __future__ import annotations

import pytest

from rm65_driver.protocol import messages as P
from rm65_driver.protocol.messages import ProtocolError
from rm65_driver.rail.axis import (
    RailAxis,
    RailMode,
    RailRequestError,
    expand_get_state,
    expand_set_pos,
    expand_set_speed,
    expand_state_message,
    parse_expand_state,
)


def test_positions_convert_at_the_configured_unit_and_the_travel_is_checked():
    um = RailAxis(6.0, pos_unit_m=1e-6)
    assert um.max_counts == 6_000_000 and um.check_position(1.2345674) == 1_234_567
    assert um.to_m(1_234_567) == pytest.approx(1.234567)
    tenth_mm = RailAxis(6.0, pos_unit_m=1e-4)  # a drive counting 0.1 mm
    assert tenth_mm.check_position(1.0) == 10_000
    with pytest.raises(RailRequestError, match=r"outside the travel 0..6 m"):
        um.check_position(6.001)
    with pytest.raises(RailRequestError, match="outside the travel"):
        um.check_position(-0.0001)
    with pytest.raises(RailRequestError, match="not a finite number"):
        um.check_position(float("nan"))


@pytest.mark.parametrize("kw, text", [({"length_m": 0.0}, "length_m=0.0"), ({"length_m": float("inf")}, "length_m"),
                                      ({"length_m": 3.0, "pos_unit_m": -1e-6}, "pos_unit_m"),
                                      ({"length_m": 3.0, "max_speed_m_s": 0.0}, "max_speed_m_s"),
                                      ({"length_m": 3000.0, "pos_unit_m": 1e-6}, "int32")])
def test_a_bad_axis_is_refused_naming_the_value(kw, text):
    with pytest.raises(RailRequestError, match=text):
        RailAxis(**kw)


def test_requests_are_what_the_protocol_documents():
    assert expand_set_pos(2_500, 30) == {"command": "expand_set_pos", "pos": 2500, "speed": 30}
    assert expand_set_pos(-2_500, 30, block=True)["block"] is True
    assert expand_set_speed(-50) == {"command": "expand_set_speed", "speed": -50}
    assert expand_get_state() == {"command": "expand_get_state"}
    for bad in (0, 101, 2.5):
        with pytest.raises(RailRequestError):
            expand_set_pos(0, bad)
    with pytest.raises(RailRequestError):
        expand_set_speed(-101)
    # replies are matched like the arm's: by tag, with the documented result keys
    assert P.expected_reply_tags("expand_get_state") == {"expand_get_state", "expand_state"}
    assert P.reply_ok("expand_set_pos", {"command": "expand_set_pos", "set_pos_state": False}) is False
    assert P.reply_ok("expand_set_speed", {"command": "expand_set_speed", "set_speed_state": True}) is True


def test_state_replies_parse_in_every_documented_spelling():
    r = parse_expand_state(expand_state_message(123_456, RailMode.POSITION_NEGATIVE, current_ma=900))
    assert (r.pos, r.current_ma, r.mode, r.enabled, r.moving) == (123_456, 900, RailMode.POSITION_NEGATIVE, True, True)
    # the documentation's example: string flags
    doc = {"state": "expand_state", "pos": 0, "err_flag": "0", "en_flag": "1", "current": 0, "mode": 0, "joint_id": 1}
    assert parse_expand_state(doc).moving is False
    with pytest.raises(ProtocolError, match=r"lacks \['mode'\]"):
        parse_expand_state({"state": "expand_state", "pos": 0, "err_flag": 0, "current": 0, " mode": 0})  # doc typo
    with pytest.raises(ProtocolError, match="bad value"):
        parse_expand_state({**doc, "mode": 7})
    with pytest.raises(ProtocolError, match="not an expand_state"):
        parse_expand_state({"state": "lift_state", "height": 0})
