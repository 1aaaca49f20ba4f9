"""Planar robot body: pose ``(x, y, θ)`` from four wheel ground speeds and steering angles.

Each wheel ``i`` at body-frame position ``(x_i, y_i)`` rolls with signed ground speed ``v_i`` (m/s)
along its steering direction ``δ_i`` (rad, counter-clockwise from the body x axis). A rigid body
with twist ``(vx, vy, ω)`` (body frame) moves that contact point at ``(vx − ω y_i, vy + ω x_i)``.
Four wheels give eight equations for three unknowns; we take the least-squares twist::

    minimise  Σ_i ‖ (vx − ω y_i, vy + ω x_i) − v_i (cos δ_i, sin δ_i) ‖²

so wheels that fight each other (mismatched commands) are averaged, and the residual per wheel
(the slip it would need) is reported. With the wheels at the centroid-symmetric corners
``(±a, ±b)``, equal speeds ``v1``, front angles ``δ1`` and rear angles ``δ2``, the normal equations
decouple (``Σx_i = Σy_i = 0``) and give exactly the paper's model (1)–(3):
``vx = ½(cos δ1 + cos δ2) v1``, ``vy = ½(sin δ1 + sin δ2) v1``,
``ω = (x_w1 sin δ1 / (2 r1²) + x_w2 sin δ2 / (2 r2²)) v1``.
The pose integrates the twist exactly for a twist held constant over the step.

The least-squares operator comes from :func:`swerve.core.small_linalg.pinv` and every fit
is Python float arithmetic in a fixed order (no BLAS), so a run gives the same bits on every machine.
"""
from __future__ import annotations

import math
from math import cos, sin

import numpy as np

from swerve.core import small_linalg

from .jit import jitable


def contact_matrix(wheel_xy_m: np.ndarray) -> np.ndarray:
    """Map twist ``(vx, vy, ω)`` to stacked contact velocities ``[vx_1, vy_1, ..., vy_n]``, shape (2n, 3)."""
    xy = np.asarray(wheel_xy_m, float)
    m = np.zeros((2 * len(xy), 3))
    m[0::2, 0] = 1.0
    m[0::2, 2] = -xy[:, 1]
    m[1::2, 1] = 1.0
    m[1::2, 2] = xy[:, 0]
    return m


