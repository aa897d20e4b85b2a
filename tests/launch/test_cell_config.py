"""The `cell` command without starting anything: the shipped cell.yaml, the plan per mode, overrides,
parameter files and the one-line errors (exit code 2)."""
from __future__ import annotations

import signal
import textwrap

import pytest
import yaml

from rosproc import REPO
from stud_bringup import launch as cell_launch
from stud_bringup.launch import CellConfigError, child_specs, load_config, plan_cell, write_params_file

CELL_YAML = REPO / "src" / "stud_bringup" / "config" / "cell.yaml"


@pytest.fixture(scope="module")
def cfg() -> dict:
    return load_config(CELL_YAML)


def plan(cfg, mode, **kw):
    nodes, notes = plan_cell(cfg, mode, out_dir="/out", check_installed=False, **kw)
    return {n.name: n for n in nodes}, notes


def test_shipped_modes_run_the_documented_nodes(cfg):
    sim, _ = plan(cfg, "sim")
    assert list(sim) == ["drawing", "camera", "registration", "matcher", "arm_simulator", "arm_driver",
                         "state_publisher", "inspector", "cell_sequencer", "hmi"]
    # the TF of the camera is the hand-eye the camera and the driver use
    assert sim["state_publisher"].params["hand_eye_xyz_m"] == sim["arm_driver"].params["hand_eye_xyz_m"]
    assert sim["camera"].params["pose_source"] == "arm"
    assert sim["arm_driver"].params["tcp_port"] == 8080 and sim["arm_driver"].start_after == ("arm_simulator",)
    assert sim["arm_simulator"].argv[-4:] == ["--port", "8080", "--time-scale", "1.0"]  # typed vars in a string list
    assert sim["arm_driver"].params["journal_file"] == "/out/weld_journal.jsonl"
    assert sim["cell_sequencer"].exit_on and sim["drawing"].required
    replay, _ = plan(cfg, "replay", cli_vars={"bag": "/bags/run1"})
    assert list(replay) == ["bag_play", "pose_rebase", "drawing", "registration", "matcher", "state_publisher", "hmi"]
    assert replay["bag_play"].argv[:7] == ["ros2", "bag", "play", "/bags/run1", "--delay", "1.0",
                                           "--wait-for-subscribers"]
    # only the sensor topics: the cell's own drawing and registration nodes publish the rest
    argv = replay["bag_play"].argv
    played = argv[argv.index("--topics") + 1:argv.index("--remap")]
    assert sorted(played) == ["/camera/color/camera_info", "/camera/color/image_raw", "/camera/depth/image_raw",
                              "/camera/pose"]
    # the recorded poses go to pose_rebase, which poses the camera with the hand-eye in use
    assert argv[argv.index("--remap") + 1:] == ["/camera/pose:=/camera/pose_recorded"]
    assert replay["bag_play"].start_after == ("registration", "matcher", "pose_rebase")
    rebase = replay["pose_rebase"].params
    assert rebase["recorded_hand_eye_xyz_m"] == rebase["hand_eye_xyz_m"] == sim["camera"].params["hand_eye_xyz_m"]
    hw, _ = plan(cfg, "hardware")
    assert "camera" not in hw and "arm_simulator" not in hw
    assert hw["arm_driver"].params["arm_ip"] == "192.168.1.18"
    # a streaming vendor camera becomes triggered shots posed by the arm (the shot node, not the driver)
    assert "shot" in hw and not hw["arm_driver"].params.get("publish_camera_pose", False)
    assert hw["shot"].params["hand_eye_xyz_m"] == hw["arm_driver"].params["hand_eye_xyz_m"]
    assert hw["arm_driver"].start_after == ()  # the simulator is not part of this launch
    assert "state_publisher" in hw


