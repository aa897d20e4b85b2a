"""The probe node every introspection verb runs on, and the QoS options ros2cli's verbs share.

ros2cli asks its daemon (which has watched the graph for a while) or spins a fresh node for
``--spin-time`` (0.5 s). We have no daemon, and a fresh participant here sees the others after
0.1-2.9 s each, one by one (measured on the project's 2-core machine with our Fast DDS profile), so
:meth:`ProbeNode.settle` spins at least ``--spin-time``, then until some other node is known (at
most ``FIRST_NODE_S``), then until the graph has not changed for ``QUIET_S``. Verbs aimed at one
thing (a topic, a node, a service) also wait for that thing, up to their timeout.

The node is hidden (its name starts with ``_``), so it never shows in ``ros2 node list``.
"""
from __future__ import annotations

import argparse
import os
import time
from typing import Callable

DEFAULT_SPIN_TIME_S = 0.5
FIRST_NODE_S = 4.0
QUIET_S = 1.0
MAX_SETTLE_S = 8.0


def add_spin_time(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--spin-time", type=float, default=DEFAULT_SPIN_TIME_S,
                        help="Spin time in seconds to wait for discovery (at least; we wait until the "
                             "graph is quiet, there is no daemon)")
    parser.add_argument("-s", "--use-sim-time", action="store_true", help="Enable ROS simulation time")
    parser.add_argument("--no-daemon", action="store_true", help="accepted for compatibility (there is no daemon)")


def add_qos_arguments(parser: argparse.ArgumentParser, verb: str, default_profile: str) -> None:
    from rclpy.qos import (
        QoSDurabilityPolicy,
        QoSHistoryPolicy,
        QoSLivelinessPolicy,
        QoSPresetProfiles,
        QoSReliabilityPolicy,
    )

    parser.add_argument("--qos-profile", choices=QoSPresetProfiles.short_keys(), default=default_profile,
                        help=f"Quality of service preset profile to {verb} with (default: {default_profile})")
    parser.add_argument("--qos-depth", metavar="N", type=int, help=f"Queue size setting to {verb} with")
    parser.add_argument("--qos-history", choices=QoSHistoryPolicy.short_keys())
    parser.add_argument("--qos-reliability", choices=QoSReliabilityPolicy.short_keys())
    parser.add_argument("--qos-durability", choices=QoSDurabilityPolicy.short_keys())
    parser.add_argument("--qos-liveliness", choices=QoSLivelinessPolicy.short_keys())
    parser.add_argument("--qos-liveliness-lease-duration-seconds", type=float)


def qos_overridden(args: argparse.Namespace) -> bool:
    return any(getattr(args, k) is not None for k in (
        "qos_depth", "qos_history", "qos_reliability", "qos_durability", "qos_liveliness",
        "qos_liveliness_lease_duration_seconds"))


def qos_from_args(args: argparse.Namespace):
    """The preset ``--qos-profile`` with the ``--qos-*`` overrides applied (as ros2cli)."""
    from rclpy.duration import Duration
    from rclpy.qos import (
        QoSDurabilityPolicy,
        QoSHistoryPolicy,
        QoSLivelinessPolicy,
        QoSPresetProfiles,
        QoSReliabilityPolicy,
    )

    profile = QoSPresetProfiles.get_from_short_key(args.qos_profile)
    if args.qos_history:
        profile.history = QoSHistoryPolicy.get_from_short_key(args.qos_history)
    if args.qos_durability:
        profile.durability = QoSDurabilityPolicy.get_from_short_key(args.qos_durability)
    if args.qos_reliability:
        profile.reliability = QoSReliabilityPolicy.get_from_short_key(args.qos_reliability)
    if args.qos_liveliness:
        profile.liveliness = QoSLivelinessPolicy.get_from_short_key(args.qos_liveliness)
    if args.qos_liveliness_lease_duration_seconds and args.qos_liveliness_lease_duration_seconds >= 0:
        profile.liveliness_lease_duration = Duration(seconds=args.qos_liveliness_lease_duration_seconds)
    if args.qos_depth is not None and args.qos_depth >= 0:
        profile.depth = args.qos_depth
    elif profile.durability == QoSDurabilityPolicy.TRANSIENT_LOCAL and profile.depth == 0:
        profile.depth = 1
    return profile


