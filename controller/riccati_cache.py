"""Finite-horizon Riccati solutions kept on disk, keyed by everything they are computed from.

:func:`controller.riccati.finite_horizon_lqr` is a pure function of its inputs: the discrete
error system ``Ad``, ``Bd`` (which carry the robot's geometry and limits, the trajectory and its
reference frames), the weights ``Q``, ``R`` and the step ``tau``. It runs in fixed-order Python
(:mod:`core.small_linalg`), ~0.3 s for the 40 s line. :class:`RiccatiCache` stores its result
``(K, P)`` in one file per input (:class:`core.value_cache.ValueCache`: float64 values with a
checksum), named by a SHA-256 of the exact bytes of every input
and of the source of the code that computes it (``riccati.py``, ``core/small_linalg.py``), so
a changed input or an edited recursion is a different file. A file comes back bit for bit (the
arrays are stored as float64), so a run with the cache gives the same gains, and the same log,
as one without.

A file that cannot be read, is damaged, or does not hold what its name says is recomputed and
written again; a cache folder that cannot be written leaves the solve uncached; files are written
atomically.
"""
from __future__ import annotations

import hashlib
import os
import struct
from pathlib import Path

import numpy as np

from swerve.controller import riccati
from swerve.core import small_linalg
from swerve.core.value_cache import ValueCache

#: The first bytes of every cache file; bumped when the layout changes (the arrays stored, their order).
LAYOUT = b"swerve riccati cache 2\n"


def _code_digest() -> bytes:
    """SHA-256 of the source of the recursion and of the arithmetic it runs on."""
    digest = hashlib.sha256(LAYOUT)
    for module in (riccati, small_linalg):
        digest.update(Path(module.__file__).read_bytes())
    return digest.digest()


def riccati_key(Ad, Bd, Q, R, tau: float) -> str:
    """Hex SHA-256 of the inputs of :func:`finite_horizon_lqr` (shapes, float64 bytes, ``tau``)
    and of its code."""
    digest = hashlib.sha256(_code_digest())
    for a in (Ad, Bd, Q, R):
        a = np.ascontiguousarray(a, dtype=np.float64)
        digest.update(struct.pack("<Q", a.ndim) + struct.pack(f"<{a.ndim}Q", *a.shape))
        digest.update(a.astype("<f8", copy=False).tobytes())
    digest.update(struct.pack("<d", float(tau)))
    return digest.hexdigest()


class RiccatiCache(ValueCache):
    """:func:`finite_horizon_lqr` with its results kept in ``folder`` (see the module notes).

    ``solve`` has the signature of :func:`finite_horizon_lqr`, so it can be passed wherever the
    solver is (``synthesize(..., lqr=RiccatiCache(folder).solve)``). :attr:`hits` and
    :attr:`misses` count its answers.
    """

    def __init__(self, folder: str | os.PathLike):
        super().__init__(folder, "riccati", LAYOUT)

    def solve(self, Ad, Bd, Q, R, tau: float, progress: bool = False):
        """``(K (N, m, n), P (N + 1, n, n))`` of :func:`finite_horizon_lqr` for these inputs, from
        the cache when it holds them, else computed and stored."""
        n_steps, n, m = np.shape(Bd)
        k_size = n_steps * m * n

        def compute():
            K, P = riccati.finite_horizon_lqr(Ad, Bd, Q, R, tau, progress=progress)
            return np.concatenate((np.ravel(K), np.ravel(P)))

        flat = self.values(riccati_key(Ad, Bd, Q, R, tau), k_size + (n_steps + 1) * n * n, compute)
        return flat[:k_size].reshape(n_steps, m, n), flat[k_size:].reshape(n_steps + 1, n, n)
