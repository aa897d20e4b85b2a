"""Full message definitions for MCAP schemas, as rosbag2's ``LocalMessageDefinitionSource`` builds them.

``ros2msg``: the type's ``.msg`` text, then for each dependency (sorted, depth first, each once)
``"\\n" + "=" * 80 + "\\nMSG: pkg/Type\\n"`` and its text. Types with only an ``.idl`` get
``ros2idl`` the same way with ``IDL:`` delimiters. Definitions come from the ``share/<pkg>/msg``
folders of the ament index, the files rosbag2 reads. Foxglove, ``rosbags`` and ``mcap-ros2-support``
decode messages with these texts alone.
"""
from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_prefix

DELIMITER = "=" * 80 + "\n"
# the same patterns as rosbag2_cpp/message_definitions/local_message_definition_source.cpp
_TYPENAME = re.compile(r"^([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)$")
_MSG_FIELD_TYPE = re.compile(r"(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+")
_IDL_INCLUDE = re.compile(r"(?:^|\n)#include\s+(?:\"|<)([a-zA-Z0-9_/]+)\.idl(?:\"|>)")
# rosbag2's list lacks wstring (it would then look for a package-local "wstring.msg" and fall back
# to IDL); treating it as the primitive it is gives the definition Foxglove expects.
_PRIMITIVES = {"bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
               "int32", "uint32", "int64", "uint64", "string", "wstring"}
_MAX_DEPTH = 50


class DefinitionNotFound(LookupError):
    """No .msg (or .idl) file for a type in the ament index."""


def _definition_file(type_name: str, ext: str) -> tuple[str, Path]:
    match = _TYPENAME.match(type_name)
    if not match:
        raise DefinitionNotFound(f"type name '{type_name}' not understood (expected pkg/msg/Name)")
    package, name = match.groups()
    try:
        prefix = Path(get_package_prefix(package))
    except (PackageNotFoundError, OSError):  # OSError: no AMENT_PREFIX_PATH at all
        raise DefinitionNotFound(f"package '{package}' of '{type_name}' is not in the ament index") from None
    path = prefix / "share" / package / "msg" / f"{name}{ext}"
    if not path.is_file():
        raise DefinitionNotFound(f"no {path}")
    return package, path


def _msg_dependencies(text: str, package: str) -> list[str]:
    deps = set()
    for match in _MSG_FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in _PRIMITIVES:
            continue
        deps.add(field_type if "/" in field_type else f"{package}/{field_type}")
    return sorted(deps)


def _full_text(root: str, ext: str, label: str, deps_of) -> str:
    seen: set[str] = set()

    def append(type_name: str, depth: int) -> str:
        if depth <= 0:
            raise DefinitionNotFound(f"reached the maximum nesting depth resolving {root}")
        package, path = _definition_file(type_name, ext)
        text = path.read_text()
        result = text
        for dep in deps_of(text, package):
            if dep not in seen:
                seen.add(dep)
                result += "\n" + DELIMITER + f"{label}: {dep}\n" + append(dep, depth - 1)
        return result

    if label == "IDL":
        return DELIMITER + f"IDL: {root}\n" + append(root, _MAX_DEPTH)
    return append(root, _MAX_DEPTH)


@lru_cache(maxsize=None)
def message_definition(type_name: str) -> tuple[str, str]:
    """``(schema_encoding, text)`` for an MCAP schema of ``type_name`` (``pkg/msg/Name``).

    ``("ros2msg", text)`` from the .msg files, else ``("ros2idl", text)`` from .idl files, else
    ``("unknown", "")`` as rosbag2 does for a type it cannot find (the bag stays readable by rosbag2;
    viewers then cannot decode that topic).
    """
    try:
        return "ros2msg", _full_text(type_name, ".msg", "MSG", _msg_dependencies)
    except DefinitionNotFound:
        pass
    try:
        return "ros2idl", _full_text(type_name, ".idl", "IDL",
                                     lambda text, _pkg: sorted(set(_IDL_INCLUDE.findall(text))))
    except DefinitionNotFound:
        return "unknown", ""
