"""hand_eye.yaml: what the calibrator writes is what the nodes read, and a file that must not be used
is refused in one line naming the file, the field and the value."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from stud_common.hand_eye_in_use import HandEyeFileError, HandEyeLimits, load_hand_eye_file, resolve_hand_eye
from stud_perception.hand_eye import calibrate_hand_eye
from stud_perception.hand_eye_file import calibration_record, write_yaml
from stud_perception.hand_eye_solvers import rotation_angle_deg
from test_hand_eye import DRAWING, X_OFF, reachable_tool_poses, synthetic_shots


@pytest.fixture(scope="module")
def result():
    return calibrate_hand_eye(synthetic_shots(X_OFF, reachable_tool_poses(), 11), DRAWING)


def _write(tmp_path, record, name="hand_eye.yaml"):
    return write_yaml(tmp_path / name, record, "test file")


def test_written_calibration_reads_back_as_the_transform_with_its_figures(tmp_path, result):
    path = _write(tmp_path, calibration_record(result, poses_refused=3, believed_xyz_m=[0.05, 0, -0.1],
                                                believed_rpy_deg=[0, 0, 0]))
    text = path.read_text()
    assert text.startswith("# test file\n")
    data = yaml.safe_load(text)
    assert data["accepted"] is True and data["poses"]["used"] == len(reachable_tool_poses())
    assert data["poses"]["refused"] == 3 and len(data["shots"]) == data["poses"]["used"]
    assert set(data["methods"]) >= {"tsai", "park", "andreff"} and data["methods_agree"] is True
    assert data["residuals"]["intrinsics"] == "ok"
    cal = load_hand_eye_file(path)
    assert cal.source == "file" and cal.path == str(path.resolve()) and cal.date == data["date"]
    T = cal.T_tool_cam
    assert np.linalg.norm(T[:3, 3] - result.T_tool_cam[:3, 3]) < 1e-6
    assert rotation_angle_deg(T[:3, :3], result.T_tool_cam[:3, :3]) < 1e-5  # 9-digit quaternion
    assert cal.position_rms_mm == pytest.approx(result.rms_mm, abs=1e-4)
    assert cal.poses_used == result.n_shots
    summary = cal.summary()
    assert summary["source"] == "file" and len(summary["quaternion_xyzw"]) == 4
    assert summary["reprojection_rms_px"] is None  # synthetic shots have no pixels: NaN -> null


def test_without_a_file_the_typed_values_are_used():
    cal = resolve_hand_eye("", [0.05, 0.0, -0.1], [0.0, 0.0, 90.0])
    assert cal.source == "parameters" and cal.xyz_m == (0.05, 0.0, -0.1)
    assert np.allclose(cal.T_tool_cam[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert cal.summary()["date"] is None and cal.summary()["position_rms_mm"] is None


def _edited(tmp_path, result, edit):
    record = calibration_record(result)
    edit(record)
    return _write(tmp_path, record)


@pytest.mark.parametrize("edit, message", [
    (lambda r: r.update(accepted=False, problems=["rotations too small: 3 deg"]),
     "accepted is False: the calibration was refused (rotations too small: 3 deg)"),
    (lambda r: r["hand_eye"].update(rpy_deg=[0.0, 0.0, 10.0]), "hand_eye.rpy_deg [0.0, 0.0, 10.0] and quaternion_xyzw"),
    (lambda r: r["hand_eye"].pop("xyz_m"), "missing field hand_eye.xyz_m"),
    (lambda r: r["hand_eye"].update(xyz_m=[0.05, "a", 0.1]),
     "hand_eye.xyz_m must be 3 finite numbers, got [0.05, 'a', 0.1]"),
    (lambda r: r["hand_eye"].update(child_frame="camera_link"), "hand_eye.child_frame is 'camera_link'"),
    (lambda r: r.update(format="other 2"), "format is 'other 2'"),
    (lambda r: r["poses"].update(used=7), "refused: poses.used 7: too few poses, need at least 12"),
    (lambda r: r["poses"].update(rotation_spread_deg=[40.0, 2.0, 1.0]), "rotations about one axis only"),
    (lambda r: r["residuals"].update(position_max_mm=1.5), "residuals.position_max_mm 1.5 mm exceeds the limit 1 mm"),
])
def test_a_file_that_must_not_be_used_is_refused_naming_the_field(tmp_path, result, edit, message):
    path = _edited(tmp_path, result, edit)
    with pytest.raises(HandEyeFileError) as info:
        load_hand_eye_file(path)
    assert str(path) in str(info.value) and message in str(info.value) and "\n" not in str(info.value)


def test_the_readers_limits_decide(tmp_path, result):
    path = _write(tmp_path, calibration_record(result))
    load_hand_eye_file(path, HandEyeLimits())
    strict = HandEyeLimits(max_rms_mm=result.rms_mm / 2)
    with pytest.raises(HandEyeFileError, match=r"residuals.position_rms_mm .* exceeds the limit"):
        load_hand_eye_file(path, strict)
    with pytest.raises(HandEyeFileError, match="too few poses"):
        resolve_hand_eye(str(path), [0, 0, 0], [0, 0, 0], HandEyeLimits(min_poses=100))


def test_unreadable_files_are_one_line_errors(tmp_path):
    with pytest.raises(HandEyeFileError, match="cannot read the calibration file"):
        load_hand_eye_file(tmp_path / "missing.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("hand_eye: [1, 2\n")
    with pytest.raises(HandEyeFileError, match="not valid YAML") as info:
        load_hand_eye_file(bad)
    assert "\n" not in str(info.value)
    bad.write_text("- 1\n")
    with pytest.raises(HandEyeFileError, match="not a calibration file"):
        load_hand_eye_file(bad)


def test_rpy_in_the_file_is_the_cells_convention(tmp_path, result):
    cal = load_hand_eye_file(_write(tmp_path, calibration_record(result)))
    from stud_common.rotations import rpy_to_matrix

    assert np.allclose(rpy_to_matrix(*np.radians(cal.rpy_deg)), result.T_tool_cam[:3, :3], atol=1e-7)
    assert math.isclose(np.linalg.norm(cal.summary()["quaternion_xyzw"]), 1.0, abs_tol=1e-9)
