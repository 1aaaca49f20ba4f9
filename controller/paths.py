"""Analytic planar paths ``t -> (x(t), y(t))`` with derivatives up to the third, and samples of drawn primitives.

Every path is a :class:`PlanarPath`: ``derivatives(t) -> ndarray shape (4, 2, len(t))`` gives position
(m), velocity (m/s), acceleration (m/s^2) and jerk (m/s^3) at the times ``t`` (s); ``t_end_s``
is where it ends and ``direction`` how the body faces it. Paths
drawn as samples are fitted by :mod:`controller.path_fit`; :func:`draw_primitives` samples
lines and arcs as a user or CAD tool would. Sines and cosines are :mod:`math`'s, mapped over
the arrays (:mod:`core.mathmap`): NumPy's own loops are picked per CPU and differ in the
last bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar, Protocol

import numpy as np

from swerve.core.mathmap import cos_sin


class PlanarPath(Protocol):
    """What a trajectory's path offers (the analytic paths here, and
    :class:`~swerve.controller.path_fit.FittedPath` for drawn ones)."""

    #: End of the path, s (a trajectory may stop earlier, never later).
    t_end_s: float
    #: +1: the body faces the direction of travel; -1: driven in reverse (v1 < 0). A
    #: trajectory file's ``direction`` key overrides it.
    direction: int

    def derivatives(self, t) -> np.ndarray:
        """Position, velocity, acceleration and jerk at ``t`` (s): shape (4, 2, len(t)), SI."""
        ...


class _AnalyticPath:
    """The paper's paths are driven forwards (a trajectory file may still say ``reverse``)."""

    direction: ClassVar[int] = 1


@dataclass(frozen=True)
class LinePath(_AnalyticPath):
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
class CirclePath(_AnalyticPath):
    """The paper's circle (64): ``x = R sin(w t)``, ``y = R (1 - cos(w t))``, ``w = 2 pi / T``."""

    radius_m: float = 1.0
    period_s: float = 56.0
    t_end_s: float = 56.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        R, w = self.radius_m, 2 * math.pi / self.period_s
        c, s = cos_sin(w * t)
        w2, w3 = w * w, w * w * w
        return np.array([[R * s, R * (1 - c)],
                         [R * w * c, R * w * s],
                         [-R * w2 * s, R * w2 * c],
                         [-R * w3 * c, -R * w3 * s]])


@dataclass(frozen=True)
class CurvilinearPath(_AnalyticPath):
    """The paper's curvilinear path (67), ``w = 2 pi / T``::

        x = cos(w t)/2 + sin(2 w t)/2 - 1/2,    y = cos(2 w t)/2 + sin(w t)/2 - offset
    """

    offset_m: float = 0.6
    period_s: float = 140.0
    t_end_s: float = 140.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        w = 2 * math.pi / self.period_s
        c1, s1 = cos_sin(w * t)
        c2, s2 = cos_sin(2 * w * t)
        w2, w3 = w * w, w * w * w
        return np.array([
            [0.5 * c1 + 0.5 * s2 - 0.5, 0.5 * c2 + 0.5 * s1 - self.offset_m],
            [w * (-0.5 * s1 + c2), w * (-s2 + 0.5 * c1)],
            [w2 * (-0.5 * c1 - 2 * s2), w2 * (-2 * c2 - 0.5 * s1)],
            [w3 * (0.5 * s1 - 4 * c2), w3 * (4 * s2 - 0.5 * c1)]])


def draw_primitives(segments, start=(0.0, 0.0, 0.0), spacing_m: float = 0.01):
    """Sample a path drawn from lines and arcs, as a user or CAD tool would.

    Parameters
    ----------
    segments : sequence of ``("line", length_m)`` and ``("arc", radius_m, turn_rad)``
        (``turn_rad`` > 0 turns left).
    start : ``(x_m, y_m, heading_rad)`` of the first sample.
    spacing_m : distance between samples along the path, m.

    Returns
    -------
    s_m, x_m, y_m, kappa_1pm : ndarrays, shape (n,)
        Arc length, position and drawn curvature of the samples (at a junction the curvature
        of the segment that starts there).
    """
    x, y, th = map(float, start)
    total = sum(seg[1] if seg[0] == "line" else abs(seg[1] * seg[2]) for seg in segments)
    n = int(round(total / spacing_m))
    s_all = np.linspace(0.0, total, n + 1)
    out = np.empty((4, n + 1))
    s0 = 0.0
    for seg in segments:
        length = seg[1] if seg[0] == "line" else abs(seg[1] * seg[2])
        k = 0.0 if seg[0] == "line" else math.copysign(1.0 / seg[1], seg[2])
        sel = (s_all >= s0 - 1e-12) & (s_all <= s0 + length + 1e-12)
        u = s_all[sel] - s0
        if k == 0.0:
            px, py = x + u * math.cos(th), y + u * math.sin(th)
        else:
            cu, su = cos_sin(th + k * u)
            px = x + (su - math.sin(th)) / k
            py = y - (cu - math.cos(th)) / k
        out[:, sel] = [s_all[sel], px, py, np.full(u.size, k)]
        if k == 0.0:
            x, y = x + length * math.cos(th), y + length * math.sin(th)
        else:
            x = x + (math.sin(th + k * length) - math.sin(th)) / k
            y = y - (math.cos(th + k * length) - math.cos(th)) / k
            th += k * length
        s0 += length
    return out[0], out[1], out[2], out[3]


def draw_sines(t_s, terms_x, terms_y):
    """Sample a smooth free-form curve drawn as sums of sines, as a user's sketch tool might.

    Parameters
    ----------
    t_s : array_like, shape (n,)
        Sample times, s.
    terms_x, terms_y : sequences of ``(amplitude_m, angular_rate_radps, phase_rad)``
        ``x(t) = sum a sin(w t + phi)``, likewise ``y``.

    Returns
    -------
    x_m, y_m : ndarrays, shape (n,)
    """
    t = np.asarray(t_s, dtype=float)
    out = []
    for terms in (terms_x, terms_y):
        v = np.zeros_like(t)
        for a, w, ph in terms:
            v = v + a * cos_sin(w * t + ph)[1]
        out.append(v)
    return out[0], out[1]
