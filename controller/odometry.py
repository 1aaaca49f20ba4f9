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

from swerve.controller.kinematics import Geometry, rk4_step_floats

FRONT = (0, 3)
REAR = (1, 2)


def model_inputs(ground_speeds_mps, steer_rad) -> tuple[float, float, float]:
    """``(v1, delta1, delta2)`` from four ground speeds (m/s) and four steering angles (rad)."""
    v, d = list(map(float, ground_speeds_mps)), list(map(float, steer_rad))
    if len(v) != 4 or len(d) != 4:
        raise ValueError(f"expected 4 wheel speeds and 4 steering angles, got {len(v)} and {len(d)}")
    return _mean4(v), (d[FRONT[0]] + d[FRONT[1]]) / 2, (d[REAR[0]] + d[REAR[1]]) / 2


def _mean4(v) -> float:
    """Mean of 4 floats, summed in order (as numpy's ``mean`` does for 4 values)."""
    return (v[0] + v[1] + v[2] + v[3]) / 4


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
        self._pose = tuple(np.asarray(pose, dtype=float).tolist())
        self._last: tuple[float, float, float] | None = None
        self._angles: list[float] | None = None

    @property
    def pose(self) -> np.ndarray:
        """Pose estimate ``(x_m, y_m, theta_rad)``, shape (3,) (a copy)."""
        return np.array(self._pose)

    @property
    def pose_floats(self) -> tuple[float, float, float]:
        """:attr:`pose` as a tuple of floats (no array: the control loop's form)."""
        return self._pose

    @property
    def state(self) -> np.ndarray:
        """Model state ``(x, y, theta, delta1, delta2)``, shape (5,); steering NaN before the first sample."""
        d1, d2 = (self._last[1], self._last[2]) if self._last else (np.nan, np.nan)
        return np.array([*self._pose, d1, d2])

    def update(self, dt_s: float, wheel_speeds_radps, steer_rad, wheel_angles_rad=None
               ) -> tuple[float, float, float]:
        """Advance by ``dt_s`` with the new sample; returns the pose ``(x_m, y_m, theta_rad)``.

        ``wheel_angles_rad`` (4,), optional: drive wheel rotation angles (multi-turn), preferred
        over the speeds for the distance rolled.
        """
        r = self.geom.wheel_radius_m
        v1, d1, d2 = model_inputs([w * r for w in map(float, wheel_speeds_radps)], steer_rad)
        angles = None if wheel_angles_rad is None else list(map(float, wheel_angles_rad))
        if self._last is not None and dt_s > 0:
            v0, e1, e2 = self._last
            if angles is not None and self._angles is not None:
                v_bar = r * _mean4([a - b for a, b in zip(angles, self._angles)]) / dt_s
            else:
                v_bar = 0.5 * (v0 + v1)
            u = (v_bar, (d1 - e1) / dt_s, (d2 - e2) / dt_s)
            # 16 ms: one RK4 step suffices
            self._pose = tuple(rk4_step_floats([*self._pose, e1, e2], u, dt_s, self.geom, 1)[:3])
        self._last = (v1, d1, d2)
        self._angles = angles
        return self._pose
