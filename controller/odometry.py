"""Pose estimate from measured wheel speeds and steering angles with model (1)-(5).

Measured per wheel, in the paper's order (wheels 1 and 4 front, 2 and 3 rear): ground speed
``r * wheel_speed`` (m/s) and steering angle (rad). The model's inputs are their means:
``v1`` over the four drive wheels, ``delta1`` over the front pair, ``delta2`` over the rear pair.
Between two samples the steering angles move linearly (rate = difference / dt). When the drive
wheels' rotation angles are given, ``v1`` over the interval is the distance they rolled,
``r * mean(delta angle) / dt``: the encoder's 4096 counts per turn do not accumulate error,
while Present Velocity's 0.229 rpm steps (0.8 mm/s on a 33 mm wheel) would bias the distance.
Without angles, ``v1`` is the mean of the two speed samples. The model is integrated with RK4.
"""
from __future__ import annotations

import numpy as np

from controller.kinematics import Geometry, rk4_step

FRONT = (0, 3)
REAR = (1, 2)


def model_inputs(ground_speeds_mps, steer_rad) -> tuple[float, float, float]:
    """``(v1, delta1, delta2)`` from four ground speeds (m/s) and four steering angles (rad)."""
    v = np.asarray(ground_speeds_mps, dtype=float)
    d = np.asarray(steer_rad, dtype=float)
    if v.shape != (4,) or d.shape != (4,):
        raise ValueError(f"expected 4 wheel speeds and 4 steering angles, got {v.shape} and {d.shape}")
    return float(v.mean()), float(d[list(FRONT)].mean()), float(d[list(REAR)].mean())


class Odometry:
    """Dead-reckoning of ``(x, y, theta)`` from wheel measurements.

    Parameters
    ----------
    geom : Geometry
        Wheel layout (``a_m``, ``b_m``, ``wheel_radius_m``).
    pose : array_like, shape (3,)
        Start pose ``(x_m, y_m, theta_rad)``.
    """

    def __init__(self, geom: Geometry, pose=(0.0, 0.0, 0.0)):
        self.geom = geom
        self.pose = np.asarray(pose, dtype=float).copy()
        self._last: tuple[float, float, float] | None = None
        self._angles: np.ndarray | None = None

    @property
    def state(self) -> np.ndarray:
        """Model state ``(x, y, theta, delta1, delta2)``, shape (5,); steering NaN before the first sample."""
        d1, d2 = (self._last[1], self._last[2]) if self._last else (np.nan, np.nan)
        return np.array([*self.pose, d1, d2])

    def update(self, dt_s: float, wheel_speeds_radps, steer_rad, wheel_angles_rad=None) -> np.ndarray:
        """Advance by ``dt_s`` with the new sample; returns the pose, shape (3,).

        ``wheel_angles_rad`` (4,), optional: drive wheel rotation angles (multi-turn), preferred
        over the speeds for the distance rolled.
        """
        r = self.geom.wheel_radius_m
        v1, d1, d2 = model_inputs(np.asarray(wheel_speeds_radps, dtype=float) * r, steer_rad)
        angles = None if wheel_angles_rad is None else np.asarray(wheel_angles_rad, dtype=float)
        if self._last is not None and dt_s > 0:
            v0, e1, e2 = self._last
            if angles is not None and self._angles is not None:
                v_bar = r * float(np.mean(angles - self._angles)) / dt_s
            else:
                v_bar = 0.5 * (v0 + v1)
            s = np.array([*self.pose, e1, e2])
            u = np.array([v_bar, (d1 - e1) / dt_s, (d2 - e2) / dt_s])
            self.pose = rk4_step(s, u, dt_s, self.geom, substeps=1)[:3]  # 16 ms: one RK4 step suffices
        self._last = (v1, d1, d2)
        self._angles = angles
        return self.pose.copy()
