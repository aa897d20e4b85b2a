"""Our `ros2` entry point: ament-index lookups as ros2cli does them, usage errors, hand-over."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tools" / "ros2_lite"))
from ros2_lite import ament  # noqa: E402


def ros2(*args: str, env: dict | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(["ros2", *args], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


def test_ros2_run_resolves_our_executable_through_the_ament_index_and_runs_it():
    done = ros2("run", "stud_planner", "selfcheck", "--timeout", "30")
    assert done.returncode == 0, done.stderr
    assert "self-check passed" in done.stdout


def test_ros2_run_passes_arguments_and_exit_code_through(tmp_path):
    done = ros2("run", "stud_planner", "selfcheck", "--no-such-flag-is-fine", "--timeout", "0.01", "--echo")
    assert done.returncode == 1  # an echo process that hears nothing fails: the child's code comes back


def test_ros2_run_usage_error_exits_2_with_a_message():
    done = ros2("run", "stud_planner")
    assert done.returncode == 2
    assert "required" in done.stderr and "executable_name" in done.stderr
    assert "Traceback" not in done.stderr


def test_unknown_package_and_executable_are_reported_like_ros2cli():
    done = ros2("run", "no_such_package", "x")
    assert done.returncode == 1 and done.stderr.strip() == "Package 'no_such_package' not found"
    done = ros2("run", "stud_planner", "no_such_executable")
    assert done.returncode == 1 and done.stderr.strip() == "No executable found"


def test_pkg_list_and_executables_show_our_packages():
    done = ros2("pkg", "list")
    names = done.stdout.split()
    for pkg in ("stud_welding_msgs", "stud_perception", "stud_planner", "rm65_driver", "rclpy"):
        assert pkg in names
    assert "stud_planner selfcheck" in ros2("pkg", "executables", "stud_planner").stdout


def test_executables_that_moved_to_their_own_packages_keep_their_stud_planner_names(tmp_path):
    moved = {"stud_inspection": ["inspector"], "stud_cell": ["cell_sequencer", "hand_eye_calibrator"],
             "stud_hmi": ["hmi"], "stud_bringup": ["cell", "demo"]}
    listed = ros2("pkg", "executables").stdout.splitlines()
    for package, executables in moved.items():
        for name in executables:
            assert f"{package} {name}" in listed and f"stud_planner {name}" in listed, name
    done = ros2("run", "stud_planner", "cell", "--mode", "sim", "--dry-run", "--out", str(tmp_path / "out"))
    assert done.returncode == 0, done.stderr
    assert "/lib/stud_cell/cell_sequencer " in done.stdout and "/lib/stud_hmi/hmi " in done.stdout


def test_interface_show_expands_nested_types():
    done = ros2("interface", "show", "stud_welding_msgs/msg/WeldTargetArray")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "WeldTarget[] targets" in lines
    assert "\tuint8 STATUS_OK = 0" in lines
    assert "\tstring stud_id" in lines and "\t\tfloat64 x" in lines  # WeldTarget -> Pose -> Point
    assert ros2("interface", "show", "stud_welding_msgs/action/WeldJob").stdout.count("---") == 2
    bad = ros2("interface", "show", "stud_welding_msgs/msg/Nope")
    assert bad.returncode == 1 and "Could not find" in bad.stderr


def test_executables_are_files_with_the_exec_bit_like_ros2run(tmp_path, monkeypatch):
    lib = tmp_path / "lib" / "pkg"
    (lib / ".hidden").mkdir(parents=True)
    (tmp_path / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (tmp_path / "share" / "ament_index" / "resource_index" / "packages" / "pkg").write_text("")
    for name, mode in (("tool", 0o755), ("data.txt", 0o644), (".hidden/secret", 0o755)):
        (lib / name).write_text("#!/bin/sh\n")
        (lib / name).chmod(mode)
    monkeypatch.setenv("AMENT_PREFIX_PATH", str(tmp_path))
    assert ament.package_prefix("pkg") == tmp_path
    assert [p.name for p in ament.executables("pkg", tmp_path)] == ["tool"]


def test_hands_over_to_a_real_ros2cli_when_importable(tmp_path):
    fake = tmp_path / "ros2cli"
    fake.mkdir()
    (fake / "__init__.py").write_text("")
    (fake / "cli.py").write_text("import sys\ndef main():\n    print('real ros2cli', sys.argv[1:])\n    return 7\n")
    done = ros2("pkg", "list", env={"PYTHONPATH": f"{tmp_path}:{os.environ.get('PYTHONPATH', '')}"})
    assert done.returncode == 7 and "real ros2cli ['pkg', 'list']" in done.stdout
