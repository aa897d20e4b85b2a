"""Read and write rosbag2 bags (``metadata.yaml`` + MCAP files) without a running ROS graph.

Reading: ``open_bag(path)`` takes a bag directory (split bags, file-compressed ``.mcap.zstd``,
message-compressed payloads) or a single ``.mcap`` file and yields ``BagMessage(topic, type_name,
log_time_ns, data)`` in log-time order across all files; ``BagMessage.message()`` turns the CDR bytes
into our rclpy message class. What the bag holds (topics, counts, times) is computed from the MCAP
files themselves; where ``metadata.yaml`` says otherwise ``BagReader.notes`` says so.

Writing: ``BagWriter(dir)`` writes what ``ros2 bag record`` (rosbag2 Jazzy, MCAP storage) writes:
``dir/dir_0.mcap`` (profile ``ros2``, ``ros2msg`` schemas with the full definition, ``cdr`` channels
with ``offered_qos_profiles`` and ``topic_type_hash`` metadata, zstd chunks, a ``rosbag2`` metadata
record) and ``dir/metadata.yaml`` (version 9) when closed. rclpy is imported only to serialise
message objects, so scripts can write sensor bags directly.
"""
from __future__ import annotations

import heapq
import importlib
import os
import re
import struct
import tempfile
import threading
import time
import weakref
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any, Iterable, Iterator, NamedTuple

import yaml
import zstandard
from mcap.exceptions import EndOfFile, McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from ros2_lite.bag_metadata import (
    METADATA_FILENAME,
    UNSET_TIME_NS,
    BagMetadata,
    FileInfo,
    MetadataError,
    Qos,
    TopicInfo,
    dump_qos_profiles,
    emit_yaml,
    parse_qos_profiles,
    read_metadata,
    write_metadata,
)

MCAP_MAGIC = b"\x89MCAP0\r\n"
LIBRARY = "ros2_lite bag (mcap-python)"
PRESET_PROFILES = ("none", "fastwrite", "zstd_fast", "zstd_small")
COMPRESSION_MODES = ("none", "file", "message")
ZSTD_LEVEL = 1  # rosbag2_compression_zstd's default level for file and message compression
_READ_ERRORS = (McapError, EndOfFile, struct.error, ValueError, KeyError, IndexError, OverflowError,
                zstandard.ZstdError, UnicodeDecodeError, MemoryError)


class BagError(Exception):
    """A bag that does not exist, cannot be read or cannot be written. The message is one line that
    names the path and what was expected."""


class BagMessage(NamedTuple):
    """One recorded message: CDR bytes as they came off the wire, receive time in ns since the epoch."""

    topic: str
    type_name: str
    log_time_ns: int
    data: bytes

    def message(self) -> Any:
        """The message as an instance of its rclpy class (the type must be importable)."""
        return deserialize(self.type_name, self.data)


@dataclass
class TopicSummary:
    """A topic as the MCAP files hold it."""

    name: str
    type: str
    message_count: int = 0
    serialization_format: str = "cdr"
    offered_qos_profiles: list[Qos] = field(default_factory=list)
    type_description_hash: str = ""


# -- message classes -----------------------------------------------------------------------------
def message_class(type_name: str) -> type:
    """``pkg/msg/Name`` -> the generated Python class (``pkg.msg.Name``). Raises LookupError."""
    parts = type_name.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise LookupError(f"type name '{type_name}' is not <package>/msg/<Name>")
    package, kind, name = parts
    try:
        module = importlib.import_module(f"{package}.{kind}")
        return getattr(module, name)
    except (ImportError, AttributeError) as exc:
        raise LookupError(f"type '{type_name}' is not importable here ({exc})") from None


def type_name_of(msg: Any) -> str:
    """rclpy message instance (or class) -> ``pkg/msg/Name``."""
    cls = msg if isinstance(msg, type) else type(msg)
    parts = cls.__module__.split(".")
    if len(parts) < 2 or parts[1] not in ("msg", "srv", "action"):
        raise TypeError(f"{cls!r} is not a generated ROS 2 message class")
    return f"{parts[0]}/{parts[1]}/{cls.__name__}"


def deserialize(type_name: str, data: bytes) -> Any:
    """CDR bytes -> message object of ``type_name`` (rclpy.serialization)."""
    from rclpy.serialization import deserialize_message

    return deserialize_message(data, message_class(type_name))


