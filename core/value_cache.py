"""Results of pure functions kept on disk, one file per input, keyed by the caller.

A caller names each result by a key that covers everything it is computed from (its input bytes
and the source of the code computing it, e.g. a SHA-256), so a changed input or edited code is a
different file and a hit gives the same bits as computing afresh. :class:`ValueCache` stores a
result as one file ``<name>-<key><suffix>`` in its folder: the cache's ``layout`` line, the key,
the result (float64 values, little-endian, :meth:`~ValueCache.values`; or bytes,
:meth:`~ValueCache.payload`), and the first :data:`CHECK_BYTES` bytes of the SHA-256 of all
that. A file that cannot be read, has another length, names another key or fails its checksum is
computed and written again; a folder that cannot be written leaves the results uncached. Files are
written atomically (:func:`swerve.core.atomic.write_bytes`), so a crash never leaves half a file.
Delete the folder to empty it.
"""
from __future__ import annotations

import hashlib
import logging
import os
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from swerve.core.atomic import OutputError, write_bytes

log = logging.getLogger(__name__)

#: Bytes of the SHA-256 of a file's contents that end it (a damaged value is found).
CHECK_BYTES = 8


class ValueCache:
    """Results kept in ``folder`` as ``<name>-<key><suffix>`` files whose contents begin with
    ``layout`` (see the module notes); :attr:`hits` and :attr:`misses` count its answers."""

    def __init__(self, folder: str | os.PathLike, name: str, layout: bytes, suffix: str = ".f8"):
        self.folder = Path(folder)
        self.name = name
        self.layout = layout
        self.suffix = suffix
        self.hits = 0
        self.misses = 0

    def path_for(self, key: str) -> Path:
        """The file of the result named ``key`` (hex)."""
        return self.folder / f"{self.name}-{key}{self.suffix}"

    def values(self, key: str, count: int, compute: Callable[[], Sequence[float]]) -> np.ndarray:
        """The ``count`` float64 values stored for ``key`` (hex), else ``compute()`` (a flat
        sequence of ``count`` floats), stored and returned; a new array either way."""
        stored = self._stored(key)
        if stored is not None and len(stored) == 8 * count:
            self.hits += 1
            return np.frombuffer(stored, "<f8").astype(np.float64)
        self.misses += 1
        values = np.array(compute(), np.float64)
        if values.shape != (count,):
            raise ValueError(f"{key}: computed {values.shape} values, expected {count}")
        self._store(key, values.astype("<f8").tobytes())
        return values

    def payload(self, key: str, compute: Callable[[], bytes]) -> tuple[bytes, bool]:
        """``(the bytes stored for key, True)``, else ``(compute(), False)`` once stored."""
        stored = self._stored(key)
        if stored is not None:
            self.hits += 1
            return stored, True
        self.misses += 1
        data = bytes(compute())
        self._store(key, data)
        return data, False

    def _stored(self, key: str) -> bytes | None:
        """The result in ``key``'s file, or None if it is absent, unreadable or damaged."""
        path = self.path_for(key)
        head = self.layout + bytes.fromhex(key)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None
        except OSError as exc:
            log.debug("cache file %s ignored: %s", path, exc)
            return None
        size = len(data) - CHECK_BYTES
        if (size < len(head) or not data.startswith(head)
                or hashlib.sha256(data[:size]).digest()[:CHECK_BYTES] != data[size:]):
            return None
        return data[len(head):size]

    def _store(self, key: str, result: bytes) -> None:
        """Write ``key``'s file atomically; a read-only or full folder leaves it unwritten."""
        body = self.layout + bytes.fromhex(key) + result
        try:
            write_bytes(self.path_for(key), body + hashlib.sha256(body).digest()[:CHECK_BYTES])
        except OutputError as exc:      # a read-only or full cache folder: the result stands
            log.debug("cache file not written: %s", exc)
