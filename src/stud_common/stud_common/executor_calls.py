"""Calls made on a node's executor, inside one callback group: for clients rclpy does not guard.

rclpy's ``ActionClient.send_goal_async`` (and ``get_result_async``) sends the request first and records
its sequence number after; an executor thread that takes the response in between finds no record,
logs "Ignoring unexpected goal response" and the future never completes. A node that sends goals from
a thread of its own (the cell sequencer's job) therefore sends them through :class:`ExecutorCalls`:
the call runs as a guard condition's callback in the action client's *mutually exclusive* callback
group, so the response can only be taken once the call has returned and the record is there.
"""
from __future__ import annotations

import queue
from typing import Any, Callable

from rclpy.callback_groups import CallbackGroup
from rclpy.node import Node
from rclpy.task import Future


class ExecutorCalls:
    """``call(fn)`` runs ``fn()`` on the node's executor inside ``group``; its result comes back in a Future."""

    def __init__(self, node: Node, group: CallbackGroup) -> None:
        self._pending: queue.SimpleQueue = queue.SimpleQueue()
        self._guard = node.create_guard_condition(self._run, callback_group=group)

    def call(self, fn: Callable[[], Any]) -> Future:
        """Queue ``fn`` for the executor; the Future completes with what it returned (or raised)."""
        done = Future()
        self._pending.put((fn, done))
        self._guard.trigger()
        return done

    def _run(self) -> None:
        while True:
            try:
                fn, done = self._pending.get_nowait()
            except queue.Empty:
                return
            try:
                done.set_result(fn())
            except Exception as exc:  # handed to the caller, who decides
                done.set_exception(exc)
