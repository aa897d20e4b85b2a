"""``ros2 topic list|info|echo|hz|pub``: ros2topic's arguments and output, on rclpy.

Differences from ros2cli, all on the safe side: discovery waits until the graph is quiet (no
daemon, see :mod:`ros2_lite.graph`); ``echo`` and ``hz`` wait up to ``--spin-time``-and-quiet for
an unknown topic to appear before giving up (ros2cli's ``hz`` waits for ever, as ours does).
"""
from __future__ import annotations

import argparse
import math
import threading
import time

from ros2_lite.graph import ProbeNode, add_qos_arguments, add_spin_time, is_hidden_name, qos_from_args, qos_overridden
from ros2_lite.msg_yaml import (
    InterfaceError,
    interface_class,
    is_message,
    message_to_yaml,
    parse_values,
    set_message_fields,
)

DEFAULT_TRUNCATE_LENGTH = 128
HZ_WINDOW = 10000


class TopicError(Exception):
    """One line on stderr, exit code 1 (ros2cli's string return of a verb)."""


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError("Expects a floating point number") from None
    if value <= 0.0:
        raise argparse.ArgumentTypeError("Value must be positive")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value <= 0:
        raise argparse.ArgumentTypeError("value must be a positive integer")
    return value


def _nonnegative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError("Value must be positive or zero")
    return value


def topic_names_and_types(node, include_hidden: bool = False) -> list[tuple[str, list[str]]]:
    return sorted((n, t) for n, t in node.get_topic_names_and_types() if include_hidden or not is_hidden_name(n))


def _types_of(probe: ProbeNode, topic: str) -> list[str] | None:
    for name, types in probe.node.get_topic_names_and_types():
        if name == topic:
            return types
    return None


def _message_class_of(probe: ProbeNode, topic: str, type_name: str | None, wait_s: float):
    if type_name:
        try:
            return interface_class(type_name, "msg")
        except InterfaceError:
            raise TopicError("The passed message type is invalid") from None
    if not probe.wait_until(lambda: _types_of(probe, topic) is not None, wait_s):
        print(f"WARNING: topic [{topic}] does not appear to be published yet")
        return None
    types = _types_of(probe, topic) or []
    if len(types) > 1:
        raise TopicError(f"Cannot echo topic '{topic}', as it contains more than one type: [{', '.join(types)}]")
    try:
        return interface_class(types[0], "msg")
    except InterfaceError:
        raise TopicError(f"The message type '{types[0]}' is invalid") from None


def _full_topic(name: str) -> str:
    return name if name.startswith("/") else "/" + name


# -- list / info ---------------------------------------------------------------------------------------
def cmd_list(args: argparse.Namespace) -> int:
    with ProbeNode(args, "topic_list") as probe:
        probe.settle()
        topics = topic_names_and_types(probe.node, args.include_hidden_topics)
        counts = {n: (probe.node.count_publishers(n), probe.node.count_subscribers(n)) for n, _ in topics} \
            if args.verbose else {}
    if args.count_topics:
        print(len(topics))
        return 0
    if args.verbose:
        for index, word in ((0, "publisher"), (1, "subscriber")):
            lines = [("Published" if index == 0 else "Subscribed") + " topics:"]
            for name, types in topics:
                count = counts[name][index]
                if count:
                    lines.append(f" * {name} [{', '.join(types)}] {count} {word}{'s' if count > 1 else ''}")
            print("\n".join(lines) + "\n")
        return 0
    for name, types in topics:
        print(f"{name} [{', '.join(types)}]" if args.show_types else name)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    topic = _full_topic(args.topic_name)
    with ProbeNode(args, "topic_info") as probe:
        probe.settle()
        probe.wait_until(lambda: _types_of(probe, topic) is not None, 2.0)
        types = _types_of(probe, topic)
        if types is None:
            raise TopicError(f"Unknown topic '{args.topic_name}'")
        end = "\n\n" if args.verbose else "\n"
        print(f"Type: {types[0] if len(types) == 1 else types}", end=end)
        print(f"Publisher count: {probe.node.count_publishers(topic)}", end=end)
        if args.verbose:
            for info in probe.node.get_publishers_info_by_topic(topic):
                print(info, end=end)
        print(f"Subscription count: {probe.node.count_subscribers(topic)}", end=end)
        if args.verbose:
            for info in probe.node.get_subscriptions_info_by_topic(topic):
                print(info, end=end)
    return 0


