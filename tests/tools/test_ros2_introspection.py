"""`ros2 topic|node|param|service|action` against a live node over DDS, with ros2cli's output."""
from __future__ import annotations

import os
import signal
import subprocess
from pathlib import Path

import pytest
import yaml

from rosproc import python_proc, wait_for

NODES = str(Path(__file__).resolve().parent / "graph_nodes.py")


def ros2(*args: str, timeout: float = 60, input_text: str | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(["ros2", *args], capture_output=True, text=True, timeout=timeout, input=input_text,
                          env={**os.environ, "ROS2_LITE_NO_HANDOVER": "1"})


@pytest.fixture()
def talker(procs, tmp_path):
    proc = python_proc(NODES, [], tmp_path / "talker.log")
    procs.append(proc)
    wait_for(lambda: "demo_talker up" in proc.output(), 60, what="the demo_talker node")
    return proc


def test_topic_list_info_echo_and_hz(talker):
    done = ros2("topic", "list", "-t")
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert "/chatter [std_msgs/msg/String]" in lines and "/latched [std_msgs/msg/String]" in lines
    assert lines == sorted(lines)
    assert "/chatter" in ros2("topic", "list").stdout.splitlines()

    info = ros2("topic", "info", "/chatter")
    assert info.stdout.splitlines()[:2] == ["Type: std_msgs/msg/String", "Publisher count: 1"]
    verbose = ros2("topic", "info", "-v", "/latched").stdout
    assert "Node name: demo_talker" in verbose and "Durability: TRANSIENT_LOCAL" in verbose
    unknown = ros2("topic", "info", "/nope")
    assert unknown.returncode == 1 and unknown.stderr.strip() == "Unknown topic '/nope'"

    # A latched topic: echo picks transient local itself, so the message sent before it started arrives.
    once = ros2("topic", "echo", "--once", "/latched")
    assert once.returncode == 0, once.stderr
    assert once.stdout == "data: latched once\n---\n"
    field = ros2("topic", "echo", "--once", "--field", "data", "/chatter", "std_msgs/msg/String")
    assert field.stdout.startswith("hello ") and field.stdout.endswith("\n---\n")

    hz = subprocess.Popen(["ros2", "topic", "hz", "/chatter"], stdout=subprocess.PIPE, text=True,
                          start_new_session=True)
    try:
        lines = [hz.stdout.readline() for _ in range(2)]
    finally:
        os.killpg(hz.pid, signal.SIGINT)
        hz.wait(timeout=20)
    assert lines[0].startswith("average rate: ")
    assert 5.0 < float(lines[0].split(":")[1]) < 15.0  # 10 Hz
    assert lines[1].startswith("\tmin: ") and "window: " in lines[1]


def test_topic_pub_once_reaches_a_subscriber(talker):
    done = ros2("topic", "pub", "--once", "/heard", "std_msgs/msg/String", "{data: 'from the CLI'}")
    assert done.returncode == 0, done.stderr
    # (after "Waiting for at least 1 matching subscription(s)..." once a second until discovery is done)
    assert "publisher: beginning loop\npublishing #1: std_msgs.msg.String(data='from the CLI')\n\n" in done.stdout
    wait_for(lambda: "heard: from the CLI" in talker.output(), 20, what="the published message")
    bad = ros2("topic", "pub", "--once", "/heard", "std_msgs/msg/String", "{nope: 1}")
    assert bad.returncode == 1 and "Failed to populate field" in bad.stderr and "nope" in bad.stderr


def test_node_list_info_and_parameters(talker):
    assert ros2("node", "list").stdout.splitlines() == ["/demo_talker"]  # the CLI's own node is hidden
    info = ros2("node", "info", "/demo_talker").stdout.splitlines()
    assert info[0] == "/demo_talker"
    assert "    /chatter: std_msgs/msg/String" in info[info.index("  Publishers:"):]
    assert "    /heard: std_msgs/msg/String" in info[info.index("  Subscribers:"):info.index("  Publishers:")]
    assert "    /demo_talker/reset: std_srvs/srv/Trigger" in info
    assert "    /demo_job: stud_welding_msgs/action/WeldJob" in info[info.index("  Action Servers:"):]
    missing = ros2("node", "info", "/nobody")
    assert missing.returncode == 1 and "Unable to find node '/nobody'" in missing.stderr

    listed = ros2("param", "list", "/demo_talker").stdout.splitlines()
    assert {"  greeting", "  rate_hz", "  read_only_value", "  use_sim_time"} <= set(listed)
    assert ros2("param", "get", "/demo_talker", "greeting").stdout == "String value is: hello\n"
    assert ros2("param", "get", "/demo_talker", "rate_hz").stdout == "Double value is: 10.0\n"
    ok = ros2("param", "set", "/demo_talker", "greeting", "ahoy")
    assert ok.returncode == 0 and ok.stdout == "Set parameter successful\n"
    assert ros2("param", "get", "/demo_talker", "greeting", "--hide-type").stdout == "ahoy\n"
    refused = ros2("param", "set", "/demo_talker", "rate_hz", "500.0")
    assert refused.returncode == 1 and refused.stderr.startswith("Setting parameter failed")
    dumped = yaml.safe_load(ros2("param", "dump", "/demo_talker").stdout)
    assert dumped["/demo_talker"]["ros__parameters"]["greeting"] == "ahoy"
    assert dumped["/demo_talker"]["ros__parameters"]["read_only_value"] == 3
    assert ros2("param", "get", "/nobody", "x", "--timeout", "1").stderr.strip() == "Node not found"


def test_service_list_call_and_action_send_goal(talker):
    services = ros2("service", "list", "-t").stdout.splitlines()
    assert "/demo_talker/reset [std_srvs/srv/Trigger]" in services
    assert not any("/_action/" in s for s in services)  # hidden, as in ros2cli
    call = ros2("service", "call", "/demo_talker/reset", "std_srvs/srv/Trigger")
    assert call.returncode == 0, call.stderr
    assert "requester: making request: std_srvs.srv.Trigger_Request()\n\nresponse:\n" in call.stdout
    assert "std_srvs.srv.Trigger_Response(success=True, message='counter reset')" in call.stdout

    assert ros2("action", "list", "-t").stdout.splitlines() == ["/demo_job [stud_welding_msgs/action/WeldJob]"]
    goal = ros2("action", "send_goal", "-f", "/demo_job", "stud_welding_msgs/action/WeldJob",
                "{targets: [{stud_id: S1}, {stud_id: S2, pose: {position: {x: 1}}}]}")
    assert goal.returncode == 0, goal.stderr
    out = goal.stdout
    assert out.startswith("Waiting for an action server to become available...\nSending goal:\n     targets:\n")
    assert "Goal accepted with ID: " in out and "Feedback:\n    stud_id: S1" in out
    assert "Result:\n    welded:\n- S1\n- S2\n" in out
    assert out.rstrip().endswith("Goal finished with status: SUCCEEDED")


def test_output_into_a_closed_pipe_ends_quietly(talker):
    done = subprocess.run("ros2 topic echo /chatter | head -n 1", shell=True, capture_output=True, text=True,
                          timeout=60, env={**os.environ, "ROS2_LITE_NO_HANDOVER": "1"})
    assert done.stdout.startswith("data: hello")
    assert "Traceback" not in done.stderr and "BrokenPipe" not in done.stderr
    shown = subprocess.run("ros2 interface show stud_welding_msgs/msg/WeldTargetArray | head -n 2", shell=True,
                           capture_output=True, text=True, timeout=60)
    assert len(shown.stdout.splitlines()) == 2 and shown.stderr == ""