class RobotBody:
    """Least-squares rigid-body fit of the wheels and pose integration.

    Parameters
    ----------
    wheel_xy_m : array_like, shape (n, 2)
        Wheel contact points in the body frame (x forward, y left), m.
    pose : tuple of float
        Initial ``(x_m, y_m, theta_rad)`` in the world frame.
    """

    def __init__(self, wheel_xy_m, pose: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        self.wheel_xy_m = np.asarray(wheel_xy_m, float)
        self._m = contact_matrix(self.wheel_xy_m)
        self._m_rows = self._m.tolist()
        pinv = small_linalg.pinv(self._m_rows)
        self._pinv = np.array(pinv)                # (3, 2n): least-squares solution operator
        # the same as Python floats for the per-step fit (the arguments of kinematic_twist): the
        # (vx, vy, ω) coefficients of each wheel's v cos δ (even columns of pinv) and v sin δ (odd)
        cols = list(zip(*pinv))
        self.fit_rows = tuple([col[i] for col in cols[parity::2]] for parity in (0, 1) for i in range(3))
        self.x_m, self.y_m, self.theta_rad = map(float, pose)
        self._twist = (0.0, 0.0, 0.0)
        self._fit: tuple | None = None     # (wheel speeds, steering angles, twist) of the last step
        self._residual_mps = np.zeros(len(self.wheel_xy_m))

    @property
    def residual_mps(self) -> np.ndarray:
        """Each wheel's contact-velocity misfit (slip speed) at the last fit, m/s, shape (n,);
        computed when asked (the steps only keep what it needs)."""
        if self._fit is not None:
            vs, ds, twist = self._fit
            w = [v * f(d) for v, d in zip(vs, ds) for f in (cos, sin)]
            r = [small_linalg.dot(row, twist) - wi for row, wi in zip(self._m_rows, w)]
            self._residual_mps = np.array([math.sqrt(x * x + y * y) for x, y in zip(r[0::2], r[1::2])])
            self._fit = None
        return self._residual_mps

    def fit_twist(self, speeds_mps, steer_rad) -> np.ndarray:
        """Least-squares body twist ``(vx m/s, vy m/s, ω rad/s)`` (body frame), shape (3,).

        Also sets ``residual_mps`` (n,): each wheel's contact-velocity misfit (slip speed). The same
        arithmetic as a step of :meth:`step_many`; the pose does not move.
        """
        vs, ds = tuple(map(float, speeds_mps)), tuple(map(float, steer_rad))
        twist = kinematic_twist(*self.fit_rows, vs, ds)
        self._fit = (vs, ds, twist)
        return np.array(twist)

    def step(self, dt_s: float, speeds_mps, steer_rad) -> tuple[float, float, float]:
        """Advance the pose by ``dt_s`` under the fitted twist; return ``(x, y, θ)``.

        Scalar arithmetic in Python floats (for four wheels NumPy's per-call overhead costs more
        than the sums); the same fit as :meth:`fit_twist`, bit for bit."""
        return self.step_many(dt_s, ((speeds_mps, steer_rad),))

    def step_many(self, dt_s: float, steps) -> tuple[float, float, float]:
        """:meth:`step` for consecutive steps: ``steps`` yields ``(speeds_mps, steer_rad)`` per
        step, each a sequence over the wheels."""
        rows = self.fit_rows
        x, y, theta = self.x_m, self.y_m, self.theta_rad
        vs = ds = twist = None
        for vs, ds in steps:
            twist = kinematic_twist(*rows, vs, ds)
            x, y, theta = _se2_step(x, y, theta, *twist, dt_s)
        if twist is not None:
            self._twist, self._fit = twist, (tuple(vs), tuple(ds), twist)
            self.x_m, self.y_m, self.theta_rad = x, y, theta
        return x, y, theta

    @property
    def twist(self) -> np.ndarray:
        """Body twist ``(vx m/s, vy m/s, ω rad/s)`` (body frame) of the last step, shape (3,)."""
        return np.array(self._twist)

    @property
    def pose(self) -> tuple[float, float, float]:
        """World pose ``(x_m, y_m, theta_rad)``."""
        return self.x_m, self.y_m, self.theta_rad


@jitable
def kinematic_twist(cx, cy, cw, sx, sy, sw, vs, ds) -> tuple[float, float, float]:
    """The least-squares twist ``pinv @ [v1 cos δ1, v1 sin δ1, v2 cos δ2, ...]`` (m/s, m/s, rad/s)
    for speeds ``vs`` (m/s) and angles ``ds`` (rad), each a sequence over the wheels, and the
    per-wheel coefficients of ``pinv`` (:attr:`RobotBody.fit_rows`: ``cx[i]`` is the coefficient of
    wheel ``i``'s ``v cos δ`` on ``vx``, ``sw[i]`` that of its ``v sin δ`` on ``ω``, ...): each row
    added term by term in that order from 0.0 (explicitly: the builtin ``sum`` compensates from
    3.12)."""
    vx = vy = om = 0.0
    for i in range(len(vs)):
        v, d = vs[i], ds[i]
        c, s = v * cos(d), v * sin(d)
        vx += cx[i] * c
        vy += cy[i] * c
        om += cw[i] * c
        vx += sx[i] * s
        vy += sy[i] * s
        om += sw[i] * s
    return vx, vy, om


def se2_step(pose: tuple[float, float, float], twist, dt_s: float) -> tuple[float, float, float]:
    """World pose ``(x_m, y_m, theta_rad)`` after ``dt_s`` at the body twist ``(vx, vy, ω)`` held
    constant (exact SE(2) motion)."""
    x, y, theta = pose
    vx, vy, w = (float(v) for v in twist)
    return _se2_step(x, y, theta, vx, vy, w, dt_s)


@jitable
def _se2_step(x: float, y: float, theta: float, vx: float, vy: float, w: float,
              dt_s: float) -> tuple[float, float, float]:
    """:func:`se2_step` on plain floats."""
    h = w * dt_s
    if abs(h) > 1e-9:
        s, c = math.sin(h) / w, (1.0 - math.cos(h)) / w
        dx, dy = s * vx - c * vy, c * vx + s * vy
    else:
        dx, dy = vx * dt_s, vy * dt_s
    ct, st = math.cos(theta), math.sin(theta)
    return x + ct * dx - st * dy, y + st * dx + ct * dy, theta + h


def paper_model_rates(theta: float, delta1: float, delta2: float, v1: float, a: float, b: float
                      ) -> tuple[float, float, float]:
    """The paper's kinematic model (1)–(3): ``(ẋ, ẏ, θ̇)`` for front ``δ1``, rear ``δ2``, speed ``v1``."""
    r2 = a * a + b * b
    xdot = 0.5 * (math.cos(delta1 + theta) + math.cos(delta2 + theta)) * v1
    ydot = 0.5 * (math.sin(delta1 + theta) + math.sin(delta2 + theta)) * v1
    thdot = (a * math.sin(delta1) / (2 * r2) + (-a) * math.sin(delta2) / (2 * r2)) * v1
    return xdot, ydot, thdot
