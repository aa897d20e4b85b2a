"""rosbag2's ``metadata.yaml``: the data model, reading every version (1..9), writing version 9.

The layout follows rosbag2 Jazzy (``rosbag2_storage/yaml.hpp``, ``qos.cpp``): version 9 writes
``offered_qos_profiles`` as a YAML sequence with policy names (``keep_last``, ``reliable``, ...);
versions 4..8 stored it as a string holding a YAML list with integer policies, which we read too.
The writer emits the same block style as yaml-cpp (keys in rosbag2's order, ``""`` for empty
strings, ``~`` for empty custom data) so a file we write diffs cleanly against one rosbag2 wrote.
No rclpy here: this module is used by offline tools.
"""
from __future__ import annotations

import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

METADATA_FILENAME = "metadata.yaml"
METADATA_VERSION = 9  # what rosbag2 Jazzy writes
INFINITE_NS = 2**63 - 1  # RMW_DURATION_INFINITE: {sec: 9223372036, nsec: 854775807}
UNSET_TIME_NS = 2**63 - 1  # rosbag2's starting_time of a file that got no message

# rmw enum values (rmw/types.h) as stored by metadata versions < 9, and their rmw names (version 9)
_HISTORY = {0: "system_default", 1: "keep_last", 2: "keep_all", 3: "unknown"}
_RELIABILITY = {0: "system_default", 1: "reliable", 2: "best_effort", 3: "unknown", 4: "best_available"}
_DURABILITY = {0: "system_default", 1: "transient_local", 2: "volatile", 3: "unknown", 4: "best_available"}
_LIVELINESS = {0: "system_default", 1: "automatic", 2: "manual_by_node", 3: "manual_by_topic", 4: "unknown",
               5: "best_available"}


class MetadataError(ValueError):
    """metadata.yaml is missing fields or holds values of the wrong kind."""


