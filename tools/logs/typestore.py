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
    for name, (_, fields) in out.items():
        for f, desc in fields:
            inner = desc[1][0] if desc[0] in (Nodetype.ARRAY, Nodetype.SEQUENCE) else desc
            if inner[0] == Nodetype.NAME and inner[1] not in out:
                root.section(name).fail(f"field {f} names {inner[1]}, which the file does not define", f)
    return out


@functools.cache
def log_typestore() -> Typestore:
    """The type store of the run log's messages (built once per process)."""
    store = Typestore()
    store.register(message_definitions())
    return store
