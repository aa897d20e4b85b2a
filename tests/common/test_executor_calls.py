"""ExecutorCalls: a call made from another thread runs on the node's executor, inside the callback group
it was given, and hands back its result or its exception."""
from __future__ import annotations

import threading

import pytest
import rclpy
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.executors import MultiThreadedExecutor

from stud_common.executor_calls import ExecutorCalls


@pytest.fixture
def spinning_node():
    rclpy.init()
    node = rclpy.create_node("executor_calls_probe")
    executor = MultiThreadedExecutor(num_threads=2)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield node
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()


def _result(future, timeout_s=5.0):
    done = threading.Event()
    future.add_done_callback(lambda _f: done.set())
    assert done.wait(timeout_s), "the executor never ran the call"
    return future


def test_a_call_runs_on_an_executor_thread_inside_the_group_and_returns_its_value(spinning_node):
    group = MutuallyExclusiveCallbackGroup()
    calls = ExecutorCalls(spinning_node, group)
    caller = threading.current_thread()
    seen = {}

    def probe():
        seen["thread"] = threading.current_thread()
        # inside a mutually exclusive group: the group is held while the call runs
        seen["held"] = not group.can_execute(calls._guard)
        return 42

    assert _result(calls.call(probe)).result() == 42
    assert seen["thread"] is not caller and seen["held"]


def test_an_exception_in_the_call_reaches_the_caller(spinning_node):
    calls = ExecutorCalls(spinning_node, MutuallyExclusiveCallbackGroup())
    future = _result(calls.call(lambda: 1 / 0))
    with pytest.raises(ZeroDivisionError):
        future.result()