@dataclass(frozen=True)
class Qos:
    """One offered QoS profile as rosbag2 stores it. Durations in nanoseconds (``INFINITE_NS`` = infinite).

    Profiles that come from DDS discovery have ``history='unknown'`` and ``depth=0``: history is not
    part of what a publisher announces.
    """

    history: str = "keep_last"
    depth: int = 10
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline_ns: int = INFINITE_NS
    lifespan_ns: int = INFINITE_NS
    liveliness: str = "automatic"
    liveliness_lease_duration_ns: int = INFINITE_NS
    avoid_ros_namespace_conventions: bool = False

    def to_dict(self) -> dict[str, Any]:
        """The version-9 mapping, in rosbag2's key order."""
        return {
            "history": self.history,
            "depth": self.depth,
            "reliability": self.reliability,
            "durability": self.durability,
            "deadline": _duration_dict(self.deadline_ns),
            "lifespan": _duration_dict(self.lifespan_ns),
            "liveliness": self.liveliness,
            "liveliness_lease_duration": _duration_dict(self.liveliness_lease_duration_ns),
            "avoid_ros_namespace_conventions": self.avoid_ros_namespace_conventions,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Qos":
        """Parse a profile of any metadata version (integer or named policies)."""
        try:
            return cls(
                history=_policy(d["history"], _HISTORY),
                depth=int(d.get("depth", 0)),
                reliability=_policy(d["reliability"], _RELIABILITY),
                durability=_policy(d["durability"], _DURABILITY),
                deadline_ns=_duration_ns(d.get("deadline")),
                lifespan_ns=_duration_ns(d.get("lifespan")),
                liveliness=_policy(d.get("liveliness", 0), _LIVELINESS),
                liveliness_lease_duration_ns=_duration_ns(d.get("liveliness_lease_duration")),
                avoid_ros_namespace_conventions=bool(d.get("avoid_ros_namespace_conventions", False)),
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise MetadataError(f"invalid QoS profile {d!r}: {exc}") from None


def _policy(value: Any, names: dict[int, str]) -> str:
    if isinstance(value, bool):
        raise ValueError(f"policy {value!r}")
    if isinstance(value, int):
        return names.get(value, "unknown")
    text = str(value).strip().lower()
    return text if text in names.values() else "unknown"


def _duration_dict(ns: int) -> dict[str, int]:
    return {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}


def _duration_ns(d: Any) -> int:
    if not d:
        return 0
    sec, nsec = int(d["sec"]), int(d["nsec"])
    # rosbag2 maps the "infinite" of Foxy-era RMWs to RMW_DURATION_INFINITE (qos.cpp)
    if (sec, nsec) in ((0x7FFFFFFF, 0xFFFFFFFF), (0x7FFFFFFF, 0x7FFFFFFF)) or sec * 1_000_000_000 + nsec >= INFINITE_NS:
        return INFINITE_NS
    return sec * 1_000_000_000 + nsec


def parse_qos_profiles(value: Any) -> list[Qos]:
    """``offered_qos_profiles`` of any version: a list of mappings, or a string holding one (v4..8)."""
    if value is None or value == "":
        return []
    if isinstance(value, str):
        try:
            value = yaml.safe_load(value)
        except yaml.YAMLError as exc:
            raise MetadataError(f"offered_qos_profiles is not YAML: {exc}") from None
        if value is None:
            return []
    if not isinstance(value, list):
        raise MetadataError(f"offered_qos_profiles must be a list, got {type(value).__name__}")
    return [Qos.from_dict(d) for d in value]


def dump_qos_profiles(profiles: list[Qos]) -> str:
    """The string rosbag2 puts in an MCAP channel's ``offered_qos_profiles`` (``YAML::Dump``, version 9)."""
    if not profiles:
        return "[]"
    return emit_yaml([p.to_dict() for p in profiles]).rstrip("\n")


@dataclass
class TopicInfo:
    """One entry of ``topics_with_message_count``."""

    name: str
    type: str
    serialization_format: str = "cdr"
    offered_qos_profiles: list[Qos] = field(default_factory=list)
    type_description_hash: str = ""
    message_count: int = 0


@dataclass
class FileInfo:
    """One entry of ``files`` (version >= 5): a storage file, its first message time and span."""

    path: str
    starting_time_ns: int = UNSET_TIME_NS
    duration_ns: int = 0
    message_count: int = 0


@dataclass
class BagMetadata:
    """``rosbag2_bagfile_information``. Times in nanoseconds since the epoch, durations in nanoseconds."""

    version: int = METADATA_VERSION
    storage_identifier: str = "mcap"
    duration_ns: int = 0
    starting_time_ns: int = UNSET_TIME_NS
    message_count: int = 0
    topics: list[TopicInfo] = field(default_factory=list)
    compression_format: str = ""
    compression_mode: str = ""
    relative_file_paths: list[str] = field(default_factory=list)
    files: list[FileInfo] = field(default_factory=list)
    custom_data: dict[str, str] = field(default_factory=dict)
    ros_distro: str = ""

    def to_dict(self) -> dict[str, Any]:
        """The mapping rosbag2 writes (``convert<BagMetadata>::encode``), in its key order."""
        return {
            "version": self.version,
            "storage_identifier": self.storage_identifier,
            "duration": {"nanoseconds": self.duration_ns},
            "starting_time": {"nanoseconds_since_epoch": self.starting_time_ns},
            "message_count": self.message_count,
            "topics_with_message_count": [
                {
                    "topic_metadata": {
                        "name": t.name,
                        "type": t.type,
                        "serialization_format": t.serialization_format,
                        "offered_qos_profiles": [q.to_dict() for q in t.offered_qos_profiles],
                        "type_description_hash": t.type_description_hash,
                    },
                    "message_count": t.message_count,
                }
                for t in self.topics
            ],
            "compression_format": self.compression_format,
            "compression_mode": self.compression_mode,
            "relative_file_paths": list(self.relative_file_paths),
            "files": [
                {
                    "path": f.path,
                    "starting_time": {"nanoseconds_since_epoch": f.starting_time_ns},
                    "duration": {"nanoseconds": f.duration_ns},
                    "message_count": f.message_count,
                }
                for f in self.files
            ],
            "custom_data": dict(self.custom_data) or None,
            "ros_distro": self.ros_distro,
        }

    @classmethod
    def from_dict(cls, info: Any) -> "BagMetadata":
        """Parse ``rosbag2_bagfile_information`` of any version (fields absent in old versions default)."""
        if not isinstance(info, dict):
            raise MetadataError("'rosbag2_bagfile_information' is not a mapping")
        try:
            version = int(info["version"])
            topics = []
            for entry in info.get("topics_with_message_count") or []:
                tm = entry["topic_metadata"]
                topics.append(TopicInfo(
                    name=str(tm["name"]),
                    type=str(tm["type"]),
                    serialization_format=str(tm.get("serialization_format", "cdr")),
                    offered_qos_profiles=parse_qos_profiles(tm.get("offered_qos_profiles")),
                    type_description_hash=str(tm.get("type_description_hash") or ""),
                    message_count=int(entry.get("message_count", 0)),
                ))
            files = [
                FileInfo(
                    path=str(f["path"]),
                    starting_time_ns=int(f["starting_time"]["nanoseconds_since_epoch"]),
                    duration_ns=int(f["duration"]["nanoseconds"]),
                    message_count=int(f["message_count"]),
                )
                for f in (info.get("files") or [])
            ]
            return cls(
                version=version,
                storage_identifier=str(info["storage_identifier"]),
                duration_ns=int(info["duration"]["nanoseconds"]),
                starting_time_ns=int(info["starting_time"]["nanoseconds_since_epoch"]),
                message_count=int(info["message_count"]),
                topics=topics,
                compression_format=str(info.get("compression_format") or ""),
                compression_mode=str(info.get("compression_mode") or ""),
                relative_file_paths=[str(p) for p in info.get("relative_file_paths") or []],
                files=files,
                custom_data={str(k): str(v) for k, v in (info.get("custom_data") or {}).items()},
                ros_distro=str(info.get("ros_distro") or ""),
            )
        except KeyError as exc:
            raise MetadataError(f"missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise MetadataError(f"invalid value ({exc})") from None


def read_metadata(bag_dir: Path) -> BagMetadata:
    """Read ``<bag_dir>/metadata.yaml``. Raises OSError, MetadataError."""
    path = Path(bag_dir) / METADATA_FILENAME
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise MetadataError(f"not valid YAML ({str(exc).splitlines()[0]})") from None
    except UnicodeDecodeError:
        raise MetadataError("not a text file") from None
    if not isinstance(doc, dict) or "rosbag2_bagfile_information" not in doc:
        raise MetadataError("no 'rosbag2_bagfile_information' mapping")
    return BagMetadata.from_dict(doc["rosbag2_bagfile_information"])


def write_metadata(bag_dir: Path, metadata: BagMetadata) -> Path:
    """Write ``<bag_dir>/metadata.yaml`` atomically (a reader never sees half a file)."""
    path = Path(bag_dir) / METADATA_FILENAME
    tmp = path.with_name(f".{METADATA_FILENAME}.tmp")
    tmp.write_text(emit_yaml({"rosbag2_bagfile_information": metadata.to_dict()}))
    os.replace(tmp, path)
    return path


# -- a YAML emitter in yaml-cpp's block style ---------------------------------------------------
_PLAIN = re.compile(r"^[A-Za-z_/][A-Za-z0-9_/.\-]*$")
_RESERVED = {"true", "false", "yes", "no", "on", "off", "null", "y", "n", "~"}


def _scalar(value: Any) -> str:
    if value is None:
        return "~"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    text = str(value)
    if _PLAIN.match(text) and text.lower() not in _RESERVED:
        return text
    return json.dumps(text)  # a JSON string is a valid YAML double-quoted scalar


def emit_yaml(value: Any, indent: int = 0) -> str:
    """Block-style YAML: maps ``key: value``, sequences ``- item`` indented under their key."""
    lines: list[str] = []
    _emit(value, indent, lines, first_prefix=None)
    return "\n".join(lines) + "\n"


def _emit(value: Any, indent: int, lines: list[str], first_prefix: str | None) -> None:
    """Append ``value`` at column ``indent``; ``first_prefix`` replaces the first line's indentation
    (used for ``- `` of a sequence item holding a map)."""
    pad = " " * indent
    prefix = first_prefix if first_prefix is not None else pad
    if isinstance(value, dict):
        if not value:
            lines.append(prefix + "{}")
            return
        for i, (key, item) in enumerate(value.items()):
            head = (prefix if i == 0 else pad) + f"{key}:"
            if isinstance(item, dict) and item:
                lines.append(head)
                _emit(item, indent + 2, lines, None)
            elif isinstance(item, list) and item:
                lines.append(head)
                _emit(item, indent + 2, lines, None)
            else:
                lines.append(f"{head} {_inline(item)}")
    elif isinstance(value, list):
        if not value:
            lines.append(prefix + "[]")
            return
        for i, item in enumerate(value):
            dash = (prefix if i == 0 else pad) + "- "
            if isinstance(item, (dict, list)) and item:
                _emit(item, indent + 2, lines, dash)
            else:
                lines.append(dash + _inline(item))
    else:
        lines.append(prefix + _inline(value))


def _inline(value: Any) -> str:
    if isinstance(value, dict):
        return "{}"
    if isinstance(value, list):
        return "[]"
    return _scalar(value)