# -- echo ------------------------------------------------------------------------------------------------
def choose_qos(probe: ProbeNode, args: argparse.Namespace, topic: str):
    """The subscription QoS: the flags if given; otherwise the preset made compatible with every
    publisher (reliable / transient local only when all of them offer it), as ros2cli."""
    from rclpy.qos import QoSDurabilityPolicy, QoSPresetProfiles, QoSReliabilityPolicy

    if qos_overridden(args):
        return qos_from_args(args)
    profile = QoSPresetProfiles.get_from_short_key(args.qos_profile)
    infos = probe.node.get_publishers_info_by_topic(topic)
    if not infos:
        return profile
    reliable = sum(i.qos_profile.reliability == QoSReliabilityPolicy.RELIABLE for i in infos)
    latched = sum(i.qos_profile.durability == QoSDurabilityPolicy.TRANSIENT_LOCAL for i in infos)
    if reliable == len(infos):
        profile.reliability = QoSReliabilityPolicy.RELIABLE
    else:
        if reliable:
            print("Some, but not all, publishers are offering QoSReliabilityPolicy.RELIABLE. Falling back to "
                  "QoSReliabilityPolicy.BEST_EFFORT as it will connect to all publishers")
        profile.reliability = QoSReliabilityPolicy.BEST_EFFORT
    if latched == len(infos):
        profile.durability = QoSDurabilityPolicy.TRANSIENT_LOCAL
    else:
        if latched:
            print("Some, but not all, publishers are offering QoSDurabilityPolicy.TRANSIENT_LOCAL. Falling back "
                  "to QoSDurabilityPolicy.VOLATILE as it will connect to all publishers")
        profile.durability = QoSDurabilityPolicy.VOLATILE
    return profile


def _field_path(text: str | None) -> list[str] | None:
    if text is None:
        return None
    parts = [p for p in text.split(".") if p]
    if not parts:
        raise TopicError(f"Invalid field value '{text}'")
    return parts


def cmd_echo(args: argparse.Namespace) -> int:
    topic = _full_topic(args.topic_name)
    field = _field_path(args.field)
    truncate = None if args.full_length else args.truncate_length
    with ProbeNode(args, "echo") as probe:
        probe.settle()
        msg_class = _message_class_of(probe, topic, args.message_type, wait_s=2.0)
        if msg_class is None:
            raise TopicError("Could not determine the type for the passed topic")
        qos = choose_qos(probe, args, topic)
        done = threading.Event()
        deadline = time.monotonic() + args.timeout if args.timeout else None

        def on_message(msg) -> None:
            if done.is_set():
                return
            value = msg
            for name in field or []:
                try:
                    value = getattr(value, name)
                except AttributeError as exc:
                    raise TopicError(f"Invalid field '{'.'.join(field)}': {exc}") from None
            if args.once:
                done.set()
            if not is_message(value):
                print(value, end="\n---\n", flush=True)
                return
            print(message_to_yaml(value, truncate_length=truncate, no_arr=args.no_arr, no_str=args.no_str,
                                  flow_style=args.flow_style), end="---\n", flush=True)

        probe.node.create_subscription(msg_class, topic, on_message, qos)
        probe.wait_until(lambda: done.is_set() or (deadline is not None and time.monotonic() > deadline), -1)
    return 0


# -- hz ----------------------------------------------------------------------------------------------------
class RateWindow:
    """Arrival intervals of the last ``window`` messages and the statistics ``ros2 topic hz`` prints."""

    def __init__(self, window: int = HZ_WINDOW):
        self.window = window
        self.intervals_ns: list[int] = []
        self.last_ns: int | None = None
        self.last_printed_ns = 0

    def add(self, now_ns: int) -> None:
        if self.last_ns is not None and now_ns >= self.last_ns:
            self.intervals_ns.append(now_ns - self.last_ns)
            if len(self.intervals_ns) > self.window:
                self.intervals_ns.pop(0)
        self.last_ns = now_ns

    def report(self) -> str | None:
        """The lines to print, once a second of message time has passed since the last report."""
        if not self.intervals_ns or self.last_ns is None:
            return None
        if self.last_printed_ns == 0:
            self.last_printed_ns = self.last_ns
            return None
        if self.last_ns < self.last_printed_ns + 1_000_000_000:
            return None
        times = self.intervals_ns
        n = len(times)
        mean = sum(times) / n
        rate = 1e9 / mean if mean > 0 else 0.0
        std = math.sqrt(sum((t - mean) ** 2 for t in times) / n)
        self.last_printed_ns = self.last_ns
        return (f"average rate: {rate:.3f}\n\tmin: {min(times) * 1e-9:.3f}s max: {max(times) * 1e-9:.3f}s "
                f"std dev: {std * 1e-9:.5f}s window: {n}")