class ProbeNode:
    """``with ProbeNode(args, "echo") as probe:`` -- rclpy initialised, a hidden node ``probe.node``."""

    def __init__(self, args: argparse.Namespace | None, purpose: str):
        self._args = args
        self._purpose = purpose
        self.node = None

    def __enter__(self) -> "ProbeNode":
        import rclpy
        from rclpy.parameter import Parameter

        rclpy.init(args=[])
        sim = bool(getattr(self._args, "use_sim_time", False))
        self.node = rclpy.create_node(
            f"_ros2cli_{self._purpose}_{os.getpid()}", start_parameter_services=False,
            parameter_overrides=[Parameter("use_sim_time", value=sim)],
            automatically_declare_parameters_from_overrides=True)
        return self

    def __exit__(self, *exc) -> None:
        import rclpy

        if self.node is not None:
            self.node.destroy_node()
        rclpy.try_shutdown()

    # -- waiting ---------------------------------------------------------------------------------
    def spin_for(self, seconds: float) -> None:
        import rclpy

        deadline = time.monotonic() + seconds
        while rclpy.ok() and time.monotonic() < deadline:
            rclpy.spin_once(self.node, timeout_sec=min(0.05, max(0.0, deadline - time.monotonic())))

    def _signature(self) -> tuple:
        n = self.node
        return (tuple(sorted(n.get_node_names_and_namespaces())), tuple(n.get_topic_names_and_types()),
                tuple(n.get_service_names_and_types()))

    def settle(self) -> None:
        """Spin until discovery is done: ``--spin-time`` at least, then until the graph is quiet."""
        start = time.monotonic()
        self.spin_for(getattr(self._args, "spin_time", DEFAULT_SPIN_TIME_S) or 0.0)
        own = self.node.get_name()
        self.wait_until(lambda: any(name != own for name, _ in self.node.get_node_names_and_namespaces()),
                        max(0.0, FIRST_NODE_S - (time.monotonic() - start)))
        last, changed = self._signature(), time.monotonic()
        while time.monotonic() - changed < QUIET_S and time.monotonic() - start < MAX_SETTLE_S:
            self.spin_for(0.1)
            sig = self._signature()
            if sig != last:
                last, changed = sig, time.monotonic()

    def wait_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until ``condition()``; False after ``timeout_s`` (a negative timeout waits for ever)."""
        import rclpy

        deadline = None if timeout_s < 0 else time.monotonic() + timeout_s
        while rclpy.ok():
            if condition():
                return True
            if deadline is not None and time.monotonic() > deadline:
                return False
            rclpy.spin_once(self.node, timeout_sec=0.05)
        return False

    def spin_until_done(self, future, timeout_s: float | None = None) -> bool:
        import rclpy

        rclpy.spin_until_future_complete(self.node, future, timeout_sec=timeout_s)
        return future.done()

    # -- graph -----------------------------------------------------------------------------------
    def node_names(self, include_hidden: bool = False) -> list[str]:
        names = []
        for name, ns in self.node.get_node_names_and_namespaces():
            if include_hidden or (name and not name.startswith("_")):
                names.append(ns + ("" if ns.endswith("/") else "/") + name)
        return names

    def wait_for_node(self, full_name: str, timeout_s: float, include_hidden: bool = False) -> bool:
        return self.wait_until(lambda: full_name in self.node_names(include_hidden), timeout_s)


def absolute_name(name: str) -> str:
    return name if name.startswith("/") else "/" + name


def split_node_name(full_name: str) -> tuple[str, str]:
    """``/ns/name`` -> (name, namespace)."""
    namespace, _, name = absolute_name(full_name).rpartition("/")
    return name, namespace or "/"


def is_hidden_name(name: str) -> bool:
    return any(part.startswith("_") for part in name.split("/"))
