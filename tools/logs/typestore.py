"""The rosbags type store of a run log: only the message types the log writes.

rosbags' ROS 2 stores (``get_typestore(Stores.ROS2_JAZZY)``) import the message classes of every
distribution the store derives from, ~0.1 s; the log needs 19 types. :func:`log_typestore`
registers those from ``message_types.yaml`` (the Jazzy definitions, read by the one loader) in an
empty store: a few ms, and the same field definitions, MCAP schema text and RIHS01 hashes as the
Jazzy store (``tests/tools/logs/test_typestore.py``), so the bytes written are the same.
"""
from __future__ import annotations

import functools
import re
from pathlib import Path

from rosbags.interfaces import Nodetype
from rosbags.typesys.store import Typestore

from swerve.configs.loader import read_yaml

#: The definitions (see the file's header).
TYPES_FILE = Path(__file__).with_name("message_types.yaml")
#: ROS 2 base types a definition may use (the ones the log's types need).
BASE_TYPES = frozenset(("int32", "uint32", "float64", "string"))
_MESSAGE = re.compile(r"[a-z][a-z0-9_]*/msg/[A-Z][A-Za-z0-9]*")
_ARRAY = re.compile(r"(.+)\[(\d*)\]")


def _field_type(text: str, where) -> tuple:
    """rosbags' description ``(Nodetype, ...)`` of one field type written as in the data file."""
    array = _ARRAY.fullmatch(text)
    if array:
        element, n = array.groups()
        kind = Nodetype.ARRAY if n else Nodetype.SEQUENCE
        return kind, (_field_type(element, where), int(n or 0))
    if text in BASE_TYPES:
        return Nodetype.BASE, (text, 0)
    if _MESSAGE.fullmatch(text):
        return Nodetype.NAME, text
    where.fail(f"unknown field type {text!r} (base types: {', '.join(sorted(BASE_TYPES))}; "
               "or pkg/msg/Name, T[], T[n])")
    raise AssertionError("unreachable")


def message_definitions(path: str | Path = TYPES_FILE) -> dict[str, tuple[list, list]]:
    """``{type name: ([], [(field, description), ...])}``: rosbags' ``Typesdict`` of the file."""
    root = read_yaml(path, what="message types").root()
    out = {}
    for name in root.keys():
        if not _MESSAGE.fullmatch(name):
            root.fail(f"{name!r} is not a message type name (pkg/msg/Name)", name)
        sec = root.section(name)
        out[name] = ([], [(f, _field_type(sec.string(f), sec)) for f in sec.keys()])
    nested = {name: [(f, _nested_name(desc)) for f, desc in fields if _nested_name(desc)]
              for name, (_, fields) in out.items()}
    for name, fields in nested.items():
        for f, inner in fields:
            if inner not in out:
                root.section(name).fail(f"field {f} names {inner}, which the file does not define", f)
    for name in nested:
        _check_acyclic(name, nested, (), root)
    return out


def _nested_name(desc: tuple) -> str | None:
    """The message type a field description names (itself or as its elements), else None."""
    inner = desc[1][0] if desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE) else desc
    return inner[1] if inner[0] == Nodetype.NAME else None


def _check_acyclic(name: str, nested: dict, path: tuple, root) -> None:
    """Refuse a type that contains itself (its size would be infinite)."""
    if name in path:
        root.section(path[0]).fail(f"contains itself: {' -> '.join(path + (name,))}")
    for _, inner in nested[name]:
        _check_acyclic(inner, nested, path + (name,), root)


@functools.cache
def log_typestore() -> Typestore:
    """The type store of the run log's messages (built once per process)."""
    store = Typestore()
    store.register(message_definitions())
    return store