def serialize(msg: Any) -> bytes:
    """Message object -> CDR bytes (rclpy.serialization), as a publisher would put them on the wire."""
    from rclpy.serialization import serialize_message

    return serialize_message(msg)


# -- reading -------------------------------------------------------------------------------------
@dataclass
class _FileScan:
    path: Path  # the MCAP file read (a temporary copy for .zstd files)
    label: str  # the name shown to the user
    schemas: dict[int, Schema] = field(default_factory=dict)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)  # channel id -> messages
    start_ns: int | None = None
    end_ns: int | None = None
    ros2_metadata: dict[str, str] = field(default_factory=dict)
    indexed: bool = True  # summary with chunk indexes: iterate through the index
    truncated: str = ""  # why the file could only be read up to some point


def _split_index(path: Path) -> tuple[int, str]:
    match = re.search(r"_(\d+)\.mcap(\.zstd)?$", path.name)
    return (int(match.group(1)) if match else 1 << 30, path.name)


#: Start of the note a reader leaves when the files hold fewer messages than metadata.yaml lists.
MESSAGES_MISSING = "metadata.yaml lists more messages than the MCAP files hold"


class BagReader:
    """A rosbag2 bag directory or a single MCAP file, opened for reading.

    Attributes computed from the MCAP files: ``topics`` (name -> TopicSummary, in metadata order
    when there is a metadata.yaml), ``message_count``, ``start_time_ns``, ``end_time_ns``,
    ``duration_ns``, ``ros_distro``. ``metadata`` is the parsed metadata.yaml or None; ``notes`` lists
    where metadata.yaml and the files disagree, and files read only partly.
    """

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.metadata: BagMetadata | None = None
        self.notes: list[str] = []
        self.default_topics: list[str] | None = None  # what iterating the reader itself yields
        self._tmpdir: tempfile.TemporaryDirectory | None = None
        self._finalizer = None
        if not self.path.exists():
            raise BagError(f"Bag path '{self.path}' does not exist (expected a rosbag2 bag directory or an .mcap file)")
        if self.path.is_dir():
            self.relative_file_paths, sources = self._files_of_directory()
        elif self.path.is_file():
            if not self.path.name.endswith((".mcap", ".mcap.zstd")):
                raise BagError(f"'{self.path}' is not a bag: expected a bag directory or an .mcap file")
            self.relative_file_paths, sources = [str(self.path)], [self.path]
        else:
            raise BagError(f"'{self.path}' is not a bag: expected a bag directory or an .mcap file")
        self.storage_identifier = self.metadata.storage_identifier if self.metadata else "mcap"
        self.compression_mode = (self.metadata.compression_mode if self.metadata else "").upper()
        self.compression_format = self.metadata.compression_format if self.metadata else ""
        if any(p.name.endswith(".zstd") for p in sources) and not self.compression_mode:
            self.compression_mode, self.compression_format = "FILE", "zstd"
        if self.compression_mode == "MESSAGE" and self.compression_format not in ("zstd", ""):
            raise BagError(f"'{self.path}': compression format '{self.compression_format}' is not supported "
                           "(expected zstd)")
        self._scans = [self._scan(self._storage_file(p), str(p)) for p in sources]
        self.bag_size = self._bag_size()
        self._summarise()

    # context manager / cleanup of decompressed copies
    def close(self) -> None:
        if self._finalizer is not None:
            self._finalizer()

    def __enter__(self) -> "BagReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _files_of_directory(self) -> tuple[list[str], list[Path]]:
        meta_path = self.path / METADATA_FILENAME
        if meta_path.exists():
            try:
                self.metadata = read_metadata(self.path)
            except (MetadataError, OSError) as exc:
                raise BagError(f"'{meta_path}': not a rosbag2 metadata file: {exc}") from None
            if self.metadata.storage_identifier != "mcap":
                raise BagError(f"'{self.path}': storage '{self.metadata.storage_identifier}' is not supported "
                               "(expected mcap)")
            names = self.metadata.relative_file_paths
            if not names:
                raise BagError(f"'{meta_path}' lists no bag files (relative_file_paths is empty)")
            sources = [self.path / PurePath(n).name for n in names]
            missing = [str(p) for p in sources if not p.is_file()]
            if missing:
                raise BagError(f"'{self.path}': file(s) listed in metadata.yaml are missing: {', '.join(missing)}")
            return list(names), sources
        sources = sorted((p for p in self.path.iterdir() if p.name.endswith((".mcap", ".mcap.zstd"))),
                         key=_split_index)
        if not sources:
            raise BagError(f"'{self.path}' is not a bag: no metadata.yaml and no .mcap files in it")
        self.notes.append("no metadata.yaml in the bag directory: read the MCAP files "
                          f"({', '.join(p.name for p in sources)})")
        return [p.name for p in sources], sources

    def _storage_file(self, path: Path) -> Path:
        """A readable MCAP file for ``path``: itself, or a decompressed temporary copy of a .zstd file."""
        if not path.name.endswith(".zstd"):
            return path
        if self._tmpdir is None:
            self._tmpdir = tempfile.TemporaryDirectory(prefix="ros2_lite_bag_")
            self._finalizer = weakref.finalize(self, self._tmpdir.cleanup)
        target = Path(self._tmpdir.name) / path.name[: -len(".zstd")]
        try:
            with open(path, "rb") as fin, open(target, "wb") as fout:
                zstandard.ZstdDecompressor().copy_stream(fin, fout)
        except zstandard.ZstdError as exc:
            raise BagError(f"'{path}': not a zstd-compressed MCAP file ({exc})") from None
        return target

    def _scan(self, path: Path, label: str) -> _FileScan:
        scan = _FileScan(path=path, label=label)
        try:
            with open(path, "rb") as f:
                if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
                    raise BagError(f"'{label}': not an MCAP file (it does not start with the MCAP magic bytes)")
                f.seek(0)
                reader = SeekingReader(f, validate_crcs=True)
                try:
                    summary = reader.get_summary()
                except _READ_ERRORS:
                    summary = None
                if summary is not None and summary.statistics is not None:
                    scan.schemas = dict(summary.schemas)
                    scan.channels = dict(summary.channels)
                    stats = summary.statistics
                    scan.counts = dict(stats.channel_message_counts)
                    if stats.message_count:
                        scan.start_ns, scan.end_ns = stats.message_start_time, stats.message_end_time
                    scan.indexed = bool(summary.chunk_indexes) or stats.message_count == 0
                    for md in reader.iter_metadata():
                        if md.name == "rosbag2":
                            scan.ros2_metadata = dict(md.metadata)
                    return scan
            scan.indexed = False
            for _ in self._linear_records(scan, collect=True):
                pass
        except BagError:
            raise
        except _READ_ERRORS as exc:
            raise BagError(f"'{label}': corrupt MCAP file, not readable as MCAP ({type(exc).__name__}: {exc})") from None
        except OSError as exc:
            raise BagError(f"'{label}': cannot read ({exc.strerror or exc})") from None
        return scan

    def _linear_records(self, scan: _FileScan, collect: bool) -> Iterator[Message]:
        """Messages of a file without a usable summary, read front to back. A file that ends in the middle
        of a record (a recorder killed hard) is read up to its last complete record."""
        with open(scan.path, "rb") as f:
            records = StreamReader(f, skip_magic=False, validate_crcs=True).records
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    return
                except EndOfFile:
                    if collect:
                        scan.truncated = "it ends in the middle of a record (recording not closed?)"
                        self.notes.append(f"'{scan.label}' has no index and {scan.truncated}: "
                                          "read up to its last complete record")
                    return
                if isinstance(record, Message):
                    if collect:
                        scan.counts[record.channel_id] = scan.counts.get(record.channel_id, 0) + 1
                        t = record.log_time
                        scan.start_ns = t if scan.start_ns is None else min(scan.start_ns, t)
                        scan.end_ns = t if scan.end_ns is None else max(scan.end_ns, t)
                    yield record
                elif collect and isinstance(record, Schema):
                    scan.schemas[record.id] = record
                elif collect and isinstance(record, Channel):
                    scan.channels[record.id] = record
                elif collect and isinstance(record, Metadata) and record.name == "rosbag2":
                    scan.ros2_metadata = dict(record.metadata)
                elif isinstance(record, Footer):
                    return

    def _bag_size(self) -> int:
        if self.path.is_dir():  # rosbag2: the size of the files in the bag directory
            return sum(p.stat().st_size for p in self.path.iterdir() if p.is_file())
        return self.path.stat().st_size

    def _summarise(self) -> None:
        found: dict[str, TopicSummary] = {}  # from the files, in order of appearance
        for scan in self._scans:
            for cid, ch in scan.channels.items():
                entry = found.get(ch.topic)
                if entry is None:
                    schema = scan.schemas.get(ch.schema_id)
                    qos_text = ch.metadata.get("offered_qos_profiles", "")
                    try:
                        qos = parse_qos_profiles(qos_text)
                    except MetadataError:
                        qos = []
                    entry = found[ch.topic] = TopicSummary(ch.topic, schema.name if schema else "", 0,
                                                           ch.message_encoding, qos,
                                                           ch.metadata.get("topic_type_hash", ""))
                entry.message_count += scan.counts.get(cid, 0)
        meta_topics = {t.name: t for t in self.metadata.topics} if self.metadata else {}
        topics: dict[str, TopicSummary] = {}
        for name, meta in meta_topics.items():  # metadata.yaml's order, what rosbag2 prints
            entry = found.get(name) or TopicSummary(name, meta.type, 0, meta.serialization_format)
            entry.type = entry.type or meta.type
            if meta.offered_qos_profiles:
                entry.offered_qos_profiles = list(meta.offered_qos_profiles)
            entry.type_description_hash = entry.type_description_hash or meta.type_description_hash
            topics[name] = entry
        for name, entry in found.items():
            topics.setdefault(name, entry)
        self.topics = topics
        self.message_count = sum(t.message_count for t in topics.values())
        starts = [s.start_ns for s in self._scans if s.start_ns is not None]
        ends = [s.end_ns for s in self._scans if s.end_ns is not None]
        self.start_time_ns = min(starts) if starts else 0
        self.end_time_ns = max(ends) if ends else 0
        self.duration_ns = self.end_time_ns - self.start_time_ns
        self.ros_distro = (self.metadata.ros_distro if self.metadata else "") or self._distro_from_files()
        if self.metadata is not None:
            self._compare_with_metadata(meta_topics)

    def _distro_from_files(self) -> str:
        for scan in self._scans:
            md = scan.ros2_metadata
            if md.get("ROS_DISTRO"):
                return md["ROS_DISTRO"]
            if md.get("serialized_metadata"):
                try:
                    distro = (yaml.safe_load(md["serialized_metadata"]) or {}).get("ros_distro")
                except yaml.YAMLError:
                    distro = None
                if distro:
                    return str(distro)
        return ""

    def _compare_with_metadata(self, meta_topics: dict[str, TopicInfo]) -> None:
        md = self.metadata
        assert md is not None
        diffs, lost = [], []
        if self.message_count:
            if md.starting_time_ns != self.start_time_ns:
                diffs.append(f"starting_time {md.starting_time_ns} ns vs {self.start_time_ns} ns")
            if md.duration_ns != self.duration_ns:
                diffs.append(f"duration {md.duration_ns} ns vs {self.duration_ns} ns")
        if md.message_count != self.message_count:
            (lost if md.message_count > self.message_count else diffs).append(
                f"message_count {md.message_count} vs {self.message_count}")
        for name, topic in self.topics.items():
            meta = meta_topics.get(name)
            if meta is None:
                diffs.append(f"topic '{name}' not listed")
            else:
                if meta.message_count != topic.message_count:
                    (lost if meta.message_count > topic.message_count else diffs).append(
                        f"'{name}' count {meta.message_count} vs {topic.message_count}")
                if topic.type and meta.type != topic.type:
                    diffs.append(f"'{name}' type {meta.type} vs {topic.type}")
        lost += [f"topic '{name}' ({meta.message_count} messages) missing" for name, meta in meta_topics.items()
                 if name not in self.topics and meta.message_count]
        # Times that differ are common in real rosbag2 bags (it writes them from the recording
        # clock); fewer messages than listed means some are gone: say that apart, it is damage.
        if lost:
            self.notes.append(MESSAGES_MISSING + " (metadata.yaml vs files: " + "; ".join(lost)
                              + "): the bag was cut short or files are missing")
        if diffs:
            self.notes.append("metadata.yaml disagrees with the MCAP files (metadata.yaml vs files: "
                              + "; ".join(diffs) + "); shown: what the MCAP files hold")

    # -- messages ----------------------------------------------------------------------------------
    def messages(self, topics: Iterable[str] | None = None, start_time_ns: int | None = None,
                 end_time_ns: int | None = None) -> Iterator[BagMessage]:
        """Messages in log-time order across the bag's files; ``topics`` filters, times are inclusive
        bounds in ns since the epoch. Raises BagError when a file turns out corrupt while reading."""
        wanted = None if topics is None else set(topics)
        iters = [self._file_messages(scan, wanted, start_time_ns, end_time_ns) for scan in self._scans]
        if len(iters) == 1:
            yield from iters[0]
        else:
            yield from heapq.merge(*iters, key=lambda m: m.log_time_ns)

    def __iter__(self) -> Iterator[BagMessage]:
        return self.messages(self.default_topics)

    def _file_messages(self, scan: _FileScan, wanted: set[str] | None, start: int | None,
                       end: int | None) -> Iterator[BagMessage]:
        decompress = zstandard.ZstdDecompressor() if self.compression_mode == "MESSAGE" else None
        types = {cid: (scan.schemas[ch.schema_id].name if ch.schema_id in scan.schemas
                       else self.topics.get(ch.topic, TopicSummary(ch.topic, "")).type)
                 for cid, ch in scan.channels.items()}
        try:
            if scan.indexed:
                with open(scan.path, "rb") as f:
                    reader = SeekingReader(f, validate_crcs=True)
                    end_before = None if end is None else end + 1
                    for _schema, channel, msg in reader.iter_messages(
                            topics=None if wanted is None else sorted(wanted), start_time=start, end_time=end_before,
                            log_time_order=True):
                        yield self._bag_message(channel.topic, types.get(channel.id, ""), msg, decompress)
            else:
                for msg in self._linear_records(scan, collect=False):
                    channel = scan.channels.get(msg.channel_id)
                    if channel is None or (wanted is not None and channel.topic not in wanted):
                        continue
                    if (start is not None and msg.log_time < start) or (end is not None and msg.log_time > end):
                        continue
                    yield self._bag_message(channel.topic, types.get(channel.id, ""), msg, decompress)
        except _READ_ERRORS as exc:
            raise BagError(f"'{scan.label}': corrupt MCAP data ({type(exc).__name__}: {exc})") from None

    @staticmethod
    def _bag_message(topic: str, type_name: str, msg: Message, decompress) -> BagMessage:
        data = msg.data
        if decompress is not None:
            data = decompress.decompressobj().decompress(data)
        return BagMessage(topic, type_name, msg.log_time, bytes(data))

    def message_definition(self, type_name: str) -> tuple[str, str]:
        """``(encoding, text)`` of the schema recorded for ``type_name`` (``("", "")`` if none)."""
        for scan in self._scans:
            for schema in scan.schemas.values():
                if schema.name == type_name:
                    return schema.encoding, schema.data.decode("utf-8", "replace")
        return "", ""


