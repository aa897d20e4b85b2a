"""``ros2 bag record``: subscribe to topics with rclpy and write serialized messages to a BagWriter.

As rosbag2's recorder: topics are discovered by polling the graph (``-p`` ms), each subscription asks
for QoS every current publisher can serve (reliable only if all publishers are reliable, transient
local only if all are, so latched topics such as /drawing/layout arrive on subscription), the
publishers' offered QoS profiles are stored with the topic, messages are taken as CDR bytes
(``raw=True``) and stamped with their receive time. The callbacks only queue the bytes; a writer
thread compresses and writes them, so a 2.4 MB image does not hold up the executor. The queue is
bounded (``--max-cache-size``); what does not fit is dropped and counted, as rosbag2 does.
"""
from __future__ import annotations

import queue
import re
import signal
import sys
import threading
import time
from dataclasses import dataclass, field

from ros2_lite.stop_flag import StopFlag
from stud_bag import BagError, BagWriter, Qos, message_class
from stud_bag.metadata import INFINITE_NS

SUBSCRIPTION_DEPTH = 100  # reader history: absorbs a burst while the writer thread is busy
LOG_NAME = "rosbag2_recorder"


def log(level: str, text: str) -> None:
    print(f"[{level}] [{LOG_NAME}]: {text}", file=sys.stderr, flush=True)


@dataclass
class RecordOptions:
    topics: list[str] = field(default_factory=list)
    all_topics: bool = False
    regex: str = ""
    exclude_regex: str = ""
    exclude_topics: list[str] = field(default_factory=list)
    include_hidden_topics: bool = False
    include_unpublished_topics: bool = False
    polling_interval_ms: int = 100
    no_discovery: bool = False
    max_duration_s: float = 0.0  # 0: until SIGINT/SIGTERM
    max_cache_size: int = 100 * 1024 * 1024
    node_name: str = LOG_NAME


def fully_qualified(topic: str) -> str:
    return topic if topic.startswith("/") else "/" + topic


def is_hidden(topic: str) -> bool:
    return any(part.startswith("_") for part in topic.split("/") if part)


