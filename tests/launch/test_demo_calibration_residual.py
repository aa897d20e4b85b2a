"""The demo's simulated camera sits a calibration's residual off the hand-eye the cell uses (never
exactly where the cell believes), unless the user sets up a hand-eye case of their own."""
from __future__ import annotations

import ast

import numpy as np
import pytest

from stud_bringup.demo import CALIBRATION_RESIDUAL, calibration_residual_size, calibration_residual_vars
from stud_bringup.launch import default_config_path, load_config
from stud_common.rotations import transform_xyz_rpy
from stud_perception.hand_eye_solvers import rotation_angle_deg


def test_the_simulated_camera_is_the_residual_off_the_typed_hand_eye():
    args = calibration_residual_vars([])
    values = dict(a.split("=", 1) for a in args[1::2])
    assert args[0::2] == ["--var", "--var"] and set(values) == {"true_hand_eye_xyz_m", "true_hand_eye_rpy_deg"}
    typed = load_config(default_config_path())["vars"]
    believed = transform_xyz_rpy(typed["hand_eye_xyz_m"], typed["hand_eye_rpy_deg"])
    true = transform_xyz_rpy(ast.literal_eval(values["true_hand_eye_xyz_m"]),
                             ast.literal_eval(values["true_hand_eye_rpy_deg"]))
    mm, deg = calibration_residual_size()
    assert 1e3 * np.linalg.norm(true[:3, 3] - believed[:3, 3]) == pytest.approx(mm, abs=1e-3)
    assert float(rotation_angle_deg(true[:3, :3], believed[:3, :3])) == pytest.approx(deg, abs=1e-4)
    # a residual, not zero, and within what the daily check accepts (0.5 mm / 0.15 deg)
    assert 0.1 < mm < 0.5 and 0.02 < deg < 0.15 and np.any(CALIBRATION_RESIDUAL[1])


@pytest.mark.parametrize("var", ["hand_eye_file=/tmp/hand_eye.yaml", "true_hand_eye_xyz_m=[0.05, 0, -0.1]",
                                 " hand_eye_rpy_deg =[0, 0, 1]"])
def test_a_hand_eye_set_by_the_user_is_left_as_it_is(var):
    assert calibration_residual_vars(["arm_time_scale=1.0", var]) == []
