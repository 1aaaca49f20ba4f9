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

The files, their checksums and what happens to a damaged one or an unwritable folder are
:class:`swerve.core.value_cache.ValueCache`'s.
"""
from __future__ import annotations

import functools
import hashlib
import importlib.util
import os
import struct
from pathlib import Path

import numpy as np

from swerve.core.user_cache import user_cache_dir
from swerve.core.value_cache import ValueCache

from .params import BESSEL_NORMS

#: The first bytes of every cache file; bumped when the layout changes.
LAYOUT = b"swerve exact cache 1\n"
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


class ExactCache(ValueCache):
    """The results of :mod:`.exact` kept in ``folder`` as ``exact-<key>.f8`` files
    (:class:`swerve.core.value_cache.ValueCache`)."""

    def __init__(self, folder: str | os.PathLike):
        super().__init__(folder, "exact", LAYOUT)


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
