"""CSV export of a :class:`~tools.logs.bag.RunLog`: one row per cycle, units in the header."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from swerve.core.atomic import atomic_write

from .record import UNITS

_POSE = (("x", "m"), ("y", "m"), ("theta", "rad"))


def columns(name: str, size: int) -> list[str]:
    """Header cells for one field, e.g. ``est_pose`` -> ``est_pose_x [m]``, ``..._theta [rad]``."""
    if size == 1:
        return [f"{name} [{UNITS.get(name, '')}]"]
    if name.endswith("_pose"):
        return [f"{name}_{c} [{u}]" for c, u in _POSE]
    return [f"{name}_{i + 1} [{UNITS.get(name, '')}]" for i in range(size)]


def export_csv(log, out_path: str | Path) -> Path:
    """Write ``log`` as CSV (``stamp_ns`` first, then the cycle layout); return the path.

    NaN (unknown) is written as ``nan``; integers (cycle, flags, stamp) without a decimal point.
    """
    out_path = Path(out_path)
    names = [("stamp_ns", 1)] + list(log.layout)
    header = [c for n, s in names for c in columns(n, s)]
    blocks = []
    for name, _ in names:
        a = log.fields[name]
        blocks.append(a.reshape(len(log), -1).astype(object if a.dtype.kind == "i" else np.float64))
    table = np.hstack(blocks) if blocks else np.empty((0, 0))
    with atomic_write(out_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for row in table:
            w.writerow([v if isinstance(v, int) else repr(float(v)) for v in row])
    return out_path