def offered_qos(profile) -> Qos:
    """rclpy QoSProfile of a discovered publisher -> the profile rosbag2 stores."""
    def ns(duration) -> int:
        value = int(duration.nanoseconds)
        return INFINITE_NS if value < 0 or value >= INFINITE_NS else value

    return Qos(
        history=profile.history.name.lower(),
        depth=int(profile.depth),
        reliability=profile.reliability.name.lower(),
        durability=profile.durability.name.lower(),
        deadline_ns=ns(profile.deadline),
        lifespan_ns=ns(profile.lifespan),
        liveliness=profile.liveliness.name.lower(),
        liveliness_lease_duration_ns=ns(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


def subscription_qos(topic: str, offered: list[Qos]):
    """rosbag2's ``adapt_request_to_offers``: a request every publisher on the topic is compatible with."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    reliable = bool(offered) and all(q.reliability == "reliable" for q in offered)
    latched = bool(offered) and all(q.durability == "transient_local" for q in offered)
    if offered and not reliable and any(q.reliability == "reliable" for q in offered):
        log("WARN", f"Some, but not all, publishers on topic '{topic}' offer reliable: recording best effort")
    if offered and not latched and any(q.durability == "transient_local" for q in offered):
        log("WARN", f"Some, but not all, publishers on topic '{topic}' offer transient local: recording volatile "
                    "(latched messages published before the recording are not retrieved)")
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=SUBSCRIPTION_DEPTH,
        reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class Recorder:
    """Records until stopped (signal, ``--max-duration``); ``run()`` returns the exit code."""

    def __init__(self, writer: BagWriter, options: RecordOptions):
        self.writer = writer
        self.options = options
        self._queue: queue.Queue = queue.Queue()
        self._pending_bytes = 0
        self._lock = threading.Lock()
        self._stop = StopFlag()  # set by the SIGINT/SIGTERM handler: no lock
        self._received = 0
        self.dropped = 0
        self.written = 0
        self._writer_error: BaseException | None = None
        self._subscriptions: dict[str, object] = {}
        self._ignored: set[str] = set()
        self._wanted = {fully_qualified(t) for t in options.topics}
        self._regex = re.compile(options.regex) if options.regex else None
        self._exclude_regex = re.compile(options.exclude_regex) if options.exclude_regex else None
        self._exclude = {fully_qualified(t) for t in options.exclude_topics}

    # -- selection -----------------------------------------------------------------------------
    def _selected(self, topic: str) -> bool:
        if topic in self._exclude or (self._exclude_regex and self._exclude_regex.search(topic)):
            return False
        if self.options.all_topics:
            return self.options.include_hidden_topics or not is_hidden(topic)
        if topic in self._wanted:
            return True
        return bool(self._regex and self._regex.search(topic)) and (
            self.options.include_hidden_topics or not is_hidden(topic))

    def _discover(self, node) -> None:
        for topic, types in node.get_topic_names_and_types():
            if topic in self._subscriptions or topic in self._ignored or not self._selected(topic):
                continue
            infos = node.get_publishers_info_by_topic(topic)
            if not infos and not self.options.include_unpublished_topics:
                continue
            type_name = types[0]
            if len(types) > 1:
                log("WARN", f"Topic '{topic}' has several types {types}: recording '{type_name}'")
            try:
                cls = message_class(type_name)
            except LookupError as exc:
                log("WARN", f"Not recording topic '{topic}': {exc}")
                self._ignored.add(topic)
                continue
            offered = [offered_qos(i.qos_profile) for i in infos]
            type_hash = next((str(i.topic_type_hash) for i in infos
                              if str(i.topic_type_hash).startswith("RIHS")), "")
            # the topic reaches the writer thread through the queue, ahead of its first message
            self._queue.put(("topic", topic, type_name, offered, type_hash))
            self._subscriptions[topic] = node.create_subscription(
                cls, topic, lambda data, t=topic: self._on_message(t, data), subscription_qos(topic, offered),
                raw=True)
            log("INFO", f"Subscribed to topic '{topic}'")

    # -- data path -----------------------------------------------------------------------------
    def _on_message(self, topic: str, data: bytes) -> None:
        stamp = time.time_ns()
        self._received += 1
        size = len(data)
        with self._lock:
            if self._pending_bytes + size > 2 * self.options.max_cache_size:  # rosbag2's double buffer
                self.dropped += 1
                return
            self._pending_bytes += size
        self._queue.put(("msg", topic, data, stamp))

    def _write_loop(self) -> None:
        while True:
            item = self._queue.get()
            if item is None:
                return
            try:
                if item[0] == "topic":
                    _, topic, type_name, offered, type_hash = item
                    self.writer.add_topic(topic, type_name, offered_qos_profiles=offered,
                                          type_description_hash=type_hash)
                else:
                    _, topic, data, stamp = item
                    self.writer.write(topic, data, stamp, stamp)
                    self.written += 1
                    with self._lock:
                        self._pending_bytes -= len(data)
            except BaseException as exc:  # disk full, ...: stop recording, report once
                self._writer_error = exc
                self._stop.set()
                return

    # -- main loop -----------------------------------------------------------------------------
    def run(self) -> int:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.signals import SignalHandlerOptions

        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        previous = {s: signal.signal(s, lambda *_: self._stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
        writer_thread = threading.Thread(target=self._write_loop, name="bag_writer", daemon=True)
        writer_thread.start()
        node = None
        try:
            node = rclpy.create_node(self.options.node_name)
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            started = time.monotonic()
            self._discover(node)
            next_poll = started + self.options.polling_interval_ms / 1000.0
            log("INFO", "Recording...")
            while not self._stop.is_set():
                executor.spin_once(timeout_sec=0.05)
                now = time.monotonic()
                if self.options.max_duration_s and now - started >= self.options.max_duration_s:
                    break
                if not self.options.no_discovery and now >= next_poll:
                    self._discover(node)
                    next_poll = now + self.options.polling_interval_ms / 1000.0
            # take what DDS already delivered before unsubscribing
            deadline = time.monotonic() + 1.0
            while time.monotonic() < deadline:
                before = self._received
                executor.spin_once(timeout_sec=0.05)
                if self._received == before:
                    break
            for sub in self._subscriptions.values():
                node.destroy_subscription(sub)
        finally:
            self._queue.put(None)
            writer_thread.join()
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
            for s, handler in previous.items():
                signal.signal(s, handler)
        try:
            path = self.writer.close()
        except OSError as exc:
            raise BagError(f"Cannot finish bag '{self.writer.path}' ({exc.strerror or exc})") from None
        if self._writer_error is not None:
            raise BagError(f"Recording to '{self.writer.path}' failed: {self._writer_error}")
        size = sum(p.stat().st_size for p in path.iterdir() if p.is_file())
        log("INFO", f"Recording stopped: {self.written} messages on {len(self._subscriptions)} topics in "
                    f"'{path}' ({size / 1048576:.1f} MiB)")
        if self.dropped:
            log("WARN", f"{self.dropped} messages dropped: the writer fell behind by more than "
                        f"{2 * self.options.max_cache_size} bytes")
        return 0