def test_command_line_overrides_beat_mode_and_node_params(cfg):
    nodes, notes = plan(cfg, "sim", sets=["matcher.algorithm=fpm", "camera.depth_noise_m=0.001",
                                          "camera.hand_eye_xyz_m=[0.05, 0, 0.1]"],
                        cli_vars={"drawing": "/parts/p.dxf", "arm_port": 9000}, without_nodes=["hmi"],
                        respawn_driver=True)
    assert nodes["matcher"].params["algorithm"] == "fpm"
    assert nodes["camera"].params["depth_noise_m"] == 0.001
    assert nodes["camera"].params["hand_eye_xyz_m"] == [0.05, 0.0, 0.1]  # mixed ints/floats -> doubles
    assert nodes["drawing"].params["drawing_file"] == "/parts/p.dxf"
    assert nodes["arm_driver"].params["tcp_port"] == 9000 and nodes["arm_simulator"].argv[-3] == "9000"
    assert nodes["arm_driver"].respawn and "hmi" not in nodes and not notes
    hw, _ = plan(cfg, "hardware", sets=["arm_driver.arm_ip=10.0.0.7"])
    assert hw["arm_driver"].params["arm_ip"] == "10.0.0.7"
    replay, notes = plan(cfg, "replay", cli_vars={"bag": "/b"}, with_nodes=["arm_simulator", "arm_driver"],
                         respawn_driver=False)
    assert list(replay)[-2:] == ["arm_simulator", "arm_driver"]
    assert replay["arm_driver"].start_after == ("arm_simulator",)


@pytest.mark.parametrize("mode, kw, message", [
    ("weld", {}, "unknown mode 'weld' (this cell has: sim, replay, hardware, calibrate, "),
    ("replay", {}, "--mode replay needs --bag DIR"),
    ("sim", {"sets": ["matcher=fpm"]}, "expected NODE.PARAM=VALUE"),
    ("sim", {"sets": ["ghost.x=1"]}, "unknown node 'ghost'"),
    ("hardware", {"sets": ["camera.seed=1"]}, "node 'camera' is not part of mode hardware"),
    ("sim", {"with_nodes": ["ghost"]}, "unknown node 'ghost'"),
    ("sim", {"sets": ["camera.hand_eye_xyz_m=[1, a]"]}, "list elements must be all numbers"),
])
def test_bad_requests_are_one_line_errors(cfg, mode, kw, message):
    with pytest.raises(CellConfigError) as info:
        plan(cfg, mode, **kw)
    assert message in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize("text, message", [
    ("nodes: {a: {package: p, executable: e}}\nmodes: {sim: {nodes: [a, b]}}", "modes.sim.nodes: unknown node 'b'"),
    ("nodes: {a: {package: p, executable: e, parms: {}}}\nmodes: {sim: {nodes: [a]}}",
     "nodes.a: unknown key 'parms'"),
    ("nodes: {a: {package: p}}\nmodes: {sim: {nodes: [a]}}", "package and executable must both be strings"),
    ("nodes: {a: {cmd: [x], package: p, executable: e}}\nmodes: {sim: {nodes: [a]}}", "either package + executable"),
    ("nodes: {a: {cmd: [x], required: yes-please}}\nmodes: {sim: {nodes: [a]}}", "nodes.a.required: must be true"),
    ("nodes: {a: {cmd: [x], start_after: b}}\nmodes: {sim: {nodes: [a]}}", "start_after: unknown node 'b'"),
    ("nodes: {a: {cmd: [x], start_after: [a]}}\nmodes: {sim: {nodes: [a]}}", "cannot wait for itself"),
    ("nodes: {a: {cmd: [x]}}\nmodes: {sim: {nodes: [a], params: {z: {}}}}", "modes.sim.params: unknown node 'z'"),
    ("nodes: {a: {cmd: [x]}}\nmodes: {sim: {nodes: [a]}}\nlaunch: {sigint_timeout_s: -1}", "launch.sigint_timeout_s"),
    ("nodes: {a: {cmd: [x]}}\nmode: {}", "top level: unknown key 'mode'"),
    ("nodes: [a: 1", "not valid YAML"),
])
def test_bad_cell_yaml_is_a_one_line_error_naming_the_key(tmp_path, text, message):
    path = tmp_path / "cell.yaml"
    path.write_text(text)
    with pytest.raises(CellConfigError) as info:
        load_config(path)
    assert message in str(info.value) and str(path) in str(info.value) and "\n" not in str(info.value)


