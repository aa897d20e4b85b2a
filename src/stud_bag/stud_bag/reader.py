"""Read rosbag2 bags (``metadata.yaml`` + MCAP files) without a running ROS graph.

``open_bag(path)`` takes a bag directory (split bags, file-compressed ``.mcap.zstd``,
message-compressed payloads) or a single ``.mcap`` file and yields ``BagMessage(topic, type_name,
log_time_ns, data)`` in log-time order across all files; ``BagMessage.message()`` turns the CDR bytes
into our rclpy message class. What the bag holds (topics, counts, times) is computed from the MCAP
files themselves; where ``metadata.yaml`` says otherwise ``BagReader.notes`` says so.
"""
from __future__ import annotations

import heapq
import os
import re
import tempfile
import weakref
from dataclasses import dataclass, field
from pathlib import Path, PurePath
from typing import Any, Iterable, Iterator

import yaml
import zstandard
from mcap.exceptions import EndOfFile
from mcap.reader import SeekingReader
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader

from stud_bag.core import MCAP_MAGIC, READ_ERRORS, BagError, BagMessage, TopicSummary
from stud_bag.metadata import (
    METADATA_FILENAME,
    BagMetadata,
    MetadataError,
    TopicInfo,
    parse_qos_profiles,
    read_metadata,
)


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
        self._finalizer: weakref.finalize | None = None
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
            self._tmpdir = tempfile.TemporaryDirectory(prefix="stud_bag_")
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
                except READ_ERRORS:
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
        except READ_ERRORS as exc:
            raise BagError(f"'{label}': corrupt MCAP file, not readable as MCAP "
                           f"({type(exc).__name__}: {exc})") from None
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
        diffs: list[str] = []
        lost: list[str] = []
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
                    for _schema, channel, msg in reader.iter_messages(
                            topics=None if wanted is None else sorted(wanted), starting_at=start, ending_at=end,
                            log_time_order=True):
                        yield self._bag_message(channel.topic, types.get(channel.id, ""), msg, decompress)
            else:
                for msg in self._linear_records(scan, collect=False):
                    found = scan.channels.get(msg.channel_id)
                    if found is None or (wanted is not None and found.topic not in wanted):
                        continue
                    if (start is not None and msg.log_time < start) or (end is not None and msg.log_time > end):
                        continue
                    yield self._bag_message(found.topic, types.get(found.id, ""), msg, decompress)
        except READ_ERRORS as exc:
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

