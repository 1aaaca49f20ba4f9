"""The ideal-model poses of a tracking law (the run log's overlay), kept on disk.

A run with a log writes, next to each cycle, the pose the same law gives on the ideal model
(1)-(5) (:func:`simulated_poses`: :func:`controller.simulate.simulate` from the start state,
~0.07–0.1 s of CPU for the 40 s line, before the first cycle). It is a pure function of the
law and the start state, so :class:`OverlayCache` keeps its result in one file per input
(:class:`core.value_cache.ValueCache`: the poses as float64 bytes, a checksum, atomic writes),
named by a SHA-256 of (:func:`overlay_key`):

- the reference's trajectory, geometry and limits, pickled (the path's parameters decide the
  reference off its grid, where the governor samples it), its frames and the law's governor;
- the exact bytes of the reference's tables (times, states, inputs, frames, chained state and
  inputs), of the gains ``K`` and their frames, and of the start state;
- the source of every module of the controller package and of the arithmetic it runs on
  (``core/small_linalg.py``, ``core/mathmap.py``), so edited code is a different file.

A hit gives the same float64 poses as computing them, so the log and the export hashes are the
same with and without the cache. A law whose trajectory cannot be pickled is simulated each
time. A file that cannot be read, is damaged or does not hold whole poses is computed and
written again; a folder that cannot be written leaves the poses uncached.
"""
from __future__ import annotations

import functools
import hashlib
import os
import pickle
import struct
from pathlib import Path

import numpy as np

from swerve.controller import tracking
from swerve.controller.simulate import simulate
from swerve.controller.tracking import TrackingLaw
from swerve.core import mathmap, small_linalg
from swerve.core.value_cache import ValueCache

#: The first bytes of every cache file; bumped when the layout changes.
LAYOUT = b"swerve overlay cache 1\n"
#: Floats of one pose ``(x_m, y_m, theta_rad)``.
POSE_SIZE = 3


def simulated_poses(law: TrackingLaw, start) -> np.ndarray:
    """Poses ``(n, 3)`` of ``law`` on the ideal model (1)-(5) from the state ``start`` (5,),
    m and rad (:func:`controller.simulate.simulate`); the law is reset afterwards."""
    poses = simulate(law, start).states[:, :POSE_SIZE]
    law.reset()
    return np.ascontiguousarray(poses)


@functools.cache
def _code_digest() -> bytes:
    """SHA-256 of the source of the controller package and of the arithmetic it runs on."""
    digest = hashlib.sha256(LAYOUT)
    files = sorted(Path(tracking.__file__).parent.glob("*.py"))
    for path in files + [Path(small_linalg.__file__), Path(mathmap.__file__)]:
        source = path.read_bytes()
        digest.update(struct.pack("<Q", len(path.name)) + path.name.encode())
        digest.update(struct.pack("<Q", len(source)) + source)
    return digest.digest()


def _array_bytes(a) -> bytes:
    """Shape and little-endian float64 bytes of ``a``."""
    a = np.ascontiguousarray(a, dtype=np.float64)
    return struct.pack(f"<Q{a.ndim}Q", a.ndim, *a.shape) + a.astype("<f8", copy=False).tobytes()


def overlay_key(law: TrackingLaw, start) -> str | None:
    """Hex SHA-256 of everything :func:`simulated_poses` computes from (module notes); None if
    the law's trajectory cannot be pickled (then it is not cached)."""
    ref = law.reference
    try:
        described = pickle.dumps((ref.trajectory, ref.geom, law.limits, ref.frames, bool(law.governor)),
                                 protocol=5)
    except (pickle.PicklingError, TypeError, AttributeError):
        return None
    digest = hashlib.sha256(_code_digest())
    digest.update(struct.pack("<Q", len(described)) + described)
    for a in (ref.times_s, ref.states, ref.inputs, ref.phi_rad, ref.xd, ref.ud,
              law.gains.K, law.gains.phi_rad, [law.gains.tau_s], start):
        digest.update(_array_bytes(a))
    return digest.hexdigest()


class OverlayCache(ValueCache):
    """:func:`simulated_poses` with its results kept in ``folder`` (see the module notes);
    :attr:`hits` and :attr:`misses` count its answers."""

    def __init__(self, folder: str | os.PathLike):
        super().__init__(folder, "overlay", LAYOUT)

    def poses(self, law: TrackingLaw, start) -> np.ndarray:
        """``(n, 3)`` poses of :func:`simulated_poses` for ``law`` and ``start``: from the cache
        when it holds them, else simulated and stored. A new array either way."""
        key = overlay_key(law, start)
        if key is None:
            return simulated_poses(law, start)
        data, _ = self.payload(key, lambda: simulated_poses(law, start).astype("<f8").tobytes())
        if not data or len(data) % (8 * POSE_SIZE):     # checksummed, so only another writer's layout
            return simulated_poses(law, start)
        return np.frombuffer(data, "<f8").astype(np.float64).reshape(-1, POSE_SIZE)
