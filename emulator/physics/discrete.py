"""Zero-order-hold discretisations and Bessel prototypes, computed exactly once and kept on disk.

The physics' coefficients come from :mod:`.exact` (40-digit mpmath: the same bits on every
machine): the ZOH matrices of each motor (driven and coasting) and of the Bessel filters, and the
analogue Bessel prototype. They are pure functions of their inputs, but importing mpmath and
computing a robot's exponentials cost the emulator ~60 ms of CPU at every start.
:class:`ExactCache` keeps each result in one file of ``$XDG_CACHE_HOME/swerve/``
(:func:`swerve.core.user_cache.user_cache_dir`), named by a SHA-256 of the exact bytes of the inputs (shapes, float64 values, step, norm) and of
the code that computes them (the source of :mod:`.exact` and mpmath's ``__init__.py``, which
holds its version). A hit gives the same float64 values, so the physics, the logs and the export
hashes are the same with and without the cache; only a miss imports :mod:`.exact`, and with it
mpmath.

A file holds :data:`LAYOUT`, the 32 bytes of its key, the values as little-endian float64, and
the first bytes of the SHA-256 of all that. One that cannot be read, has another length, names
another key or fails its checksum is recomputed and written again; a folder that cannot be
written leaves the results uncached. Files are written atomically
(:func:`swerve.core.atomic.write_bytes`), so a crash never leaves half a file. Delete the
folder to empty it.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import logging
import os
import struct
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from swerve.core.atomic import OutputError, write_bytes
from swerve.core.user_cache import user_cache_dir

from .params import BESSEL_NORMS

log = logging.getLogger(__name__)

#: The first bytes of every cache file; bumped when the layout changes.
LAYOUT = b"swerve exact cache 1\n"
#: Bytes of the SHA-256 of a file's contents that end it (a damaged value is found).
CHECK_BYTES = 8
#: The source of :mod:`.exact`, part of every key.
EXACT_SOURCE = Path(__file__).with_name("exact.py")


@functools.cache
def _code_digest(source: Path) -> bytes:
    """SHA-256 of :mod:`.exact`'s source and of mpmath's ``__init__.py`` (found, not imported)."""
    digest = hashlib.sha256(LAYOUT + source.read_bytes())
    spec = importlib.util.find_spec("mpmath")
    if spec is not None and spec.origin is not None:
        digest.update(Path(spec.origin).read_bytes())
    return digest.digest()


def _exact():
    """:mod:`.exact`, imported here, when a value must be computed: it imports mpmath, which a
    start-up that finds every value in the cache never loads."""
    from . import exact
    return exact


def exact_key(kind: str, payload: bytes) -> str:
    """Hex SHA-256 of the code (:func:`_code_digest`), the computation's ``kind`` and its
    input bytes ``payload``."""
    return hashlib.sha256(_code_digest(EXACT_SOURCE) + kind.encode() + b"\0" + payload).hexdigest()


class ExactCache:
    """Float64 results of :mod:`.exact` kept in ``folder`` (see the module notes); :attr:`hits`
    and :attr:`misses` count its answers."""

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self.hits = 0
        self.misses = 0

    def values(self, key: str, count: int, compute: Callable[[], Sequence[float]]) -> np.ndarray:
        """The ``count`` float64 values stored for ``key``, else ``compute()`` (a flat sequence
        of ``count`` floats), stored and returned; a new array either way."""
        path = self.folder / f"exact-{key}.f8"
        head = LAYOUT + bytes.fromhex(key)
        size = len(head) + 8 * count
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            data = b""
        except OSError as exc:
            log.debug("exact cache file %s ignored: %s", path, exc)
            data = b""
        if (len(data) == size + CHECK_BYTES and data.startswith(head)
                and hashlib.sha256(data[:size]).digest()[:CHECK_BYTES] == data[size:]):
            self.hits += 1
            return np.frombuffer(data, "<f8", count, len(head)).astype(np.float64)
        self.misses += 1
        values = np.array(compute(), np.float64)
        if values.shape != (count,):
            raise ValueError(f"{key}: computed {values.shape} values, expected {count}")
        body = head + values.astype("<f8").tobytes()
        try:
            write_bytes(path, body + hashlib.sha256(body).digest()[:CHECK_BYTES])
        except OutputError as exc:      # a read-only or full cache folder: the result stands
            log.debug("exact cache file not written: %s", exc)
        return values


def _cache(cache: ExactCache | None) -> ExactCache:
    return cache if cache is not None else ExactCache(user_cache_dir())


def zoh(a, b, dt_s: float, cache: ExactCache | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(Ad (n, n), Bd (n, m))`` of ``dx/dt = A x + B u``
    over ``dt_s`` s, for ``a`` (n, n) and ``b`` (n, m): ``[Ad Bd] = expm([[A B], [0 0]] dt)``
    (:func:`.exact.zoh_rows`), from ``cache`` (default: the user's cache folder)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or b.ndim != 2 or b.shape[0] != a.shape[0]:
        raise ValueError(f"zoh: a must be (n, n) and b (n, m), got {a.shape} and {b.shape}")
    n, m = b.shape
    dt_s = float(dt_s)
    payload = (struct.pack("<QQ", n, m) + a.astype("<f8").tobytes() + b.astype("<f8").tobytes()
               + struct.pack("<d", dt_s))
    values = _cache(cache).values(
        exact_key("zoh", payload), n * (n + m),
        lambda: [v for row in _exact().zoh_rows(a.tolist(), b.tolist(), dt_s) for v in row]).reshape(n, n + m)
    return values[:, :n].copy(), values[:, n:].copy()


def bessel_prototype(cutoff_radps: float, norm: str, cache: ExactCache | None = None) -> tuple[float, float]:
    """``(a1, a0)`` of the 2nd-order analogue Bessel for ``cutoff_radps`` and ``norm``
    (:func:`.exact.bessel_prototype`), from ``cache`` (default: the user's cache folder)."""
    if norm not in BESSEL_NORMS:
        raise ValueError(f"Bessel norm must be 'mag', 'phase' or 'delay', got {norm!r}")
    cutoff_radps = float(cutoff_radps)
    a1, a0 = _cache(cache).values(exact_key("bessel", struct.pack("<d", cutoff_radps) + norm.encode()), 2,
                                  lambda: _exact().bessel_prototype(cutoff_radps, norm)).tolist()
    return a1, a0
