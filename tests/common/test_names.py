"""stud_common.names: the interface contract's names, each once, and what the nodes use."""
from __future__ import annotations

import re
from pathlib import Path

from stud_common import names

REPO = Path(__file__).resolve().parents[2]


def _constants() -> dict[str, str]:
    return {k: v for k, v in vars(names).items() if k.isupper() and isinstance(v, str)}


def test_every_name_is_absolute_distinct_and_a_ros_name():
    values = list(_constants().values())
    assert len(values) == len(set(values)) > 40
    assert all(re.fullmatch(r"(/[a-z][a-z0-9_]*)+", v) for v in values), values


def test_the_contracts_topics_are_the_ones_the_acceptance_checks_read():
    c = _constants()
    assert (c["COLOR_IMAGE"], c["DEPTH_IMAGE"], c["CAMERA_INFO"], c["CAMERA_POSE"]) == (
        "/camera/color/image_raw", "/camera/depth/image_raw", "/camera/color/camera_info", "/camera/pose")
    assert (c["DRAWING_LAYOUT"], c["REGISTRATION_RESULT"], c["WELD_TARGETS"], c["WELD_TARGET_POSES"],
            c["WELD_TARGET_MARKERS"], c["WELD_TARGET_OVERLAY"], c["ARM_STATE"], c["ARM_WELD_JOB"],
            c["DIAGNOSTICS"]) == (
        "/drawing/layout", "/registration/result", "/weld_targets", "/weld_targets/poses", "/weld_targets/markers",
        "/weld_targets/overlay", "/arm/state", "/arm/weld_job", "/diagnostics")


def test_no_node_spells_a_name_of_the_contract_in_code():
    """A topic, service or action name in a create_publisher/subscription/service/client call or an
    action server/client is one of the constants, never a string literal of its own."""
    call = re.compile(r"(create_(publisher|subscription|service|client)|Action(Server|Client))\([^)]*?\"(/[a-z_/]+)\"")
    found = []
    for path in (REPO / "src").rglob("*.py"):
        if "ros2_ws" in path.parts or path.name == "selfcheck.py":  # selfcheck: its own private topics
            continue
        found += [f"{path.relative_to(REPO)}: {m.group(4)}" for m in call.finditer(path.read_text())]
    assert found == []