def cmd_hz(args: argparse.Namespace) -> int:
    from rclpy.clock import Clock, ClockType
    from rclpy.qos import qos_profile_sensor_data

    topic = _full_topic(args.topic_name)
    with ProbeNode(args, "hz") as probe:
        probe.settle()
        msg_class = _message_class_of(probe, topic, None, wait_s=0.0)
        if msg_class is None:  # ros2cli waits for the topic to be published
            probe.wait_until(lambda: _types_of(probe, topic) is not None, -1)
            msg_class = _message_class_of(probe, topic, None, wait_s=0.0)
        clock = Clock(clock_type=ClockType.SYSTEM_TIME) if args.use_wtime else probe.node.get_clock()
        window = RateWindow(args.window_size)
        filter_fn = (lambda m: eval(args.filter_expr)) if args.filter_expr else None  # noqa: S307 (ros2cli's --filter)

        def on_message(msg) -> None:
            if filter_fn is None or filter_fn(msg):
                window.add(clock.now().nanoseconds)

        probe.node.create_subscription(msg_class, topic, on_message, qos_profile_sensor_data)

        def tick() -> bool:
            text = window.report()
            if text:
                print(text, flush=True)
            return False

        probe.wait_until(tick, -1)
    return 0


# -- pub -----------------------------------------------------------------------------------------------------
def cmd_pub(args: argparse.Namespace) -> int:
    import rclpy

    try:
        msg_class = interface_class(args.message_type, "msg")
    except InterfaceError:
        raise TopicError("The passed message type is invalid") from None
    values = parse_values(args.values)
    times = 1 if args.once else args.times
    wait_subs = args.wait_matching_subscriptions if args.wait_matching_subscriptions is not None else int(times != 0)
    if wait_subs == 0 and args.max_wait_time_secs is not None:
        raise TopicError("--max-wait-time-secs option is only effective with --wait-matching-subscriptions, "
                         "--once or --times")
    topic = _full_topic(args.topic_name)
    with ProbeNode(args, "pub") as probe:
        node = probe.node
        pub = node.create_publisher(msg_class, topic, qos_from_args(args))
        waited, logged = 0.0, 0
        while pub.get_subscription_count() < wait_subs:
            if logged == 0:
                print(f"Waiting for at least {wait_subs} matching subscription(s)...", flush=True)
            if args.max_wait_time_secs is not None and waited >= args.max_wait_time_secs:
                raise TopicError(f"Timed out waiting for subscribers: Expected {wait_subs} subcribers but only "
                                 f"got {pub.get_subscription_count()} subscribers")
            logged = (logged + 1) % 10
            probe.spin_for(0.1)
            waited += 0.1
        msg = msg_class()
        try:
            set_message_fields(msg, values, now=lambda: node.get_clock().now().to_msg())
        except InterfaceError as exc:
            raise TopicError(f"Failed to populate field: {exc}") from None
        stamped = _now_fields(values)
        print("publisher: beginning loop", flush=True)
        count = 0
        period = 1.0 / args.rate
        next_t = time.monotonic()
        while rclpy.ok() and (times == 0 or count < times):
            if stamped:
                set_message_fields(msg, stamped, now=lambda: node.get_clock().now().to_msg())
            count += 1
            if args.print and count % args.print == 0:
                print(f"publishing #{count}: {msg!r}\n", flush=True)
            pub.publish(msg)
            if times and count >= times:
                break
            next_t += period
            probe.spin_for(max(0.0, next_t - time.monotonic()))
        probe.spin_for(args.keep_alive)  # let the last message reach the wire
    return 0


def _now_fields(values: dict) -> dict:
    """The part of ``values`` that says ``now``/``auto`` (re-stamped for every message)."""
    out = {}
    for key, value in values.items():
        if value in ("now", "auto"):
            out[key] = value
        elif isinstance(value, dict):
            sub = _now_fields(value)
            if sub:
                out[key] = sub
    return out


