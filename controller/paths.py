"""Smooth planar paths ``t -> (x(t), y(t))`` with derivatives up to the third.

Every path has ``derivatives(t) -> ndarray shape (4, 2, len(t))``: position (m), velocity
(m/s), acceleration (m/s^2) and jerk (m/s^3) at the times ``t`` (s), and ``t_end_s``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swerve.controller.errors import ControllerError


@dataclass(frozen=True)
class LinePath:
    """Straight line ``p(t) = start + velocity * t`` (the paper's (61): start 0, velocity 1/20)."""

    start_m: tuple[float, float] = (0.0, 0.0)
    velocity_mps: tuple[float, float] = (0.05, 0.05)
    t_end_s: float = 40.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.zeros((4, 2, t.size))
        v = np.asarray(self.velocity_mps, dtype=float)
        out[0] = np.asarray(self.start_m, dtype=float)[:, None] + v[:, None] * t
        out[1] = v[:, None]
        return out


@dataclass(frozen=True)
class CirclePath:
    """The paper's circle (64): ``x = R sin(w t)``, ``y = R (1 - cos(w t))``, ``w = 2 pi / T``."""

    radius_m: float = 1.0
    period_s: float = 56.0
    t_end_s: float = 56.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        R, w = self.radius_m, 2 * np.pi / self.period_s
        s, c = np.sin(w * t), np.cos(w * t)
        return np.array([[R * s, R * (1 - c)],
                         [R * w * c, R * w * s],
                         [-R * w ** 2 * s, R * w ** 2 * c],
                         [-R * w ** 3 * c, -R * w ** 3 * s]])


@dataclass(frozen=True)
class CurvilinearPath:
    """The paper's curvilinear path (67), ``w = 2 pi / T``::

        x = cos(w t)/2 + sin(2 w t)/2 - 1/2,    y = cos(2 w t)/2 + sin(w t)/2 - offset
    """

    offset_m: float = 0.6
    period_s: float = 140.0
    t_end_s: float = 140.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        w = 2 * np.pi / self.period_s
        s1, c1 = np.sin(w * t), np.cos(w * t)
        s2, c2 = np.sin(2 * w * t), np.cos(2 * w * t)
        return np.array([
            [0.5 * c1 + 0.5 * s2 - 0.5, 0.5 * c2 + 0.5 * s1 - self.offset_m],
            [w * (-0.5 * s1 + c2), w * (-s2 + 0.5 * c1)],
            [w ** 2 * (-0.5 * c1 - 2 * s2), w ** 2 * (-2 * c2 - 0.5 * s1)],
            [w ** 3 * (0.5 * s1 - 4 * c2), w ** 3 * (4 * s2 - 0.5 * c1)]])


class SplinePath:
    """A path through ``t, x, y`` samples: quintic smoothing splines (C4, so jerk is smooth).

    Parameters
    ----------
    t_s, x_m, y_m : array_like, shape (n,)
        Samples; ``t_s`` strictly increasing, shifted so that the path starts at t = 0.
    smoothing_m : float
        RMS deviation allowed between spline and samples, m (0 interpolates).
    """

    def __init__(self, t_s, x_m, y_m, smoothing_m: float = 1e-4):
        from scipy.interpolate import UnivariateSpline

        t = np.asarray(t_s, dtype=float)
        t = t - t[0]
        n = t.size
        s = n * smoothing_m ** 2
        self._sx = UnivariateSpline(t, np.asarray(x_m, float), k=5, s=s)
        self._sy = UnivariateSpline(t, np.asarray(y_m, float), k=5, s=s)
        self.t_end_s = float(t[-1])

    def derivatives(self, t):
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.t_end_s)
        return np.array([[self._sx(t, nu), self._sy(t, nu)] for nu in range(4)])


def read_csv_path(path: str | Path, smoothing_m: float = 1e-4) -> SplinePath:
    """Read a ``t,x,y`` CSV file (s, m, m; an optional header line) into a :class:`SplinePath`.

    Raises
    ------
    ControllerError
        Unreadable file, wrong column count, non-numbers, NaN/inf, fewer than 6 rows, or
        times that do not strictly increase.
    """
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ControllerError(f"cannot read path file {path}: {exc}") from exc
    rows = []
    for no, line in enumerate(lines, start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = [f.strip() for f in text.split(",")]
        if len(fields) != 3:
            raise ControllerError(f"{path}:{no}: expected 3 columns t,x,y, got {len(fields)}")
        try:
            vals = [float(f) for f in fields]
        except ValueError:
            if not rows and [f.lower() for f in fields] == ["t", "x", "y"]:
                continue  # header
            raise ControllerError(f"{path}:{no}: not a number in {text!r}") from None
        if not all(np.isfinite(vals)):
            raise ControllerError(f"{path}:{no}: NaN or infinite value in {text!r}")
        rows.append(vals)
    if len(rows) < 6:
        raise ControllerError(f"{path}: need at least 6 samples t,x,y, found {len(rows)}")
    data = np.array(rows)
    dt = np.diff(data[:, 0])
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise ControllerError(f"{path}: time must strictly increase (sample {i + 2}: "
                              f"t = {data[i + 1, 0]} after {data[i, 0]})")
    return SplinePath(data[:, 0], data[:, 1], data[:, 2], smoothing_m)
