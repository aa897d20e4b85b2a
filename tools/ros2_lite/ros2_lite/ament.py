"""The ament resource index, read the way ament_index_python and ros2cli read it.

A package ``P`` is installed in prefix ``X`` when ``X/share/ament_index/resource_index/packages/P``
exists; the first prefix on ``AMENT_PREFIX_PATH`` wins. Interface definitions are listed under the
``rosidl_interfaces`` resource type and live in ``X/share/P/{msg,srv,action}/Name.<kind>``.
"""
from __future__ import annotations

import os
from pathlib import Path

RESOURCE_INDEX = Path("share") / "ament_index" / "resource_index"
PRIMITIVES = {
    "bool", "byte", "char", "float32", "float64", "int8", "uint8", "int16", "uint16",
    "int32", "uint32", "int64", "uint64", "string", "wstring",
}


def prefixes() -> list[Path]:
    raw = os.environ.get("AMENT_PREFIX_PATH", "")
    return [Path(p) for p in raw.split(os.pathsep) if p]


def resources(resource_type: str) -> dict[str, Path]:
    """Resource name -> prefix it is registered in (first prefix wins)."""
    found: dict[str, Path] = {}
    for prefix in prefixes():
        folder = prefix / RESOURCE_INDEX / resource_type
        if folder.is_dir():
            for entry in folder.iterdir():
                if not entry.name.startswith(".") and entry.is_file():
                    found.setdefault(entry.name, prefix)
    return found


def packages() -> dict[str, Path]:
    return resources("packages")


def package_prefix(name: str) -> Path | None:
    return packages().get(name)


def executables(package: str, prefix: Path) -> list[Path]:
    """Executable files below ``<prefix>/lib/<package>`` (sorted walk, dot-folders skipped),
    as ros2run's ``get_executable_paths``."""
    base = prefix / "lib" / package
    paths: list[Path] = []
    for dirpath, dirnames, filenames in os.walk(base):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith("."))
        for filename in sorted(filenames):
            path = Path(dirpath) / filename
            if os.access(path, os.X_OK):
                paths.append(path)
    return paths


def interfaces() -> list[str]:
    """All interface names ``pkg/kind/Name`` registered in the index."""
    names: list[str] = []
    for package, prefix in resources("rosidl_interfaces").items():
        text = (prefix / RESOURCE_INDEX / "rosidl_interfaces" / package).read_text()
        for line in text.splitlines():
            rel = line.strip()
            if rel.endswith((".msg", ".srv", ".action")) and "/" in rel:
                kind, file = rel.split("/", 1)
                names.append(f"{package}/{kind}/{file.rsplit('.', 1)[0]}")
    return sorted(set(names))


def interface_path(type_name: str) -> Path:
    """``pkg/msg/Name`` (or ``pkg/Name`` for a message) -> the definition file."""
    parts = type_name.strip("/").split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or parts[1] not in ("msg", "srv", "action"):
        raise LookupError(f"Invalid interface type '{type_name}': expected <package>/<msg|srv|action>/<Name>")
    package, kind, name = parts
    prefix = package_prefix(package)
    if prefix is None:
        raise LookupError(f"Unknown package '{package}'")
    path = prefix / "share" / package / kind / f"{name}.{kind}"
    if not path.is_file():
        raise LookupError(f"Could not find the interface '{path}'")
    return path


def _field_type(line: str) -> str | None:
    """Base type of a field line (``pkg/Type``), or None for primitives, constants, comments."""
    code = line.split("#", 1)[0].strip()
    if not code or code == "---":  # empty, or the request/response/feedback separator
        return None
    first, _, rest = code.partition(" ")
    if "=" in rest.split("#")[0] and not rest.strip().startswith("="):
        # "uint8 NAME = 1" is a constant; "float64[] name" is not
        if rest.split("=", 1)[0].strip().isidentifier() and rest.split("=", 1)[0].strip().isupper():
            return None
    base = first.split("[", 1)[0].split("<=", 1)[0]
    if base in PRIMITIVES:
        return None
    return base


def interface_text(type_name: str, comments: bool = True, expand: bool = True, _package: str | None = None,
                   _indent: str = "") -> str:
    """Definition text as `ros2 interface show` prints it: nested types expanded with a tab
    per level; nested definitions without their comments."""
    path = interface_path(type_name)
    package = type_name.strip("/").split("/")[0]
    out: list[str] = []
    for raw in path.read_text().splitlines():
        line = raw.rstrip()
        stripped = line.strip()
        if stripped.startswith("#") or not stripped:
            if comments and (not _indent or not stripped.startswith("#")):
                if stripped or not _indent:
                    out.append(_indent + line)
            continue
        out.append(_indent + (line if comments else line.split("#", 1)[0].rstrip()))
        nested = _field_type(line) if expand else None
        if nested:
            full = nested if "/" in nested else f"{package}/msg/{nested}"
            if full.count("/") == 1:
                full = full.replace("/", "/msg/", 1)
            if nested == "Header":
                full = "std_msgs/msg/Header"
            out.append(interface_text(full, comments=False, expand=True, _indent=_indent + "\t"))
    return "\n".join(out)