def test_missing_executables_skip_optional_nodes_and_stop_required_ones(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text(textwrap.dedent("""\
        nodes:
          real: {cmd: [python3, -c, "pass"]}
          later: {package: stud_planner, executable: not_written_yet, optional: true}
          broken: {cmd: [/nonexistent/tool]}
        modes:
          ok: {nodes: [real, later]}
          bad: {nodes: [real, broken]}
        """))
    cfg = load_config(path)
    nodes, notes = plan_cell(cfg, "ok", out_dir=str(tmp_path))
    assert notes == ["skipping later: stud_planner/not_written_yet is not installed"]
    assert nodes[1].skip and nodes[0].skip is None
    with pytest.raises(CellConfigError, match="cannot launch broken: command '/nonexistent/tool' is not installed"):
        plan_cell(cfg, "bad", out_dir=str(tmp_path))


def test_params_file_is_a_ros2_params_file_with_types_kept(cfg, tmp_path):
    nodes, _ = plan(cfg, "sim", sets=["camera.seed=7", "camera.mark_depth_dropout=true", "drawing.mark_layer=007"])
    path = write_params_file(nodes["camera"], tmp_path)
    data = yaml.safe_load(path.read_text())
    params = data["/**"]["ros__parameters"]
    assert params["seed"] == 7 and params["mark_depth_dropout"] is True and params["depth_noise_m"] == 0.0005
    assert params["hand_eye_rpy_deg"] == [0.0, 0.0, 0.0]
    drawing = yaml.safe_load(write_params_file(nodes["drawing"], tmp_path).read_text())["/**"]["ros__parameters"]
    assert drawing["mark_layer"] == 7  # YAML reads 007 as a number: documented, say "'007'" for a string
    cmd = nodes["camera"].command(str(path))
    assert cmd[-3:] == ["--ros-args", "--params-file", str(path)]
    assert nodes["hmi"].command(None) == nodes["hmi"].argv  # no parameters: no --ros-args at all


def test_every_node_that_takes_views_subscribes_reliably_in_the_cell(cfg):
    """In every mode the views come from reliable publishers (the camera, shot and pose_rebase nodes,
    the driver's /camera/pose, ros2 bag play): the cell's consumers take them reliably, nothing is lost
    on the way. Standalone, the nodes keep sensor-data QoS (any vendor driver matches)."""
    from rclpy.qos import ReliabilityPolicy

    from stud_common import ros_io

    for mode in ("sim", "replay", "hardware", "calibrate", "verify"):
        nodes, _ = plan(cfg, mode, cli_vars={"bag": "/bags/run1"} if mode == "replay" else None)
        takers = [n for n in ("registration", "matcher", "inspector", "hand_eye_calibrator", "pose_rebase")
                  if n in nodes]
        assert takers, mode
        for name in takers:
            assert nodes[name].params["sensor_qos"] == "reliable", (mode, name)
    assert ros_io.sensor_qos("reliable").reliability == ReliabilityPolicy.RELIABLE
    assert ros_io.sensor_qos(ros_io.SENSOR_QOS_PARAM.default).reliability == ReliabilityPolicy.BEST_EFFORT


def test_only_our_executables_are_asked_for_their_stacks(cfg, tmp_path):
    """SIGUSR1 prints a stuck node's stacks (stud_common.stacks); to a command of another package
    (ros2 bag) it would be a kill, so it is not sent there."""
    replay, _ = plan(cfg, "replay", cli_vars={"bag": "/bags/run1"})
    specs = {s.name: s for s in child_specs(list(replay.values()), tmp_path)}
    assert specs["bag_play"].stack_dump_signal is None
    assert specs["matcher"].stack_dump_signal == signal.SIGUSR1
    assert specs["pose_rebase"].stack_dump_signal == signal.SIGUSR1


def test_remaps_become_ros_args(tmp_path):
    path = tmp_path / "cell.yaml"
    path.write_text("nodes: {m: {cmd: [python3], remaps: {/camera/depth/image_raw: /cam/aligned_depth}}}\n"
                    "modes: {hw: {nodes: [m], remaps: {m: {/camera/color/image_raw: /cam/color}}}}\n")
    nodes, _ = plan_cell(load_config(path), "hw", out_dir=str(tmp_path))
    assert nodes[0].command(None)[-5:] == ["--ros-args", "-r", "/camera/depth/image_raw:=/cam/aligned_depth",
                                            "-r", "/camera/color/image_raw:=/cam/color"]


def run_main(capsys, *argv) -> tuple[int, str, str]:
    code = cell_launch.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("argv, message", [
    (["--mode", "weld"], "unknown mode 'weld'"),
    (["--mode", "replay"], "--mode replay needs --bag DIR"),
    (["--mode", "replay", "--bag", "/nonexistent/bag"], "--bag /nonexistent/bag: no such bag"),
    (["--mode", "sim", "--drawing", "/nonexistent.dxf"], "--drawing /nonexistent.dxf: no such file"),
    (["--mode", "sim", "--params", "/nonexistent/cell.yaml"], "cannot read /nonexistent/cell.yaml"),
    (["--bag", "x"], "the following arguments are required: --mode"),
    (["--mode", "sim", "--var", "novalue"], "--var 'novalue': expected KEY=VALUE"),
])
def test_main_usage_errors_exit_2_with_one_line(capsys, argv, message):
    code, out, err = run_main(capsys, *argv)
    assert code == 2 and message in err and err.count("\n") == 1 and err.startswith("cell")
    assert out == ""


def test_main_dry_run_prints_commands_with_params_files(capsys, tmp_path):
    code, out, err = run_main(capsys, "--mode", "sim", "--dry-run", "--params", str(CELL_YAML), "--out",
                              str(tmp_path), "--no-hmi", "--set", "matcher.algorithm=bfs")
    assert code == 0, err
    assert f"--params-file {tmp_path}/params/matcher.yaml" in out
    assert "{sensor_qos: reliable, algorithm: bfs, normal_window_m: 0.02, per_view_registration: false}" in out
    assert "# hmi" not in out and "--port 8080" in out
    assert not (tmp_path / "params").exists()  # a dry run writes nothing


def test_the_hand_eye_vars_reach_every_node_that_poses_the_camera(cfg, tmp_path):
    sim, _ = plan(cfg, "sim")
    cam = sim["camera"].params
    assert cam["true_hand_eye_xyz_m"] == cam["hand_eye_xyz_m"] == [0.05, 0.0, -0.1]  # true defaults to believed
    assert cam["hand_eye_file"] == sim["arm_driver"].params["hand_eye_file"] == ""
    # the empty limits mapping (the solver's defaults) is no parameter at all: rcl cannot parse "{}" before other keys
    assert "hand_eye_limits" not in cam
    assert "hand_eye_limits" not in yaml.safe_load(write_params_file(sim["camera"], tmp_path).read_text())["/**"][
        "ros__parameters"]
    nodes, _ = plan(cfg, "sim", cli_vars={"hand_eye_file": "/cal/hand_eye.yaml", "hand_eye_limits": {"max_rms_mm": 0.3},
                                          "true_hand_eye_rpy_deg": [1.0, -0.5, 0.8]})
    for name in ("camera", "arm_driver"):
        assert nodes[name].params["hand_eye_file"] == "/cal/hand_eye.yaml"
        assert nodes[name].params["hand_eye_limits"] == {"max_rms_mm": 0.3}
    assert nodes["camera"].params["true_hand_eye_rpy_deg"] == [1.0, -0.5, 0.8]
    assert nodes["camera"].params["hand_eye_rpy_deg"] == [0.0, 0.0, 0.0]  # believed stays
    hw, _ = plan(cfg, "hardware", cli_vars={"hand_eye_file": "/cal/hand_eye.yaml"})
    assert hw["shot"].params["hand_eye_file"] == hw["arm_driver"].params["hand_eye_file"] == "/cal/hand_eye.yaml"
    for mode, task in (("calibrate", "calibrate"), ("verify", "verify"), ("calibrate_hardware", "calibrate"),
                       ("verify_hardware", "verify")):
        nodes, _ = plan(cfg, mode)
        calibrator = nodes["hand_eye_calibrator"]
        assert calibrator.exit_on and calibrator.params["task"] == task and calibrator.params["output_dir"] == "/out"
        assert ("camera" in nodes) == (not mode.endswith("hardware")) and ("shot" in nodes) == mode.endswith("hardware")


def test_an_empty_registration_station_reaches_the_sequencer_as_an_empty_list(cfg, tmp_path):
    """`--var registration_station_xyz_m=[]`: no station, the board is searched for. ROS has no type for an
    empty list; the parameter file carries it and the node reads it as [] (ros_io.declare_params)."""
    nodes, _ = plan(cfg, "sim", cli_vars=dict([cell_launch.parse_assignment("registration_station_xyz_m=[]", "--var")]))
    params = yaml.safe_load(write_params_file(nodes["cell_sequencer"], tmp_path).read_text())["/**"]["ros__parameters"]
    assert params["registration_station_xyz_m"] == []


def test_the_rail_vars_reach_the_simulator_driver_state_publisher_camera_hmi_and_sequencer(cfg):
    """rail_length_m 0 (the default): no rail, the arm fixed; every node that knows of the rail gets the same
    values, the simulated truth only the simulator and the camera (the cell never reads it)."""
    sim, _ = plan(cfg, "sim")
    argv = sim["arm_simulator"].argv
    assert argv[argv.index("--rail-length-m") + 1] == "0.0" and "--rail-mount-xyz-m=[0.0, 0.0, 0.0]" in argv
    assert argv[-4:] == ["--port", "8080", "--time-scale", "1.0"]
    driver = sim["arm_driver"].params
    assert driver["rail_length_m"] == 0.0 and driver["workspace_max_m"] == [0.7, 0.7, 1.1]   # the driver's defaults
    assert driver["workspace_min_m"] == [-0.7, -0.7, -0.02] and driver["rail_pos_unit_m"] == 1e-6
    assert not any(k.startswith("true_rail") for k in driver)
    rail = {"rail_length_m": 2.0, "rail_mount_xyz_m": [0.0, 0.0, 0.1], "true_rail_scale_ppm": 300.0,
            "workspace_max_m": [2.7, 0.7, 1.1]}
    nodes, _ = plan(cfg, "sim", cli_vars=rail)
    argv = nodes["arm_simulator"].argv
    assert argv[argv.index("--rail-length-m") + 1] == "2.0" and "--rail-mount-xyz-m=[0.0, 0.0, 0.1]" in argv
    assert argv[argv.index("--true-rail-scale-ppm") + 1] == "300.0"
    for name in ("arm_driver", "state_publisher", "hmi", "cell_sequencer"):
        params = nodes[name].params
        assert params["rail_length_m"] == 2.0 and params["rail_mount_xyz_m"] == [0.0, 0.0, 0.1], name
        assert not any(k.startswith("true_rail") for k in params), name
    assert nodes["arm_driver"].params["workspace_max_m"] == [2.7, 0.7, 1.1]
    assert nodes["camera"].params["true_rail_scale_ppm"] == 300.0 and "rail_length_m" not in nodes["camera"].params
