"""What the bag reader and writer share: the errors, one recorded message, a topic's summary, the
constants of rosbag2's MCAP layout, and message (de)serialisation through rclpy."""
from __future__ import annotations

import importlib
import struct
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import zstandard
from mcap.exceptions import EndOfFile, McapError

from stud_bag.metadata import (
    Qos,
)

MCAP_MAGIC = b"\x89MCAP0\r\n"
LIBRARY = "stud_bag (mcap-python)"
PRESET_PROFILES = ("none", "fastwrite", "zstd_fast", "zstd_small")
COMPRESSION_MODES = ("none", "file", "message")
ZSTD_LEVEL = 1  # rosbag2_compression_zstd's default level for file and message compression
READ_ERRORS = (McapError, EndOfFile, struct.error, ValueError, KeyError, IndexError, OverflowError,
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

