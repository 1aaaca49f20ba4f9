"""Finite-horizon Riccati solutions kept on disk, keyed by everything they are computed from.

:func:`controller.riccati.finite_horizon_lqr` is a pure function of its inputs: the discrete
error system ``Ad``, ``Bd`` (which carry the robot's geometry and limits, the trajectory and its
reference frames), the weights ``Q``, ``R`` and the step ``tau``. It runs in fixed-order Python
(:mod:`core.small_linalg`), ~0.3 s for the 40 s line. :class:`RiccatiCache` stores its result
``(K, P)`` in one ``.npz`` file per input, named by a SHA-256 of the exact bytes of every input
and of the source of the code that computes it (``riccati.py``, ``core/small_linalg.py``), so
a changed input or an edited recursion is a different file. A file comes back bit for bit (the
arrays are stored as float64), so a run with the cache gives the same gains, and the same log,
as one without.

A file that cannot be read, is damaged, or does not hold what its name says is recomputed and
written again; a cache folder that cannot be written leaves the solve uncached. Files are
written atomically (:func:`core.atomic.write_bytes`), so a crash never leaves half a file.
"""
from __future__ import annotations

import hashlib
import io
import logging
import os
import struct
import zipfile
from pathlib import Path

import numpy as np

from swerve.controller import riccati
from swerve.core import small_linalg
from swerve.core.atomic import OutputError, write_bytes

log = logging.getLogger(__name__)

#: Bumped when the file layout changes (the arrays stored, their names).
LAYOUT = b"swerve riccati cache 1"


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


class RiccatiCache:
    """:func:`finite_horizon_lqr` with its results kept in ``folder`` (see the module notes).

    ``solve`` has the signature of :func:`finite_horizon_lqr`, so it can be passed wherever the
    solver is (``synthesize(..., lqr=RiccatiCache(folder).solve)``). :attr:`hits` and
    :attr:`misses` count its answers.
    """

    def __init__(self, folder: str | os.PathLike):
        self.folder = Path(folder)
        self.hits = 0
        self.misses = 0

    def path_for(self, key: str) -> Path:
        """The file of the input whose :func:`riccati_key` is ``key``."""
        return self.folder / f"riccati-{key}.npz"

    def solve(self, Ad, Bd, Q, R, tau: float, progress: bool = False):
        """``(K, P)`` of :func:`finite_horizon_lqr` for these inputs, from the cache when it
        holds them, else computed and stored."""
        key = riccati_key(Ad, Bd, Q, R, tau)
        path = self.path_for(key)
        n_steps, n, m = np.shape(Bd)
        stored = self._read(path, key, (n_steps, m, n), (n_steps + 1, n, n))
        if stored is not None:
            self.hits += 1
            return stored
        self.misses += 1
        K, P = riccati.finite_horizon_lqr(Ad, Bd, Q, R, tau, progress=progress)
        buf = io.BytesIO()
        np.savez(buf, key=np.array(key), K=K, P=P)
        try:
            write_bytes(path, buf.getvalue())
        except OutputError as exc:       # a read-only or full cache folder: the solve stands
            log.debug("Riccati cache not written: %s", exc)
        return K, P

    @staticmethod
    def _read(path: Path, key: str, k_shape: tuple, p_shape: tuple):
        """``(K, P)`` stored in ``path`` for ``key``, or None (absent, unreadable or damaged)."""
        try:
            with np.load(path, allow_pickle=False) as data:
                if str(data["key"]) != key:
                    return None
                K, P = data["K"], data["P"]
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
            log.debug("Riccati cache file %s ignored: %s", path, exc)
            return None
        if (K.shape != k_shape or P.shape != p_shape or K.dtype != np.float64 or P.dtype != np.float64):
            return None
        return K, P
