"""Messages as YAML and back, the way ros2cli shows and fills them (rosidl_runtime_py is not in the wheels).

* :func:`message_to_yaml`: fields in definition order, block style, nested messages as mappings,
  arrays as lists; strings and arrays longer than ``truncate_length`` cut with ``'...'``.
* :func:`set_message_fields`: fill a message from a YAML mapping (``'{data: hi}'``), converting
  ints to floats where the field is a float, building nested messages and sequences of them;
  ``now`` for a ``builtin_interfaces/Time`` field and ``auto`` for a ``std_msgs/Header`` are stamped
  with the current time (as ``ros2 topic pub``). Unknown field names are an error naming the field.
* :func:`interface_class`: ``pkg/msg/Name`` (``pkg/Name`` for a message), ``pkg/srv/Name``,
  ``pkg/action/Name`` -> the generated Python class.
"""
from __future__ import annotations

import array
import importlib
import sys
from collections import OrderedDict
from typing import Any, Callable

import yaml

_FLOAT_TYPES = {"float", "double", "long double"}
_INT_TYPES = {"octet", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"}


class InterfaceError(ValueError):
    """A type name that does not name an importable interface, or values that do not fit it."""


def interface_class(type_name: str, kind: str = "msg"):
    """The generated class of ``type_name`` (``pkg/kind/Name``, or ``pkg/Name`` meaning ``kind``)."""
    parts = type_name.strip("/").split("/")
    if len(parts) == 2:
        parts = [parts[0], kind, parts[1]]
    if len(parts) != 3 or parts[1] != kind or not all(parts):
        raise InterfaceError(f"The passed {_KIND_WORD[kind]} type is invalid")
    try:
        module = importlib.import_module(f"{parts[0]}.{parts[1]}")
        return getattr(module, parts[2])
    except (ImportError, AttributeError, ValueError):
        raise InterfaceError(f"The passed {_KIND_WORD[kind]} type is invalid") from None


_KIND_WORD = {"msg": "message", "srv": "service", "action": "action"}


def is_message(value: Any) -> bool:
    return hasattr(type(value), "get_fields_and_field_types") and hasattr(value, "__slots__")


# -- message -> YAML ---------------------------------------------------------------------------------
def message_to_ordereddict(msg: Any, truncate_length: int | None = None, no_arr: bool = False,
                           no_str: bool = False) -> OrderedDict:
    out: OrderedDict = OrderedDict()
    for name in type(msg).get_fields_and_field_types():
        value = getattr(msg, name)
        if no_str and isinstance(value, str):
            continue
        if no_arr and isinstance(value, (list, tuple, array.array, bytes)) or (no_arr and _is_ndarray(value)):
            continue
        out[name] = _convert(value, truncate_length, no_arr, no_str)
    return out


def _is_ndarray(value: Any) -> bool:
    return type(value).__module__ == "numpy" and type(value).__name__ == "ndarray"


def _convert(value: Any, truncate: int | None, no_arr: bool, no_str: bool) -> Any:
    if is_message(value):
        return message_to_ordereddict(value, truncate, no_arr, no_str)
    if isinstance(value, str):
        return value[:truncate] + "..." if truncate is not None and len(value) > truncate else value
    if isinstance(value, (array.array, bytes)) or _is_ndarray(value):
        value = list(value.tolist() if hasattr(value, "tolist") else value)
    if isinstance(value, (list, tuple)):
        items = [_convert(v, truncate, no_arr, no_str) for v in value]
        if truncate is not None and len(items) > truncate:
            items = items[:truncate] + ["..."]
        return items
    if type(value).__module__ == "numpy":  # a numpy scalar from a fixed-size array
        return value.item()
    return value


class _Dumper(yaml.SafeDumper):
    pass


_Dumper.add_representer(OrderedDict, lambda dumper, data: dumper.represent_mapping(
    "tag:yaml.org,2002:map", data.items()))
_Dumper.add_representer(bytes, lambda dumper, data: dumper.represent_list(list(data)))


def message_to_yaml(msg: Any, truncate_length: int | None = None, no_arr: bool = False, no_str: bool = False,
                    flow_style: bool = False) -> str:
    """The YAML text ``ros2 topic echo`` prints for ``msg`` (without the ``---`` separator)."""
    return yaml.dump(message_to_ordereddict(msg, truncate_length, no_arr, no_str), Dumper=_Dumper,
                     allow_unicode=True, width=sys.maxsize, default_flow_style=flow_style)


# -- YAML -> message ---------------------------------------------------------------------------------
def parse_values(text: str) -> dict:
    """The YAML mapping of a command line's values argument ('' or '{}': no fields)."""
    try:
        values = yaml.safe_load(text) if text.strip() else {}
    except yaml.YAMLError as exc:
        raise InterfaceError(f"the values are not valid YAML: {' '.join(str(exc).split())}") from None
    if values is None:
        return {}
    if not isinstance(values, dict):
        raise InterfaceError("The passed value needs to be a dictionary in YAML format")
    return values


def set_message_fields(msg: Any, values: dict, now: Callable[[], Any] | None = None) -> None:
    """Fill ``msg`` from ``values`` (a mapping of field names). ``now()`` gives the Time used for
    ``now`` / ``auto`` values; without it they are an error."""
    fields = list(type(msg).get_fields_and_field_types())
    slot_types = dict(zip(fields, type(msg).SLOT_TYPES))
    for name, value in values.items():
        if name not in slot_types:
            raise InterfaceError(f"{type(msg).__name__} has no field '{name}' (fields: {', '.join(fields)})")
        try:
            setattr(msg, name, _value_for(getattr(msg, name), slot_types[name], value, now))
        except InterfaceError as exc:
            raise InterfaceError(f"field '{name}': {exc}") from None
        except (AssertionError, TypeError, ValueError) as exc:
            raise InterfaceError(f"field '{name}': {value!r} does not fit ({exc or 'wrong type'})") from None


def _namespaced_class(slot_type):
    return getattr(importlib.import_module(".".join(slot_type.namespaces)), slot_type.name)


def _value_for(current: Any, slot_type, value: Any, now) -> Any:
    from rosidl_parser import definition as d

    if isinstance(slot_type, d.NamespacedType):
        full = "/".join(slot_type.namespaces + [slot_type.name])
        if value in ("now", "auto") and full in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header"):
            if now is None:
                raise InterfaceError(f"'{value}' is only understood when publishing")
            if full == "builtin_interfaces/msg/Time":
                return now()
            header = _namespaced_class(slot_type)()
            header.stamp = now()
            return header
        if not isinstance(value, dict):
            raise InterfaceError(f"a {full} field needs a mapping of its fields, got {value!r}")
        sub = _namespaced_class(slot_type)()
        set_message_fields(sub, value, now)
        return sub
    if isinstance(slot_type, d.AbstractNestedType):
        if not isinstance(value, (list, tuple)):
            raise InterfaceError(f"an array field needs a list, got {value!r}")
        element = slot_type.value_type
        items = [_value_for(None, element, v, now) for v in value]
        if isinstance(current, array.array):
            return array.array(current.typecode, items)
        if _is_ndarray(current):
            import numpy as np

            return np.array(items, dtype=current.dtype)
        if isinstance(current, bytes):
            return bytes(items)
        return items
    if isinstance(slot_type, d.BasicType):
        if slot_type.typename in _FLOAT_TYPES:
            return float(value)
        if slot_type.typename == "boolean":
            if not isinstance(value, bool):
                raise InterfaceError(f"a boolean field needs true or false, got {value!r}")
            return value
        if slot_type.typename == "octet":
            return bytes([int(value)]) if isinstance(value, int) else bytes(value)
        if slot_type.typename in _INT_TYPES:
            if isinstance(value, bool) or not isinstance(value, int):
                raise InterfaceError(f"an integer field needs an integer, got {value!r}")
            return value
    if isinstance(slot_type, (d.AbstractString, d.AbstractWString)):
        if isinstance(value, (dict, list)):
            raise InterfaceError(f"a string field needs text, got {value!r}")
        return str(value)
    return value
