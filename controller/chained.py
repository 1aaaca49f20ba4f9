"""Chained form (6)-(18) of model (1)-(5), in a world frame rotated by ``phi``.

Chained system: ``x1' = u1, x2' = u2, x3' = x2 u1, x4' = u3, x5' = x4 u1``.
In a frame rotated by ``phi`` (rad) the world coordinates are ``R(-phi) (x, y)`` and the heading
is ``theta - phi``; model (1)-(5) is invariant under this rotation (steering angles are relative
to the body), so the transforms below are the paper's (11)-(18) applied to rotated coordinates.
``phi = 0`` is the paper's chained form.

With ``ci = cos(delta_i + theta')``, ``si = sin(...)``, ``Di = xwi sin(delta_i) / r**2``,
``Bi = xwi cos(delta_i) / r**2``, ``sigma' = (delta1 + delta2)/2 + theta'``::

    x = (x', (D1+D2)/(c1+c2), theta', tan(sigma'), y')

The form is singular where ``c1 + c2 = 0``: ``sigma' = +-pi/2``, travel parallel to the frame's
y-axis. Functions here compute whatever numpy computes there; callers check
:func:`singularity_margin` first. The frame rotation and :func:`to_chained` (which the reference and
the frame changes go through) use :mod:`math`'s functions (:mod:`core.mathmap`), so their bits
do not depend on NumPy's SIMD loops.
"""
from __future__ import annotations

import math

import numpy as np

from swerve.controller.kinematics import Geometry
from swerve.core.mathmap import cos_sin, elementwise


def wrap_angle(angle):
    """Wrap angles (rad) to ``[-pi, pi)``."""
    return (np.asarray(angle, dtype=float) + np.pi) % (2 * np.pi) - np.pi


def _rotated(state, phi):
    s = np.asarray(state, dtype=float)
    c, sn = cos_sin(phi)
    xr = c * s[..., 0] + sn * s[..., 1]
    yr = -sn * s[..., 0] + c * s[..., 1]
    return xr, yr, s[..., 2] - phi, s[..., 3], s[..., 4]


def _terms(th, d1, d2, geom):
    a, r2 = geom.a_m, geom.r2_m2
    c1, c2 = np.cos(d1 + th), np.cos(d2 + th)
    s1, s2 = np.sin(d1 + th), np.sin(d2 + th)
    D = a * (np.sin(d1) - np.sin(d2)) / r2          # D1 + D2 (xw2 = -a)
    B1, B2 = a * np.cos(d1) / r2, -a * np.cos(d2) / r2
    return c1, c2, s1, s2, D, B1, B2


def singularity_margin(state, phi=0.0):
    """``|cos(sigma')|`` in the frame ``phi``: 0 on the singular set, 1 far from it."""
    _, _, th, d1, d2 = _rotated(state, phi)
    return np.abs(np.cos(0.5 * (d1 + d2) + th))


def to_chained(state, geom: Geometry = Geometry(), phi=0.0) -> np.ndarray:
    """Chained coordinates (11)-(15) of a state.

    Parameters
    ----------
    state : array_like, shape (..., 5)
        ``(x_m, y_m, theta_rad, delta1_rad, delta2_rad)``.
    phi : float or array_like, shape (...)
        Frame angle, rad.

    Returns
    -------
    ndarray, shape (..., 5)
    """
    xr, yr, th, d1, d2 = _rotated(state, phi)
    D = geom.a_m * (elementwise(math.sin, d1) - elementwise(math.sin, d2)) / geom.r2_m2  # D1 + D2
    c = elementwise(math.cos, d1 + th) + elementwise(math.cos, d2 + th)
    return np.stack([xr, D / c, th, elementwise(math.tan, 0.5 * (d1 + d2) + th), yr], axis=-1)


