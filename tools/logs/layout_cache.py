"""The run log's layouts (:class:`~swerve.tools.logs.bag.LogLayouts`) kept on disk.

Finding them (:func:`~swerve.tools.logs.bag.probe_layouts`) imports rosbags' type system,
builds the log's type store and has rosbags generate and run the serialisers of every topic's
probes: ~60–100 ms of CPU before a logged run's first cycle. They are a pure function of the
joint names, the message definitions and the code, so :class:`LayoutCache` keeps them in one
file per input (:class:`core.value_cache.ValueCache`: JSON text, a checksum, atomic writes),
named by a SHA-256 of (:func:`layouts_key`) the joint names, the topics and their types,
``message_types.yaml``, the source of the modules that probe and use them (``bag.py``,
``messages.py``, ``record.py``, ``typestore.py``, this one) and the source of rosbags' type
system and CDR serialisers (``rosbags/typesys/*.py``, ``rosbags/serde/*.py``,
``rosbags/interfaces/*.py``): another rosbags version or edited code is a different file.

A hit gives the same templates, schemas and string layout as probing, so the log's bytes are the
same (``tests/tools/logs/test_layout_cache.py``). A file that cannot be read, is damaged or does
not hold every topic's layout is probed and written again; a folder that cannot be written
leaves the layouts unkept.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import json
import os
import struct
from pathlib import Path
from typing import Sequence

from swerve.core.value_cache import ValueCache

from . import bag, messages, record
from .bag import DEFAULT_WHEELS, TOPICS, LogLayouts, joint_names, probe_layouts

#: The first bytes of every cache file; bumped when the layout of its data changes.
LAYOUT = b"swerve run-log layouts 1\n"
#: The folders of rosbags whose modules make the layouts (type store, CDR serialisers, schemas).
ROSBAGS_PARTS = ("typesys", "serde", "interfaces")


def _update(digest, name: str, data: bytes) -> None:
    digest.update(struct.pack("<Q", len(name)) + name.encode() + struct.pack("<Q", len(data)) + data)


@functools.cache
def _code_digest() -> bytes:
    """SHA-256 of the message definitions, swerve's log modules and rosbags' type system."""
    digest = hashlib.sha256(LAYOUT)
    here = Path(bag.__file__).parent
    for path in (Path(bag.__file__), Path(messages.__file__), Path(record.__file__), here / "typestore.py",
                 Path(__file__), here / "message_types.yaml"):
        _update(digest, path.name, path.read_bytes())
    spec = importlib.util.find_spec("rosbags")
    for root in (spec.submodule_search_locations if spec is not None else ()):
        for part in ROSBAGS_PARTS:
            for path in sorted((Path(root) / part).glob("*.py")):
                _update(digest, f"rosbags/{part}/{path.name}", path.read_bytes())
    return digest.digest()


def layouts_key(wheels: Sequence[str] = DEFAULT_WHEELS) -> str:
    """Hex SHA-256 of everything :func:`~swerve.tools.logs.bag.probe_layouts` gives for
    ``wheels`` depends on (module notes)."""
    digest = hashlib.sha256(_code_digest())
    _update(digest, "inputs", json.dumps([joint_names(wheels), sorted(TOPICS.items())]).encode())
    return digest.hexdigest()


class LayoutCache(ValueCache):
    """:func:`~swerve.tools.logs.bag.probe_layouts` with its results kept in ``folder`` (module
    notes); :attr:`hits` and :attr:`misses` count its answers."""

    def __init__(self, folder: str | os.PathLike):
        super().__init__(folder, "runlog-layouts", LAYOUT, suffix=".bin")

    def layouts(self, wheels: Sequence[str] = DEFAULT_WHEELS) -> LogLayouts:
        """The :class:`~swerve.tools.logs.bag.LogLayouts` of ``wheels``: from the cache when it
        holds them, else probed and stored."""
        data, _ = self.payload(
            layouts_key(wheels), lambda: json.dumps(probe_layouts(wheels).as_data()).encode())
        try:
            return LogLayouts.from_data(json.loads(data))
        except (ValueError, KeyError, TypeError, AttributeError):   # checksummed: another writer's layout
            return probe_layouts(wheels)
