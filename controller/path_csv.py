"""Read a trajectory CSV file of drawn samples, checking every bound before any fitting.

The format and its limits are described in ``docs/trajectories.md``. The file's size is checked
before it is opened; rows are then read one at a time, and each row is checked as it arrives
(columns, numbers, finite values within the workspace, strictly increasing time, the duration
cap, speed and centripetal acceleration over short windows against the robot's limits), so a bad file is
refused at its first bad row, in time bounded by the row cap, whatever its length.
"""
from __future__ import annotations

import math
import os
from array import array
from collections import deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swerve.controller.errors import ControllerError
from swerve.controller.kinematics import Geometry, Limits

#: Most sample rows a trajectory CSV file may hold (the gain schedule's cap of 200,000 steps:
#: a path has no more samples than the steps that track it would need at 1 ms).
MAX_ROWS = 200_000
#: Most bytes per row on average: the file-size cap is ``MAX_ROWS * MAX_ROW_BYTES`` (25.6 MB),
#: checked before the file is read.
MAX_ROW_BYTES = 128
MAX_FILE_BYTES = MAX_ROWS * MAX_ROW_BYTES
#: Longest path: this many steps of the robot's loop (3,200 s, 53 minutes, at 16 ms).
MAX_STEPS = 200_000
#: Largest |x|, |y| of a sample, m (the robot covers 416 m in 53 minutes at 0.13 m/s).
WORKSPACE_M = 1000.0
#: Speed is measured as the chord over at least this time, s, ...
SPEED_WINDOW_S = 0.2
#: ... and may exceed the wheel-speed limit by the drawing noise it allows (±1 mm at both ends
#: of a window), m/s. The fitted reference's wheel speed is then checked exactly.
SPEED_NOISE_MPS = 2e-3 / SPEED_WINDOW_S
#: Turning is measured from chords at least this long, m, each end uncertain by the drawing
#: noise (±1 mm).
CHORD_MIN_M = 5e-3
CHORD_NOISE_M = 1e-3
#: Fewest samples a path needs.
MIN_ROWS = 6