def from_chained(chained, geom: Geometry = Geometry(), phi=0.0) -> np.ndarray:
    """Inverse of :func:`to_chained`, on the branch ``|delta1 + delta2| <= pi``.

    Returns the state, shape (..., 5).
    """
    x = np.asarray(chained, dtype=float)
    th = x[..., 2]
    S = wrap_angle(2.0 * (np.arctan(x[..., 3]) - th))        # delta1 + delta2
    sig = 0.5 * S + th
    d = 2.0 * np.arctan(x[..., 1] * geom.r2_m2 * np.cos(sig) / (geom.a_m * np.cos(0.5 * S)))
    c, sn = np.cos(phi), np.sin(phi)
    xw = c * x[..., 0] - sn * x[..., 4]
    yw = sn * x[..., 0] + c * x[..., 4]
    return np.stack([xw, yw, th + phi, 0.5 * (S + d), 0.5 * (S - d)], axis=-1)


def chained_inputs(state, inputs, geom: Geometry = Geometry(), phi=0.0) -> np.ndarray:
    """Chained inputs (16)-(18) ``(u1, u2, u3)`` for physical inputs ``(v1, omega1, omega2)``.

    Shapes: state (..., 5), inputs (..., 3) -> (..., 3).
    """
    _, _, th, d1, d2 = _rotated(state, phi)
    u = np.asarray(inputs, dtype=float)
    v1, w1, w2 = u[..., 0], u[..., 1], u[..., 2]
    c1, c2, s1, s2, D, B1, B2 = _terms(th, d1, d2, geom)
    C = c1 + c2
    u1 = 0.5 * C * v1
    u2 = (((B1 * w1 + B2 * w2) * C + D * (w1 * s1 + w2 * s2)) / C ** 2
          + v1 * D ** 2 * (s1 + s2) / (2.0 * C ** 2))
    u3 = (v1 * D + w1 + w2) / (1.0 + np.cos(d1 + d2 + 2.0 * th))
    return np.stack([u1, u2, u3], axis=-1)


def inputs_from_chained(state, chained_u, geom: Geometry = Geometry(), phi=0.0) -> np.ndarray:
    """Physical inputs ``(v1, omega1, omega2)`` that produce chained inputs ``(u1, u2, u3)``.

    ``v1 = 2 u1 / (c1 + c2)``; ``(omega1, omega2)`` solve the 2x2 linear system of the
    ``u2`` and ``u3`` rows. Shapes: state (..., 5), chained_u (..., 3) -> (..., 3).
    """
    _, _, th, d1, d2 = _rotated(state, phi)
    u = np.asarray(chained_u, dtype=float)
    c1, c2, s1, s2, D, B1, B2 = _terms(th, d1, d2, geom)
    C = c1 + c2
    v1 = 2.0 * u[..., 0] / C
    # u2 row: a11 w1 + a12 w2 = r1 ; u3 row: w1 + w2 = r2
    a11 = (B1 * C + D * s1) / C ** 2
    a12 = (B2 * C + D * s2) / C ** 2
    r1 = u[..., 1] - v1 * D ** 2 * (s1 + s2) / (2.0 * C ** 2)
    r2 = u[..., 2] * (1.0 + np.cos(d1 + d2 + 2.0 * th)) - v1 * D
    w1 = (r1 - a12 * r2) / (a11 - a12)
    w2 = r2 - w1
    return np.stack([v1, w1, w2], axis=-1)


def chained_rhs(chained, chained_u) -> np.ndarray:
    """Right-hand side of the chained system; shapes (..., 5), (..., 3) -> (..., 5)."""
    x = np.asarray(chained, dtype=float)
    u = np.asarray(chained_u, dtype=float)
    return np.stack([u[..., 0], u[..., 1], x[..., 1] * u[..., 0], u[..., 2],
                     x[..., 3] * u[..., 0]], axis=-1)


def chained_jacobian(state, geom: Geometry = Geometry(), phi=0.0, h: float = 1e-6):
    """``d to_chained / d state`` at one state by central differences, shape (5, 5)."""
    s = np.asarray(state, dtype=float)
    E = np.eye(5) * h
    return ((to_chained(s + E, geom, phi) - to_chained(s - E, geom, phi)) / (2 * h)).T
