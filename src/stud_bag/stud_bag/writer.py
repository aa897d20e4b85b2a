"""Write rosbag2 bags as ``ros2 bag record`` (rosbag2 Jazzy, MCAP storage) does.

``BagWriter(dir)`` writes ``dir/dir_0.mcap`` (profile ``ros2``, ``ros2msg`` schemas with the full
definition, ``cdr`` channels with ``offered_qos_profiles`` and ``topic_type_hash`` metadata, zstd
chunks, a ``rosbag2`` metadata record) and ``dir/metadata.yaml`` (version 9) when closed. rclpy is
imported only to serialise message objects, so scripts can write sensor bags directly.
"""
from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import zstandard
from mcap.writer import CompressionType, Writer

from stud_bag.core import COMPRESSION_MODES, LIBRARY, PRESET_PROFILES, ZSTD_LEVEL, BagError, serialize, type_name_of
from stud_bag.metadata import (
    UNSET_TIME_NS,
    BagMetadata,
    FileInfo,
    Qos,
    TopicInfo,
    dump_qos_profiles,
    emit_yaml,
    write_metadata,
)


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
        self._file: BinaryIO | None = None
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
        from stud_bag.msgdef import message_definition

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
        self._file = file = open(self.path / name, "wb")
        compression = CompressionType.ZSTD if self._preset in ("zstd_fast", "zstd_small") else CompressionType.NONE
        if self._mode != "none":  # the payload or the whole file is compressed already
            compression = CompressionType.NONE
        self._mcap = Writer(file, chunk_size=(4 if self._preset == "zstd_small" else 1) * 1024 * 1024,
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