@dataclass(frozen=True)
class PathSamples:
    """What a trajectory CSV file holds: samples ``t_s``, ``x_m``, ``y_m`` (n,), the travel
    ``direction`` (+1 forwards, -1 reverse), and an optional ``start`` state (5,) or pose (3,)."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    direction: int = 1
    start: tuple | None = None


class _Reader:
    """Checks of one file's rows as they arrive: speed and turning over windows of
    :data:`SPEED_WINDOW_S`.

    With the body along the path and symmetric steering ``delta``, the wheels run at
    ``v1 = V / cos(delta)`` and the body turns at ``omega = V kappa = (a / r^2) v1 sin(delta)``
    (model (1)-(3)), so ``v1^2 = V^2 + (q omega)^2`` with ``q = r^2 / a``: the wheel-speed limit
    bounds the path's speed and its centripetal acceleration ``V omega`` together.
    """

    def __init__(self, path, limits: Limits, geom: Geometry):
        self.path = path
        self.v_max = limits.v1_max_mps + SPEED_NOISE_MPS
        self.v1_max = limits.v1_max_mps
        self.q = geom.r2_m2 / geom.a_m
        self.win: deque = deque()       # (t, x, y) of the last SPEED_WINDOW_S
        self.chords: deque = deque()    # (t, heading of the chord over the window before t)

    def fail(self, no, text):
        raise ControllerError(f"{self.path}:{no}: {text}", file=str(self.path), line=no)

    def row(self, no, t, x, y):
        win = self.win
        if win and not t > win[-1][0]:
            self.fail(no, f"time must strictly increase (t = {t:g} s after {win[-1][0]:g} s)")
        win.append((t, x, y))
        while len(win) > 2 and t - win[1][0] >= SPEED_WINDOW_S:
            win.popleft()
        t0, x0, y0 = win[0]
        if t - t0 < SPEED_WINDOW_S:
            return
        chord = math.hypot(x - x0, y - y0)
        v = chord / (t - t0)
        if v > self.v_max:
            self.fail(no, f"the path needs wheel speed {v:.3g} m/s at t = {t:g} s (chord over "
                          f"{t - t0:.3g} s), above the limit v1_max = {self.v1_max:g} m/s of the "
                          "robot file: slow the path down")
        if chord < CHORD_MIN_M:
            self.chords.clear()
            return
        heading = math.atan2(y - y0, x - x0)
        ch = self.chords
        ch.append((t, heading))
        while len(ch) > 2 and t - ch[1][0] >= SPEED_WINDOW_S:
            ch.popleft()
        ta, ha = ch[0]
        if t - ta < SPEED_WINDOW_S:
            return
        omega = abs((heading - ha + math.pi) % (2 * math.pi) - math.pi) / (t - ta)
        omega = max(omega - 2 * CHORD_NOISE_M / chord / (t - ta), 0.0)
        v1 = math.hypot(v, self.q * omega)
        if v1 > self.v_max:
            self.fail(no, f"the path turns at {omega:.3g} rad/s at t = {t:g} s while moving at "
                          f"{v:.3g} m/s (centripetal acceleration {v * omega:.3g} m/s^2): the "
                          f"wheels would need {v1:.3g} m/s, above the limit v1_max = "
                          f"{self.v1_max:g} m/s of the robot file")


def _start_line(path, no, val):
    try:
        start = tuple(float(v) for v in val.split(","))
    except ValueError:
        start = ()
    if len(start) not in (3, 5) or not all(map(math.isfinite, start)):
        raise ControllerError(f"{path}:{no}: '# start = x, y, theta[, delta1, delta2]' needs 3 or "
                              f"5 numbers (m, rad), got {val!r}", file=str(path), line=no)
    return start


def read_csv_samples(path: str | Path, limits: Limits = Limits(), geom: Geometry = Geometry(),
                     tau_s: float = 0.016) -> PathSamples:
    """Read and check a trajectory CSV file (format: ``docs/trajectories.md``).

    Parameters
    ----------
    path : the file.
    limits, geom : the robot's limits and wheel layout: the wheel-speed limit bounds the path's
        speed and its centripetal acceleration (see :class:`_Reader`).
    tau_s : the robot loop's period, s (the duration cap is 200,000 of them).

    Returns
    -------
    PathSamples
        Arrays of shape (n,), ``MIN_ROWS <= n <= MAX_ROWS``.

    Raises
    ------
    ControllerError
        One line naming the file, the row and the bound: a file over :data:`MAX_FILE_BYTES`,
        more than :data:`MAX_ROWS` rows, wrong columns, non-numbers, NaN/inf, a coordinate
        beyond :data:`WORKSPACE_M`, times that do not strictly increase or span more than
        :data:`MAX_STEPS` steps, a speed or turn the robot's wheels cannot reach, a bad ``# start``
        line, a change of direction, or fewer than :data:`MIN_ROWS` samples.
    """
    try:
        size = os.stat(path).st_size
    except OSError as exc:
        raise ControllerError(f"cannot read path file {path}: {exc}", file=str(path)) from exc
    if size > MAX_FILE_BYTES:
        raise ControllerError(f"{path}: {size} bytes, more than the {MAX_FILE_BYTES} a trajectory "
                              f"file may have ({MAX_ROWS} rows of {MAX_ROW_BYTES} bytes)",
                              file=str(path))
    check = _Reader(path, limits, geom)
    ts, xs, ys = array("d"), array("d"), array("d")
    start, ncol, rev0 = None, None, None
    try:
        with open(path, encoding="utf-8") as fh:
            for no, line in enumerate(fh, start=1):
                text = line.strip()
                if text.startswith("#"):
                    key, _, val = text[1:].partition("=")
                    if key.strip().lower() == "start":
                        start = _start_line(path, no, val)
                    continue
                if not text:
                    continue
                fields = [f.strip() for f in text.split(",")]
                if ncol is None and not ts and [f.lower() for f in fields] in (
                        ["t", "x", "y"], ["t", "x", "y", "reverse"]):
                    ncol = len(fields)
                    continue
                if len(fields) not in (3, 4) or (ncol is not None and len(fields) != ncol):
                    check.fail(no, f"expected columns t,x,y[,reverse], got {len(fields)}")
                if len(ts) >= MAX_ROWS:
                    check.fail(no, f"more than {MAX_ROWS} sample rows, the most a trajectory "
                                   "file may have")
                try:
                    vals = [float(f) for f in fields]
                except ValueError:
                    check.fail(no, f"not a number in {text[:80]!r}")
                if not all(map(math.isfinite, vals)):
                    check.fail(no, f"NaN or infinite value in {text[:80]!r}")
                t, x, y = vals[:3]
                if abs(x) > WORKSPACE_M or abs(y) > WORKSPACE_M:
                    check.fail(no, f"x, y = {x:g}, {y:g} m is beyond the workspace (|x|, |y| <= "
                                   f"{WORKSPACE_M:g} m)")
                if ts and t - ts[0] > MAX_STEPS * tau_s:
                    check.fail(no, f"t = {t:g} s is more than {MAX_STEPS * tau_s:g} s after the "
                                   f"first sample ({MAX_STEPS} steps of {tau_s * 1e3:g} ms, the "
                                   "most a gain schedule may hold)")
                rev = vals[3] if len(vals) == 4 else 0.0
                if rev not in (0.0, 1.0):
                    check.fail(no, f"reverse must be 0 or 1, got {fields[3]!r}")
                if rev0 is None:
                    rev0 = rev
                elif rev != rev0:
                    check.fail(no, f"the direction changes (reverse {int(rev0)} -> {int(rev)}); "
                                   "that needs a stop, which the tracking law cannot pass: put "
                                   "each direction in its own file")
                check.row(no, t, x, y)
                ncol = len(vals)
                ts.append(t)
                xs.append(x)
                ys.append(y)
    except (OSError, UnicodeDecodeError) as exc:
        raise ControllerError(f"cannot read path file {path}: {exc}", file=str(path)) from exc
    if len(ts) < MIN_ROWS:
        raise ControllerError(f"{path}: need at least {MIN_ROWS} samples t,x,y, found {len(ts)}",
                              file=str(path))
    return PathSamples(np.frombuffer(ts), np.frombuffer(xs), np.frombuffer(ys),
                       -1 if rev0 else 1, start)
