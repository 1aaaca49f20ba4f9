"""One control cycle as logged: :class:`CycleRecord` and its flat float64 layout.

Every quantity is SI and float64; a value that was not measured or does not apply is NaN,
never 0. The flat layout (:data:`CYCLE_FIELDS`) is what ``/swerve/cycle`` carries, so a log
can be turned back into records without loss; ``stamp_ns`` travels as the message time instead
(an int64 nanosecond count does not fit a float64 exactly).
"""
from __future__ import annotations

import enum
import itertools
from dataclasses import dataclass, field, fields

import numpy as np

#: Layout version written into every log's metadata (``cycle_layout_version``).
LAYOUT_VERSION = 1


class CycleFlag(enum.IntFlag):
    """Bits of :attr:`CycleRecord.flags`."""

    OVERRUN = 1   #: the cycle took longer than its period
    STALE = 2     #: a measurement was not refreshed this cycle (previous value kept)


def _nan(n: int):
    return field(default_factory=lambda: np.full(n, np.nan))


@dataclass
class CycleRecord:
    """Everything the tracking loop knows at the end of one cycle.

    Arrays are float64 with the shapes shown; wheel order is the one in ``configs/robot.yaml``
    (front_left, rear_left, rear_right, front_right); poses are ``(x_m, y_m, theta_rad)``.
    """

    t_s: float                       #: trajectory time, s
    stamp_ns: int                    #: clock time of the cycle, ns (bag message time); use
    #: ``time.time_ns()`` so viewers show the real date (a monotonic base also works)
    cycle: int                       #: cycle index, 0-based
    period_s: float = np.nan         #: measured loop period, s
    cmd_drive_radps: np.ndarray = _nan(4)   #: (4,) commanded wheel speeds, rad/s
    cmd_steer_rad: np.ndarray = _nan(4)     #: (4,) commanded steering angles, rad
    cmd_v1_mps: float = np.nan               #: commanded linear velocity v1, m/s
    cmd_omega_radps: np.ndarray = _nan(2)   #: (2,) commanded steering rates (front, rear), rad/s
    meas_drive_radps: np.ndarray = _nan(4)  #: (4,) measured wheel speeds, rad/s
    meas_steer_rad: np.ndarray = _nan(4)    #: (4,) measured steering angles, rad
    meas_current_a: np.ndarray = _nan(8)    #: (8,) present current by servo ID 1..8, A
    est_pose: np.ndarray = _nan(3)          #: (3,) odometry estimate
    ref_pose: np.ndarray = _nan(3)          #: (3,) reference pose
    ref_delta: np.ndarray = _nan(2)         #: (2,) reference steering angles (front, rear), rad
    true_pose: np.ndarray = _nan(3)         #: (3,) emulator ground truth, NaN on hardware
    sim_pose: np.ndarray = _nan(3)          #: (3,) open-loop simulation overlay, or NaN
    flags: int = 0                           #: :class:`CycleFlag` bits

    def __post_init__(self) -> None:
        values = self.__dict__
        for name, shape in _ARRAY_SHAPES:
            arr = np.asarray(values[name], dtype=np.float64)
            if arr.shape != shape:
                raise ValueError(f"CycleRecord.{name} must have shape {shape}, got {arr.shape}")
            values[name] = arr


def _layout() -> tuple[tuple[str, int], ...]:
    out = []
    for f in fields(CycleRecord):
        if f.name == "stamp_ns":
            continue
        default = f.default_factory() if callable(f.default_factory) else None
        out.append((f.name, 1 if default is None else default.shape[0]))
    return tuple(out)


#: ``(name, size)`` of each field in the order of the flat ``/swerve/cycle`` array.
CYCLE_FIELDS: tuple[tuple[str, int], ...] = _layout()
#: Length of the flat array.
CYCLE_SIZE = sum(size for _, size in CYCLE_FIELDS)
#: ``(name, shape)`` of the array fields.
_ARRAY_SHAPES = tuple((name, (size,)) for name, size in CYCLE_FIELDS if size > 1)
#: ``name -> slice`` of each field in the flat array.
FLAT_SLICES = {name: slice(start, start + size) for (name, size), start in
               zip(CYCLE_FIELDS, itertools.accumulate((size for _, size in CYCLE_FIELDS), initial=0))}
#: Integer-valued fields (exact in float64 below 2**53).
INT_FIELDS = ("cycle", "flags")

#: Unit of each field, for CSV headers and plot labels.
UNITS = {
    "t_s": "s", "stamp_ns": "ns", "cycle": "1", "period_s": "s",
    "cmd_drive_radps": "rad/s", "cmd_steer_rad": "rad", "cmd_v1_mps": "m/s",
    "cmd_omega_radps": "rad/s", "meas_drive_radps": "rad/s", "meas_steer_rad": "rad",
    "meas_current_a": "A", "est_pose": "m,m,rad", "ref_pose": "m,m,rad", "ref_delta": "rad",
    "true_pose": "m,m,rad", "sim_pose": "m,m,rad", "flags": "bits",
}


def flatten(record: CycleRecord) -> list[float]:
    """``record`` (without ``stamp_ns``) as ``CYCLE_SIZE`` floats in the order of :data:`CYCLE_FIELDS`."""
    out: list[float] = []
    values = record.__dict__
    for name, size in CYCLE_FIELDS:
        value = values[name]
        if size == 1:
            out.append(float(value))
        else:
            out += value.tolist()
    return out


def pack(record: CycleRecord) -> np.ndarray:
    """Flatten ``record`` (without ``stamp_ns``) into a ``(CYCLE_SIZE,)`` float64 array."""
    return np.array(flatten(record), dtype=np.float64)


def unpack(rows: np.ndarray, layout=CYCLE_FIELDS) -> dict[str, np.ndarray]:
    """Split ``(n, size)`` flat rows into per-field arrays: ``(n,)`` or ``(n, k)``.

    ``layout`` is the ``(name, size)`` list stored in the log, so older logs keep decoding.
    """
    rows = np.atleast_2d(np.asarray(rows, dtype=np.float64))
    total = sum(size for _, size in layout)
    if rows.shape[1] != total:
        raise ValueError(f"cycle rows have {rows.shape[1]} values, layout expects {total}")
    out: dict[str, np.ndarray] = {}
    i = 0
    for name, size in layout:
        block = rows[:, i:i + size]
        out[name] = block[:, 0].copy() if size == 1 else block.copy()
        if name in INT_FIELDS:
            out[name] = out[name].astype(np.int64)
        i += size
    return out
