"""``ros2 bag play``: publish a bag's CDR bytes with the recorded timing.

Messages go out in log-time order across all files of the bag, each when its log time (relative to
the first played message, divided by ``--rate``) has elapsed on the monotonic clock; the bytes are
published untouched (``publisher.publish(bytes)``), so header stamps are the recorded ones.

QoS: reliable, and transient local when every recorded publisher of the topic offered transient local
(as rosbag2 replays the recorded offer), so /drawing/layout and /registration/result also reach
subscribers that start while the bag plays. Depth: rosbag2's 10 for latched topics (a late subscriber
gets at most the last ten); for volatile topics up to 1000 messages, or about 256 MiB of them, so
bursts are not overwritten before they are sent. Before the first message the player waits until the
subscribers it can see are matched (``--wait-for-subscribers N`` waits for N per topic). Topics whose
Python message class is not importable here are reported once and skipped.
"""
from __future__ import annotations

import itertools
import re
import signal
import sys
import time
from dataclasses import dataclass, field

from ros2_lite.stop_flag import StopFlag
from stud_bag import BagError, BagReader, Qos, message_class

LOG_NAME = "rosbag2_player"
LATCHED_DEPTH = 10  # rosbag2: the recorded profile with default history (keep last 10)
VOLATILE_DEPTH = 1000  # most messages a publisher keeps unacknowledged: a burst of small messages fits...
QUEUE_BYTES = 256 * 1024 * 1024  # ...but big ones (2.4 MB depth images) are held to about this much memory
ACK_TIMEOUT_S = 2.0  # in total, for all publishers


def log(level: str, text: str) -> None:
    print(f"[{level}] [{LOG_NAME}]: {text}", file=sys.stderr, flush=True)


@dataclass
class PlayOptions:
    rate: float = 1.0
    loop: bool = False
    topics: list[str] = field(default_factory=list)
    exclude_topics: list[str] = field(default_factory=list)
    regex: str = ""
    exclude_regex: str = ""
    start_offset_s: float = 0.0
    delay_s: float = 0.0
    clock_hz: float = 0.0  # 0: no /clock
    wait_for_subscribers: int = 0  # our addition: wait until each topic has this many matched subscribers
    wait_for_topic: dict[str, int] = field(default_factory=dict)  # ... or its own count (recorded or played name)
    wait_timeout_s: float = 10.0
    remap: dict[str, str] = field(default_factory=dict)  # recorded topic -> the name it is published under


