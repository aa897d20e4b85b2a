"""The cell sequencer node beside a fake arm node, both spun by one multi-threaded executor in this process
(real rclpy over DDS): the fixture the sequencer's adapter tests share."""
from __future__ import annotations

import threading
from contextlib import contextmanager
from typing import Callable, Iterator

import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node

from stud_cell.sequencer_node import CellSequencer


@contextmanager
def sequencer_beside(make_arm: Callable[[], Node], threads: int = 4) -> Iterator[tuple[CellSequencer, Node]]:
    """rclpy initialised, a CellSequencer and ``make_arm()`` spinning; everything shut down on exit."""
    rclpy.init()
    sequencer, arm = CellSequencer(), make_arm()
    executor = MultiThreadedExecutor(num_threads=threads)
    executor.add_node(sequencer)
    executor.add_node(arm)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield sequencer, arm
    finally:
        executor.shutdown(timeout_sec=2.0)
        sequencer.destroy_node()
        arm.destroy_node()
        rclpy.try_shutdown()
        spinner.join(timeout=2.0)