# -- parser ----------------------------------------------------------------------------------------------------
def register(sub, parser_class) -> None:
    topic = sub.add_parser("topic", help="topics: list, info, echo, hz, pub")
    verbs = topic.add_subparsers(dest="topic_command", metavar="VERB", parser_class=parser_class)

    lst = verbs.add_parser("list", help="Output a list of available topics")
    add_spin_time(lst)
    lst.add_argument("-t", "--show-types", action="store_true", help="Additionally show the topic type")
    lst.add_argument("-c", "--count-topics", action="store_true", help="Only display the number of topics discovered")
    lst.add_argument("--include-hidden-topics", action="store_true", help="Consider hidden topics as well")
    lst.add_argument("-v", "--verbose", action="store_true", help="List full details about each topic")
    lst.set_defaults(func=cmd_list)

    info = verbs.add_parser("info", help="Print information about a topic")
    add_spin_time(info)
    info.add_argument("topic_name", help="Name of the ROS topic to get info (e.g. '/chatter')")
    info.add_argument("-v", "--verbose", action="store_true",
                      help="Node name, namespace, type, type hash, GID and QoS of each publisher and subscription")
    info.set_defaults(func=cmd_info)

    echo = verbs.add_parser("echo", help="Output messages from a topic")
    add_spin_time(echo)
    echo.add_argument("topic_name", help="Name of the ROS topic to listen to (e.g. '/chatter')")
    echo.add_argument("message_type", nargs="?", help="Type of the ROS message (e.g. 'std_msgs/msg/String')")
    add_qos_arguments(echo, "subscribe", "sensor_data")
    echo.add_argument("--field", help="Echo a selected field of a message; '.' selects sub-fields")
    echo.add_argument("-f", "--full-length", action="store_true", help="Do not truncate arrays and strings")
    echo.add_argument("-l", "--truncate-length", type=_nonnegative_int, default=DEFAULT_TRUNCATE_LENGTH,
                      help=f"The length to truncate arrays, bytes and strings to (default: {DEFAULT_TRUNCATE_LENGTH})")
    echo.add_argument("--no-arr", action="store_true", help="Don't print array fields of messages")
    echo.add_argument("--no-str", action="store_true", help="Don't print string fields of messages")
    echo.add_argument("--flow-style", action="store_true", help="Print collections in the flow style")
    echo.add_argument("--once", action="store_true", help="Print the first message received and then exit")
    echo.add_argument("--timeout", metavar="N", type=_positive_float, help="Set a timeout in seconds for waiting")
    echo.set_defaults(func=cmd_echo)

    hz = verbs.add_parser("hz", help="Print the average publishing rate to screen")
    add_spin_time(hz)
    hz.add_argument("topic_name", help="Name of the ROS topic to listen to (e.g. '/chatter')")
    hz.add_argument("-w", "--window", dest="window_size", type=_positive_int, default=HZ_WINDOW, metavar="WINDOW",
                    help=f"window size, in # of messages, for calculating rate (default: {HZ_WINDOW})")
    hz.add_argument("--filter", dest="filter_expr", metavar="EXPR",
                    help="only measure messages matching the specified Python expression (of m)")
    hz.add_argument("--wall-time", dest="use_wtime", action="store_true",
                    help="calculates rate using wall time (when no clock is published in simulation)")
    hz.set_defaults(func=cmd_hz)

    pub = verbs.add_parser("pub", help="Publish a message to a topic")
    pub.add_argument("topic_name", help="Name of the ROS topic to publish to (e.g. '/chatter')")
    pub.add_argument("message_type", help="Type of the ROS message (e.g. 'std_msgs/String')")
    pub.add_argument("values", nargs="?", default="{}", help="Values to fill the message with in YAML format")
    pub.add_argument("-r", "--rate", metavar="N", type=_positive_float, default=1.0,
                     help="Publishing rate in Hz (default: 1)")
    pub.add_argument("-p", "--print", metavar="N", type=int, default=1,
                     help="Only print every N-th published message (default: 1)")
    once = pub.add_mutually_exclusive_group()
    once.add_argument("-1", "--once", action="store_true", help="Publish one message and exit")
    once.add_argument("-t", "--times", type=_nonnegative_int, default=0, help="Publish this number of times and exit")
    pub.add_argument("-w", "--wait-matching-subscriptions", type=_nonnegative_int, default=None,
                     help="Wait until this many matching subscriptions (default 1 with --once/--times, else 0)")
    pub.add_argument("--max-wait-time-secs", type=_positive_float, default=None,
                     help="Longest wait for the matching subscriptions")
    pub.add_argument("--keep-alive", metavar="N", type=_positive_float, default=0.1,
                     help="Keep the publishing node alive for N seconds after the last message (default: 0.1)")
    add_qos_arguments(pub, "publish", "default")
    pub.add_argument("-s", "--use-sim-time", action="store_true", help="Enable ROS simulation time")
    pub.set_defaults(func=cmd_pub)