def replay_qos(offered: list[Qos], message_size: int = 0):
    """Reliable; transient local if every recorded publisher offered it. ``message_size`` (bytes, the
    largest seen) bounds the depth of volatile topics so a slow subscriber cannot pile up gigabytes."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    latched = bool(offered) and all(q.durability == "transient_local" for q in offered)
    depth = LATCHED_DEPTH if latched else max(LATCHED_DEPTH, min(VOLATILE_DEPTH, QUEUE_BYTES // max(message_size, 1)))
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=depth,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class Player:
    def __init__(self, reader: BagReader, options: PlayOptions):
        self.reader = reader
        self.options = options
        self._stop = StopFlag()  # set by the SIGINT/SIGTERM handler: no lock
        self.published = 0
        self.playable = self._select_topics()

    def _select_topics(self) -> dict[str, str]:
        """topic -> type of the topics to play (importable types only)."""
        opts = self.options
        wanted = {t.lstrip("/") for t in opts.topics}  # 'AAA' and '/AAA' name the same topic
        regex = re.compile(opts.regex) if opts.regex else None
        exclude_regex = re.compile(opts.exclude_regex) if opts.exclude_regex else None
        chosen: dict[str, str] = {}
        for name, topic in self.reader.topics.items():
            if opts.topics and name.lstrip("/") not in wanted:
                continue
            if regex and not regex.search(name):
                continue
            if name.lstrip("/") in {t.lstrip("/") for t in opts.exclude_topics} or (
                    exclude_regex and exclude_regex.search(name)):
                continue
            if opts.clock_hz and name == "/clock":
                continue  # rosbag2: --clock replaces a recorded /clock
            if topic.message_count == 0:
                continue
            try:
                message_class(topic.type)
            except LookupError as exc:
                log("WARN", f"Skipping topic '{name}' ({topic.message_count} messages): {exc}")
                continue
            chosen[name] = topic.type
        in_bag = {name.lstrip("/") for name in self.reader.topics}
        missing = [t for t in opts.topics if t.lstrip("/") not in in_bag]
        for t in missing:
            log("WARN", f"Topic '{t}' is not in the bag")
        if not chosen:
            raise BagError(f"'{self.reader.path}': nothing to play (no selected topic with messages of an "
                           "importable type)")
        return chosen

    def stop(self) -> None:
        self._stop.set()

    def run(self) -> int:
        import rclpy
        from rclpy.signals import SignalHandlerOptions

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        previous = {s: signal.signal(s, lambda *_: self._stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
        node = None
        try:
            node = rclpy.create_node(LOG_NAME)
            publishers = {
                name: node.create_publisher(message_class(type_name),
                                            self.options.remap.get("/" + name.lstrip("/"), name),
                                            replay_qos(self.reader.topics[name].offered_qos_profiles,
                                                       self._message_size(name)))
                for name, type_name in self.playable.items()
            }
            clock_pub = None
            if self.options.clock_hz:
                from rclpy.qos import QoSProfile
                from rosgraph_msgs.msg import Clock

                clock_pub = node.create_publisher(Clock, "/clock", QoSProfile(depth=1))
            self._wait_for_subscribers(node, publishers)
            while not self._stop.is_set():
                if self.options.delay_s and self._stop.wait(self.options.delay_s):
                    break
                self._play_once(publishers, clock_pub)
                if not self.options.loop:
                    break
            # reliable delivery of the tail before we go away (bounded: a subscriber that vanished
            # mid-play never acknowledges)
            ack_deadline = time.monotonic() + ACK_TIMEOUT_S
            for pub in publishers.values():
                left = ack_deadline - time.monotonic()
                if self._stop.is_set() or left <= 0:
                    break
                pub.wait_for_all_acked(rclpy.duration.Duration(nanoseconds=int(left * 1e9)))
        finally:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
            for s, handler in previous.items():
                signal.signal(s, handler)
        log("INFO", f"Played {self.published} messages on {len(self.playable)} topics")
        return 0

    def _message_size(self, topic: str, sample: int = 20) -> int:
        """Largest of the topic's first ``sample`` messages, bytes."""
        return max((len(m.data) for m in itertools.islice(self.reader.messages([topic]), sample)), default=0)

    def _wait_for_subscribers(self, node, publishers) -> None:
        """Give discovery a moment so the first messages are not sent before subscribers are matched:
        until every subscriber the graph shows is matched (at least 0.3 s, at most 2 s), or, with
        ``--wait-for-subscribers N``, until each topic has N matched subscribers -- a ``--remap``ped
        topic one: it is remapped to feed an adapter (the cell's pose_rebase) -- and a topic given
        as ``TOPIC=N`` its own N."""
        start = time.monotonic()
        per_topic = self.options.wait_for_topic
        need = self.options.wait_for_subscribers
        remap = self.options.remap

        def needed(topic: str) -> int:
            recorded = "/" + topic.lstrip("/")
            for name in (recorded, remap.get(recorded)):
                if name in per_topic:
                    return per_topic[name]
            return min(need, 1) if recorded in remap else need

        counted = {t: needed(t) for t in publishers}
        need = max(counted.values(), default=0)
        timeout = self.options.wait_timeout_s if need else 2.0

        while not self._stop.is_set():
            elapsed = time.monotonic() - start
            if need:
                if all(p.get_subscription_count() >= counted[t] for t, p in publishers.items()):
                    return
            elif elapsed >= 0.3 and all(p.get_subscription_count() >= node.count_subscribers(t)
                                        for t, p in publishers.items()):
                return
            if elapsed >= timeout:
                if need:
                    short = [f"{t} ({p.get_subscription_count()} of {counted[t]})" for t, p in publishers.items()
                             if p.get_subscription_count() < counted[t]]
                    log("WARN", f"Playing although not every topic got its matched subscribers in {timeout:g} s: "
                                f"{', '.join(short)}")
                return
            time.sleep(0.02)

    def _play_once(self, publishers, clock_pub) -> None:
        rate = self.options.rate
        bag_start = self.reader.start_time_ns + int(self.options.start_offset_s * 1e9)
        messages = self.reader.messages(list(publishers), start_time_ns=bag_start)
        # The clock starts once the first message is read: opening the first chunk (decompression)
        # must not make the opening messages late and then go out in a burst.
        first = next(messages, None)
        if first is None:
            return
        wall_start = time.monotonic()
        next_clock = wall_start
        clock_period = 1.0 / self.options.clock_hz if self.options.clock_hz else 0.0
        for msg in itertools.chain([first], messages):
            due = wall_start + (msg.log_time_ns - bag_start) / 1e9 / rate
            while True:
                now = time.monotonic()
                if clock_pub is not None and now >= next_clock:
                    self._publish_clock(clock_pub, bag_start + int((now - wall_start) * rate * 1e9))
                    next_clock += clock_period
                if now >= due or self._stop.is_set():
                    break
                wake = min(due, next_clock) if clock_pub is not None else due
                self._stop.wait(min(max(wake - now, 0.0), 0.05))
            if self._stop.is_set():
                return
            publishers[msg.topic].publish(msg.data)
            self.published += 1

    @staticmethod
    def _publish_clock(pub, t_ns: int) -> None:
        from rosgraph_msgs.msg import Clock

        clock = Clock()
        clock.clock.sec, clock.clock.nanosec = divmod(t_ns, 1_000_000_000)
        pub.publish(clock)
