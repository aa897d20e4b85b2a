"""The planner's reach verdict is the driver's: for random stud poses around the arm (position, normal
up to 35 deg from vertical, the arm anywhere in its workspace) the cell sequencer's CellReach -- built
from the JSON the driver publishes on /arm/reach_config -- accepts exactly the studs the driver's weld
check accepts from wherever the arm stands, with the same reason for the refused ones. The cell's own
configuration is used (cell.yaml: standoff, working branch, hand-eye).

``REACH_AGREEMENT_EXAMPLES=3000 python -m pytest tests/cell/test_reach_planner_equals_driver.py``
draws thousands (the profile's count otherwise: 20 locally, 100 in CI)."""
from __future__ import annotations

import os

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rm65_driver.driver.params import PARAMS, safety_checker
from rm65_driver.weld.reach import ReachConfig
from stud_bringup.launch import default_config_path, load_config
from stud_cell.cell_reach import CellReach
from stud_common.hand_eye_in_use import resolve_hand_eye

CELL = load_config(default_config_path())


def cell_driver_params() -> dict:
    """The arm driver's parameter values in the cell (its defaults, cell.yaml's vars and overrides)."""
    v, node = CELL["vars"], CELL["nodes"]["arm_driver"]["params"]
    p = {prm.name: prm.default for prm in PARAMS}
    p.update(standoff_m=v["standoff_m"], stud_length_mm=v["stud_length_mm"],
             min_stud_spacing_m=v["min_stud_spacing_m"], preferred_joint_signs=node["preferred_joint_signs"])
    return p


P = cell_driver_params()
HAND_EYE = resolve_hand_eye("", CELL["vars"]["hand_eye_xyz_m"], CELL["vars"]["hand_eye_rpy_deg"]).T_tool_cam
DRIVER = safety_checker(P, HAND_EYE)
PUBLISHED = DRIVER.reach_for(P["standoff_m"], P["plunge_m"]).config.to_json()   # what /arm/reach_config carries
PLANNER = CellReach.from_config(ReachConfig.from_json(PUBLISHED))
KIN = DRIVER.kin


def _arm_poses(n: int, seed: int = 7) -> np.ndarray:
    """Joints (n, 6) anywhere in the limits whose tool tip and flange are inside the workspace box and
    above the table: where the arm may stand when a stud comes."""
    rng = np.random.default_rng(seed)
    lo, hi = KIN.limits_rad[:, 0], KIN.limits_rad[:, 1]
    box_lo, box_hi = np.asarray(DRIVER.limits.workspace_min_m), np.asarray(DRIVER.limits.workspace_max_m)
    out: list[np.ndarray] = []
    while len(out) < n:
        q = rng.uniform(lo, hi)
        F = KIN.fk(q)
        tip = (F @ DRIVER.tool_T)[:3, 3]
        inside = np.all((tip > box_lo) & (tip < box_hi)) and np.all((F[:3, 3] > box_lo) & (F[:3, 3] < box_hi))
        if inside and tip[2] > 0.05:
            out.append(q)
    return np.array(out)


ARM_POSES = _arm_poses(64)


def stud(r, azimuth, z, tilt_deg, tilt_azimuth):
    p = np.array([r * np.cos(azimuth), r * np.sin(azimuth), z])
    t = np.radians(tilt_deg)
    n = np.array([np.sin(t) * np.cos(tilt_azimuth), np.sin(t) * np.sin(tilt_azimuth), np.cos(t)])
    return p, n


EXAMPLES = int(os.environ.get("REACH_AGREEMENT_EXAMPLES", "0")) or None


@settings(**({"max_examples": EXAMPLES} if EXAMPLES else {}), deadline=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(r=st.floats(0.05, 0.68), azimuth=st.floats(-np.pi, np.pi), z=st.floats(-0.03, 0.35),
       tilt_deg=st.floats(0.0, 35.0), tilt_azimuth=st.floats(-np.pi, np.pi), arm=st.integers(0, len(ARM_POSES) - 1))
def test_the_planners_verdict_on_a_random_stud_is_the_drivers_from_wherever_the_arm_stands(r, azimuth, z, tilt_deg,
                                                                                           tilt_azimuth, arm):
    p, n = stud(r, azimuth, z, tilt_deg, tilt_azimuth)
    planner = PLANNER.stud(p, n)
    driver = DRIVER.check_target(p, n, P["standoff_m"], ARM_POSES[arm], P["plunge_m"])
    assert planner.ok == driver.ok, (planner.reason, driver.reason)
    if not driver.ok:
        assert driver.reason == f"unreachable: {planner.reason}"
        return
    plan = driver.plan  # the driver's plan welds along the normal, its moves inside the workspace
    assert plan is not None
    tip = KIN.fk(plan.q_contact) @ DRIVER.tool_T
    np.testing.assert_allclose(tip[:3, 3], p, atol=1e-5)
    assert float(tip[:3, 2] @ -n) > np.cos(np.radians(0.01))
    legs = [ARM_POSES[arm], *plan.waypoints]
    assert not any(DRIVER.check_joint_path(a, b, "move") for a, b in zip(legs[:-1], legs[1:]))


def test_the_draw_holds_studs_of_both_kinds_and_the_published_config_is_the_drivers():
    """Not vacuous: of a few fixed draws some are weldable and some not; the JSON round trip loses nothing."""
    rng = np.random.default_rng(0)
    verdicts = [PLANNER.stud(*stud(rng.uniform(0.05, 0.68), rng.uniform(-np.pi, np.pi), rng.uniform(-0.03, 0.35),
                                   rng.uniform(0, 35), rng.uniform(-np.pi, np.pi))).ok for _ in range(12)]
    assert 0 < sum(verdicts) < len(verdicts), verdicts
    assert ReachConfig.from_json(PUBLISHED) == DRIVER.reach_for(P["standoff_m"], P["plunge_m"]).config
    assert PLANNER.config.standoff_m == P["standoff_m"] == 0.06
    assert PLANNER.config.preferred_joint_signs == (0, 0, -1, 0, -1, 0)
    np.testing.assert_array_equal(PLANNER.config.hand_eye_matrix, HAND_EYE)
