"""Kinematic model (1)-(5) of the four-wheel independently steered robot.

State ``s = (x, y, theta, delta1, delta2)`` in m and rad, inputs ``(v1, omega1, omega2)`` in m/s
and rad/s. ``delta1`` steers both front wheels, ``delta2`` both rear wheels, and all four wheels
are driven at the same ground speed ``v1``. Wheel positions in the body frame: front ``(a, b)``,
rear ``(-a, b)``; ``b`` only enters through ``r**2 = a**2 + b**2``.

:class:`Geometry` and :class:`Limits` are plain numbers; the robot file becomes them in the
application layer (:func:`swerve.tools.run.geometry.load_robot`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swerve.controller.errors import ControllerError


@dataclass(frozen=True)
class Geometry:
    """Wheel layout: ``a_m`` half wheelbase, ``b_m`` half track, ``wheel_radius_m``."""

    a_m: float = 0.1125
    b_m: float = 0.1125
    wheel_radius_m: float = 0.033

    @property
    def r2_m2(self) -> float:
        """Squared distance ``a**2 + b**2`` of every wheel from the centroid, m^2."""
        return self.a_m ** 2 + self.b_m ** 2


@dataclass(frozen=True)
class Limits:
    """Actuator limits: wheel speed m/s, steering rate rad/s, steering angle rad."""

    v1_max_mps: float = 0.13
    steer_rate_max_radps: float = 4.0
    steer_angle_max_rad: float = 1.5708


def _pose_rates(th, d1, d2, v1, k, cos, sin):
    """``(dx, dy, dtheta)`` of model (1)-(3); ``k = a / (2 r**2)``. Works on floats (``math``'s
    cos/sin) and on arrays (numpy's)."""
    return (0.5 * (cos(d1 + th) + cos(d2 + th)) * v1,
            0.5 * (sin(d1 + th) + sin(d2 + th)) * v1,
            k * (sin(d1) - sin(d2)) * v1)


def state_derivative(state, inputs, geom: Geometry = Geometry()) -> np.ndarray:
    """Right-hand side of model (1)-(5).

    Parameters
    ----------
    state : array_like, shape (..., 5)
        ``(x_m, y_m, theta_rad, delta1_rad, delta2_rad)``.
    inputs : array_like, shape (..., 3)
        ``(v1_mps, omega1_radps, omega2_radps)``.

    Returns
    -------
    ndarray, shape (..., 5)
        Time derivative of the state.
    """
    s = np.asarray(state, dtype=float)
    u = np.asarray(inputs, dtype=float)
    th, d1, d2 = s[..., 2], s[..., 3], s[..., 4]
    v1, w1, w2 = u[..., 0], u[..., 1], u[..., 2]
    k = geom.a_m / (2.0 * geom.r2_m2)
    out = np.empty(np.broadcast_shapes(s.shape, u.shape[:-1] + (5,)))
    out[..., 0], out[..., 1], out[..., 2] = _pose_rates(th, d1, d2, v1, k, np.cos, np.sin)
    out[..., 3] = w1
    out[..., 4] = w2
    return out


def rk4_step(state, inputs, dt_s: float, geom: Geometry = Geometry(), substeps: int = 2):
    """Integrate model (1)-(5) over ``dt_s`` with inputs held constant (classical RK4).

    ``state`` (5,), ``inputs`` (3,). Returns the state after ``dt_s``, shape (5,).
    """
    return np.array(rk4_step_floats(np.asarray(state, dtype=float).tolist(),
                                    np.asarray(inputs, dtype=float).tolist(), dt_s, geom,
                                    substeps))


def rk4_step_floats(state, inputs, dt_s: float, geom: Geometry = Geometry(),
                    substeps: int = 2) -> list[float]:
    """:func:`rk4_step` on plain floats (5 and 3 of them; returns a list of 5): the same
    arithmetic as :func:`state_derivative` stages, without numpy's per-call overhead."""
    x, y, th, d1, d2 = state
    v1, w1, w2 = inputs
    k = geom.a_m / (2.0 * geom.r2_m2)
    h = dt_s / substeps
    cos, sin = math.cos, math.sin
    for _ in range(substeps):
        # the steering angles move linearly: the stages need them at 0, h/2 and h
        d1m, d2m = d1 + 0.5 * h * w1, d2 + 0.5 * h * w2
        k1 = _pose_rates(th, d1, d2, v1, k, cos, sin)
        k2 = _pose_rates(th + 0.5 * h * k1[2], d1m, d2m, v1, k, cos, sin)
        k3 = _pose_rates(th + 0.5 * h * k2[2], d1m, d2m, v1, k, cos, sin)
        k4 = _pose_rates(th + h * k3[2], d1 + h * w1, d2 + h * w2, v1, k, cos, sin)
        c = h / 6.0
        x = x + c * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        y = y + c * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
        th = th + c * (k1[2] + 2 * k2[2] + 2 * k3[2] + k4[2])
        d1 = d1 + c * (w1 + 2 * w1 + 2 * w1 + w1)
        d2 = d2 + c * (w2 + 2 * w2 + 2 * w2 + w2)
    return [x, y, th, d1, d2]


def wheel_commands(v1_mps: float, delta1_rad: float, delta2_rad: float) -> np.ndarray:
    """The robot's eight actuator goals ``[v1, v1, v1, v1, d1, d2, d2, d1]``.

    Wheels 1 and 4 are front, 2 and 3 rear (the paper's order); drive goals in m/s
    (ground speed), steering goals in rad. Returns shape (8,).
    """
    return np.array(wheel_command_floats(v1_mps, delta1_rad, delta2_rad))


def wheel_command_floats(v1_mps: float, delta1_rad: float, delta2_rad: float) -> list[float]:
    """:func:`wheel_commands` as a list of 8 floats (the control loop's form)."""
    v, d1, d2 = float(v1_mps), float(delta1_rad), float(delta2_rad)
    return [v, v, v, v, d1, d2, d2, d1]


def drive_angular_speed(v1_mps, wheel_radius_m: float = 0.033):
    """Drive-wheel angular speed in rad/s for ground speed ``v1_mps`` (``v1 / r``)."""
    if not wheel_radius_m > 0:
        raise ControllerError(f"wheel radius must be positive, got {wheel_radius_m}")
    return np.asarray(v1_mps, dtype=float) / wheel_radius_m


def symmetric_steering(curvature_1pm, speed_mps, geom: Geometry = Geometry()):
    """Steering that makes the body follow a path with its heading along the velocity.

    With ``delta1 = -delta2 = delta`` the body moves along its own x-axis with speed
    ``v1 cos(delta)`` on a path of curvature ``a tan(delta) / (a**2 + b**2)``.

    Returns
    -------
    delta_rad, v1_mps : ndarray
        Front steering angle (rear is its negative) and wheel speed.
    """
    delta = np.arctan(geom.r2_m2 * np.asarray(curvature_1pm, dtype=float) / geom.a_m)
    return delta, np.asarray(speed_mps, dtype=float) / np.cos(delta)