def open_bag(path: str | os.PathLike, topics: Iterable[str] | None = None) -> BagReader:
    """Open a bag for reading: ``for topic, type_name, log_time_ns, data in open_bag(p)``.

    ``path`` is a bag directory or an .mcap file; ``topics`` limits iteration to those topics.
    Raises BagError (one line naming the path) for a bag that is missing or unreadable. The returned
    ``BagReader`` also has the summary (``topics``, ``message_count``, ``start_time_ns``, ...) and is a
    context manager (it removes decompressed copies of ``.mcap.zstd`` files on close).
    """
    reader = BagReader(path)
    if topics is not None:
        reader.default_topics = list(topics)
    return reader


def read_messages(path: str | os.PathLike, topics: Iterable[str] | None = None) -> Iterator[tuple[str, Any, int]]:
    """``(topic, message object, log_time_ns)`` for each message (types must be importable)."""
    with open_bag(path, topics) as reader:
        for m in reader:
            yield m.topic, m.message(), m.log_time_ns


# -- writing -------------------------------------------------------------------------------------
@dataclass
class _WriterTopic:
    info: TopicInfo
    encoding: str
    definition: str


class BagWriter:
    """Write a rosbag2 bag directory as rosbag2 Jazzy's recorder does (one thread at a time).

    ``storage_preset_profile``: ``zstd_fast`` (default: zstd-compressed 1 MiB chunks), ``zstd_small``
    (zstd, 4 MiB chunks), ``none`` (uncompressed chunks), ``fastwrite`` (no chunks, no index).
    ``compression_mode``: rosbag2's ``none``, ``file`` (each finished file becomes ``.mcap.zstd``) or
    ``message`` (each payload zstd-compressed; rosbag2's own MCAP plugin refuses this mode, rosbags and
    this reader read it). ``max_bag_size`` (bytes) and ``max_bag_duration_s`` split into
    ``dir_1.mcap``, ... as rosbag2's ``-b``/``-d`` do. Times are ns since the epoch.
    """

    def __init__(self, path: str | os.PathLike, *, storage_preset_profile: str = "zstd_fast",
                 compression_mode: str = "none", compression_format: str = "", max_bag_size: int = 0,
                 max_bag_duration_s: float = 0.0, custom_data: dict[str, str] | None = None,
                 ros_distro: str | None = None):
        self.path = Path(path)
        if storage_preset_profile not in PRESET_PROFILES:
            raise ValueError(f"storage_preset_profile must be one of {PRESET_PROFILES}")
        mode = (compression_mode or "none").lower()
        if mode not in COMPRESSION_MODES:
            raise ValueError(f"compression_mode must be one of {COMPRESSION_MODES}")
        if mode != "none" and compression_format not in ("", "zstd"):
            raise ValueError("compression_format must be zstd")
        if self.path.exists():
            raise BagError(f"Output folder '{self.path}' already exists")
        try:
            self.path.mkdir(parents=True)
        except OSError as exc:
            raise BagError(f"Cannot create bag directory '{self.path}' ({exc.strerror or exc})") from None
        self._mode = mode
        self._preset = storage_preset_profile
        self._max_size = int(max_bag_size)
        self._max_duration_ns = int(max_bag_duration_s * 1e9)
        self._message_compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL) if mode == "message" else None
        self.metadata = BagMetadata(
            compression_format="zstd" if mode != "none" else "",
            compression_mode=mode.upper() if mode != "none" else "",
            custom_data=dict(custom_data or {}),
            ros_distro=ros_distro if ros_distro is not None else (os.environ.get("ROS_DISTRO") or "jazzy"),
        )
        self._topics: dict[str, _WriterTopic] = {}
        self._topic_counts: dict[str, int] = {}
        self._file = None
        self._mcap: Writer | None = None
        self._schema_ids: dict[str, int] = {}
        self._channel_ids: dict[str, int] = {}
        self._closed = False
        self._compressing: list[threading.Thread] = []
        self._compression_error: OSError | None = None
        self._open_file()

    @property
    def message_count(self) -> int:
        return self.metadata.message_count

    # -- topics ------------------------------------------------------------------------------------
    def add_topic(self, name: str, type_name: str, *, offered_qos_profiles: list[Qos] | None = None,
                  type_description_hash: str = "", serialization_format: str = "cdr") -> None:
        """Declare a topic before writing to it. ``offered_qos_profiles`` are what its publishers offered
        (replay uses them: e.g. ``[Qos(durability="transient_local", depth=1)]`` for a latched topic);
        default one reliable, volatile, keep-last-10 profile."""
        if name in self._topics:
            return
        from ros2_lite.bag_msgdef import message_definition

        encoding, text = message_definition(type_name)
        info = TopicInfo(name=name, type=type_name, serialization_format=serialization_format,
                         offered_qos_profiles=list(offered_qos_profiles if offered_qos_profiles is not None
                                                   else [Qos()]),
                         type_description_hash=type_description_hash)
        self._topics[name] = _WriterTopic(info, encoding, text)
        self._topic_counts[name] = 0
        self._register(name)

    def _register(self, name: str) -> None:
        topic = self._topics[name]
        assert self._mcap is not None
        schema_id = self._schema_ids.get(topic.info.type)
        if schema_id is None:
            schema_id = self._mcap.register_schema(topic.info.type, topic.encoding, topic.definition.encode())
            self._schema_ids[topic.info.type] = schema_id
        self._channel_ids[name] = self._mcap.register_channel(
            name, topic.info.serialization_format, schema_id,
            {"offered_qos_profiles": dump_qos_profiles(topic.info.offered_qos_profiles),
             "topic_type_hash": topic.info.type_description_hash})

    # -- messages ----------------------------------------------------------------------------------
    def write(self, topic: str, message: Any, log_time_ns: int | None = None,
              publish_time_ns: int | None = None) -> None:
        """Append one message: CDR ``bytes`` or a message object (serialised here). A message object on
        an undeclared topic declares it with its own type."""
        if self._closed:
            raise BagError(f"'{self.path}': the bag writer is closed")
        if isinstance(message, (bytes, bytearray, memoryview)):
            data = bytes(message)
            if topic not in self._topics:
                raise BagError(f"topic '{topic}' is not declared: call add_topic() before writing bytes")
        else:
            if topic not in self._topics:
                self.add_topic(topic, type_name_of(message))
            data = serialize(message)
        t = time.time_ns() if log_time_ns is None else int(log_time_ns)
        md = self.metadata
        if md.message_count and self._should_split(t):
            self._split()
            md.files[-1].starting_time_ns = t
        md.starting_time_ns = min(md.starting_time_ns, t)
        md.duration_ns = max(md.duration_ns, t - md.starting_time_ns)
        current = md.files[-1]
        current.starting_time_ns = min(current.starting_time_ns, t)
        current.duration_ns = max(current.duration_ns, t - current.starting_time_ns)
        current.message_count += 1
        if self._message_compressor is not None:
            data = self._message_compressor.compress(data)
        assert self._mcap is not None
        self._mcap.add_message(self._channel_ids[topic], t, data, t if publish_time_ns is None else publish_time_ns)
        md.message_count += 1
        self._topic_counts[topic] += 1

    def _should_split(self, t: int) -> bool:
        if self._max_size and self._file is not None and self._file.tell() >= self._max_size:
            return True
        start = self.metadata.files[-1].starting_time_ns
        return bool(self._max_duration_ns) and start != UNSET_TIME_NS and t - start > self._max_duration_ns

    # -- files -------------------------------------------------------------------------------------
    def _open_file(self) -> None:
        index = len(self.metadata.relative_file_paths)
        name = f"{self.path.name}_{index}.mcap"
        self._file = open(self.path / name, "wb")
        compression = CompressionType.ZSTD if self._preset in ("zstd_fast", "zstd_small") else CompressionType.NONE
        if self._mode != "none":  # the payload or the whole file is compressed already
            compression = CompressionType.NONE
        self._mcap = Writer(self._file, chunk_size=(4 if self._preset == "zstd_small" else 1) * 1024 * 1024,
                            compression=compression, use_chunking=self._preset != "fastwrite")
        self._mcap.start(profile="ros2", library=LIBRARY)
        self._schema_ids.clear()
        self._channel_ids.clear()
        self.metadata.relative_file_paths.append(name)
        self.metadata.files.append(FileInfo(path=name))
        for topic in self._topics:
            self._register(topic)

    def _finish_file(self) -> None:
        assert self._mcap is not None and self._file is not None
        self._sync_topic_metadata()
        self._mcap.add_metadata("rosbag2", {"serialized_metadata": emit_yaml(self.metadata.to_dict())})
        self._mcap.finish()
        self._file.close()
        self._mcap, self._file = None, None
        if self._mode == "file":  # compressed in the background, as rosbag2's compression threads do
            index = len(self.metadata.relative_file_paths) - 1
            thread = threading.Thread(target=self._compress_file, args=(index,), name="bag_file_compression")
            thread.start()
            self._compressing.append(thread)

    def _compress_file(self, index: int) -> None:
        name = self.metadata.relative_file_paths[index]
        source = self.path / name
        try:
            with open(source, "rb") as fin, open(self.path / f"{name}.zstd", "wb") as fout:
                zstandard.ZstdCompressor(level=ZSTD_LEVEL).copy_stream(fin, fout, size=source.stat().st_size)
        except OSError as exc:
            self._compression_error = exc
            return
        source.unlink()
        self.metadata.relative_file_paths[index] = f"{name}.zstd"

    def _split(self) -> None:
        self._finish_file()
        self._open_file()

    def _sync_topic_metadata(self) -> None:
        self.metadata.topics = [
            TopicInfo(t.info.name, t.info.type, t.info.serialization_format, t.info.offered_qos_profiles,
                      t.info.type_description_hash, self._topic_counts[name])
            for name, t in self._topics.items()
        ]

    def close(self) -> Path:
        """Finish the MCAP file and write metadata.yaml. Returns the bag directory."""
        if not self._closed:
            self._closed = True
            self._finish_file()
            for thread in self._compressing:
                thread.join()
            if self._compression_error is not None:
                raise BagError(f"Cannot compress a file of '{self.path}' ({self._compression_error})")
            write_metadata(self.path, self.metadata)
        return self.path

    def __enter__(self) -> "BagWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
