"""Planar robot body on friction-limited tyres: the world can disagree with the kinematic model.

State: pose ``(x, y, θ)`` (world) and twist ``v = (vx, vy, ω)`` (body frame). Wheel ``i`` at
``(x_i, y_i)`` with steering angle ``δ_i`` and surface speed ``u_i = r_i·ω_wheel`` slips at
``s_i = Rᵀ(δ_i)·P_i·v − (u_i, 0)`` (wheel frame: longitudinal, lateral), where
``P_i = [[1, 0, −y_i], [0, 1, x_i]]`` gives the contact-point velocity. The tyre pushes the body with

    F_i = −R(δ_i)·c_i·diag(1, k_lat)·s_i,      |F_i| ≤ μ·N_i

(a linear slip-speed tyre saturating at the friction limit; ``c_i`` is ``slip_stiffness``
reduced so that the force stays on the friction circle). Newton–Euler in the body frame:
``m(v̇x − ω vy) = ΣFx``, ``m(v̇y + ω vx) = ΣFy``, ``I ω̇ = Σ(x_i Fy_i − y_i Fx_i)``.

**Integration (stiff tyre).** The tyre time constant ``m / (4c)`` is a few ms, so the body
velocity is updated linearly implicitly: with the per-wheel stiffness frozen at its value for the
current slip, ``(M + dt·ΣP_iᵀK_iP_i) v⁺ = M v + dt·(ΣP_iᵀK_iR_i(u_i, 0) + Coriolis)``; the
matrix is symmetric positive definite for any ``dt``, so the body never blows up. The wheels are
coupled explicitly: the reaction ``r_i·F_long,i`` is the drive shaft's load over the next step.
That loop is stable while ``dt·r²·c / J_out < 2`` (``J_out`` = rotor inertia reflected to the
wheel, 2.3e-3 kg·m²): 0.16 at 1 kHz with ``c = 300 N·s/m``, ``r = 0.033 m``
(:func:`wheel_coupling_number`). Normal loads are static (``m·g`` shared so that the load's
moments about the centroid vanish, least norm): no load transfer under acceleration.

Everything is Python float arithmetic in a fixed order (no BLAS, no ``math.hypot``, whose
algorithm changed in Python 3.12), so a run gives the same bits on every machine.
"""
from __future__ import annotations

import math

import numpy as np

from swerve.core import small_linalg

from .body import _se2_step
from .jit import jitable
from .params import ContactParams


def static_normal_loads_n(wheel_xy_m: np.ndarray, mass_kg: float, gravity_mps2: float) -> np.ndarray:
    """Per-wheel normal load (N), shape (n,): least-norm loads with ``ΣN = m·g`` and no moment
    about the centroid (the centre of mass is assumed there)."""
    xy = np.asarray(wheel_xy_m, float)
    a = [[1.0] * len(xy), xy[:, 0].tolist(), xy[:, 1].tolist()]
    return np.array(small_linalg.matvec(small_linalg.pinv(a), [float(mass_kg) * float(gravity_mps2), 0.0, 0.0]))


def wheel_coupling_number(dt_s: float, radius_m: float, stiffness_n_s_per_m: float,
                          wheel_inertia_kg_m2: float) -> float:
    """``dt·r²·c / J``: the explicit wheel–tyre loop is stable below 2 (keep it well below 1)."""
    return dt_s * radius_m ** 2 * stiffness_n_s_per_m / wheel_inertia_kg_m2


class ContactBody:
    """Rigid body driven by wheel–ground contact forces (same interface as :class:`RobotBody`).

    Parameters
    ----------
    wheel_xy_m : array_like, shape (n, 2)
        Wheel contact points in the body frame, m.
    mass_kg : float
        Total mass carried by the wheels (robot + payload), kg.
    params : ContactParams
        Tyre friction and stiffness, yaw inertia (0: a uniform square plate through the wheels).
    pose : (x_m, y_m, theta_rad)
        Initial world pose.
    """

    def __init__(self, wheel_xy_m, mass_kg: float, params: ContactParams,
                 pose: tuple[float, float, float] = (0.0, 0.0, 0.0)):
        self.wheel_xy_m = np.asarray(wheel_xy_m, float)
        n = len(self.wheel_xy_m)
        self.params = params
        self.mass_kg = float(mass_kg)
        half = np.max(np.abs(self.wheel_xy_m), axis=0)
        self.yaw_inertia_kg_m2 = (params.yaw_inertia_kg_m2 or
                                  self.mass_kg * float((2 * half[0]) ** 2 + (2 * half[1]) ** 2) / 12.0)
        self.normal_n = static_normal_loads_n(self.wheel_xy_m, self.mass_kg, params.gravity_mps2)
        self.limit_n = params.friction_coefficient * self.normal_n
        self.x_m, self.y_m, self.theta_rad = map(float, pose)
        self._xy = self.wheel_xy_m.tolist()      # Python floats for the per-step scalar arithmetic
        self._x, self._y = [x for x, _ in self._xy], [y for _, y in self._xy]
        self._limits = self.limit_n.tolist()
        # last step's twist, slip, forces (x, y per wheel) and longitudinal forces, as floats
        self._twist = (0.0, 0.0, 0.0)
        self._slip, self._fx, self._fy, self._flong = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
        self.slip_energy_j = 0.0                 # work dissipated in the tyres
        self.saturated_steps = 0                 # wheel-steps on the friction limit
        self.wheel_steps = 0

    def step(self, dt_s: float, speeds_mps, steer_rad) -> tuple[float, float, float]:
        """Advance by ``dt_s`` with wheel surface speeds (m/s) and steering angles (rad), shape (n,)
        each, held over the step; return the world pose.

        Scalar arithmetic per wheel and a 3×3 solve: numpy's per-call overhead would cost ten
        times more for four wheels.
        """
        p = self.params
        n = len(self._xy)
        slip, fx, fy, flong = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
        vx, vy, w, power, sat = contact_step(
            dt_s, p.lateral_stiffness_ratio, p.slip_stiffness_n_s_per_m, self.mass_kg, self.yaw_inertia_kg_m2,
            *self._twist, self._x, self._y, self._limits, [float(u) for u in speeds_mps], steer_rad,
            slip, fx, fy, flong)
        self._slip, self._fx, self._fy, self._flong = slip, fx, fy, flong
        self.slip_energy_j += dt_s * power
        self.saturated_steps += sat
        self.wheel_steps += n
        self._twist = (vx, vy, w)
        self.x_m, self.y_m, self.theta_rad = _se2_step(self.x_m, self.y_m, self.theta_rad, vx, vy, w, dt_s)
        return self.pose

    @property
    def twist(self) -> np.ndarray:
        """Body twist ``(vx m/s, vy m/s, ω rad/s)`` (body frame) after the last step, shape (3,)."""
        return np.array(self._twist)

    @property
    def residual_mps(self) -> np.ndarray:
        """Slip speed per wheel at the last step, m/s, shape (n,)."""
        return np.array(self._slip)

    @property
    def force_n(self) -> np.ndarray:
        """Force on the body per wheel at the last step, body frame, N, shape (n, 2)."""
        return np.array([self._fx, self._fy]).T

    @property
    def force_long_n(self) -> np.ndarray:
        """Its component along each wheel's rolling direction, N, shape (n,)."""
        return np.array(self._flong)

    @property
    def force_long_list_n(self) -> list[float]:
        """:attr:`force_long_n` as Python floats (per physics step: no NumPy)."""
        return self._flong

    @property
    def pose(self) -> tuple[float, float, float]:
        """World pose ``(x_m, y_m, theta_rad)``."""
        return self.x_m, self.y_m, self.theta_rad


@jitable
def contact_step(dt_s, kl, stiffness, m, iz, vx, vy, w, xs, ys, limits, speeds, steer, slip, fx, fy, flong):
    """One :meth:`ContactBody.step` of the twist on plain numbers (sequences of floats per wheel).

    ``kl``: lateral stiffness ratio; ``stiffness``: slip stiffness, N·s/m; ``m`` (kg), ``iz``
    (kg·m²); ``(vx, vy, w)``: the twist before the step; ``xs``, ``ys``: wheel positions, m;
    ``limits``: friction limits, N; ``speeds`` (m/s), ``steer`` (rad) held over the step.
    Writes each wheel's slip speed and force on the body (body frame, and along the wheel) into
    ``slip``, ``fx``, ``fy``, ``flong``. Returns ``(vx, vy, w, tyre power, wheels saturated)``.
    """
    a11, a12, a22, a13, a23, a33 = m, 0.0, m, 0.0, 0.0, iz
    r1, r2, r3 = m * vx + dt_s * m * w * vy, m * vy - dt_s * m * w * vx, iz * w
    n = len(xs)
    sat = 0
    for j in range(n):
        x, y, u, limit = xs[j], ys[j], speeds[j], limits[j]
        c, s, sl, st = _wheel_slip(vx, vy, w, x, y, u, steer[j])
        f0 = stiffness * _norm(sl, kl * st)
        saturated = f0 > limit
        k = stiffness * (limit / f0 if saturated else 1.0)      # secant stiffness on the friction circle
        sat += saturated
        ka, kb, kd = k * (c * c + kl * s * s), k * (1.0 - kl) * c * s, k * (s * s + kl * c * c)
        kx, ky = -ka * y + kb * x, -kb * y + kd * x          # K · (−y, x)
        a11 += dt_s * ka
        a12 += dt_s * kb
        a22 += dt_s * kd
        a13 += dt_s * kx
        a23 += dt_s * ky
        a33 += dt_s * (-y * kx + x * ky)
        fu = k * u
        r1 += dt_s * fu * c
        r2 += dt_s * fu * s
        r3 += dt_s * fu * (-y * c + x * s)
        flong[j] = k                 # (the wheel's stiffness until the twist is solved)
    vx, vy, w = _solve_sym3(a11, a12, a13, a22, a23, a33, r1, r2, r3)
    power = 0.0
    for j in range(n):
        k = flong[j]
        c, s, sl, st = _wheel_slip(vx, vy, w, xs[j], ys[j], speeds[j], steer[j])
        fl, ft = -k * sl, -k * kl * st                     # force on the body, wheel frame
        slip[j] = _norm(sl, st)
        flong[j] = fl
        fx[j] = c * fl - s * ft
        fy[j] = s * fl + c * ft
        power -= fl * sl + ft * st
    return vx, vy, w, power, sat


@jitable
def _wheel_slip(vx, vy, w, x, y, u, d):
    """``(cos δ, sin δ, longitudinal slip, lateral slip)`` of the wheel at ``(x, y)`` (m) steered
    ``δ`` (rad) with surface speed ``u`` (m/s) under the body twist ``(vx, vy, w)``; m/s."""
    c, s = math.cos(d), math.sin(d)
    px, py = vx - w * y, vy + w * x
    return c, s, c * px + s * py - u, -s * px + c * py


@jitable
def _norm(x: float, y: float) -> float:
    """``√(x² + y²)`` in three correctly rounded operations (no overflow at these magnitudes)."""
    return math.sqrt(x * x + y * y)


@jitable
def _solve_sym3(a11, a12, a13, a22, a23, a33, b1, b2, b3) -> tuple[float, float, float]:
    """Solve the symmetric 3×3 system ``A x = b`` (Cramer's rule; ``A`` positive definite)."""
    c11 = a22 * a33 - a23 * a23
    c12 = a13 * a23 - a12 * a33
    c13 = a12 * a23 - a13 * a22
    det = a11 * c11 + a12 * c12 + a13 * c13
    c22 = a11 * a33 - a13 * a13
    c23 = a12 * a13 - a11 * a23
    c33 = a11 * a22 - a12 * a12
    return ((c11 * b1 + c12 * b2 + c13 * b3) / det, (c12 * b1 + c22 * b2 + c23 * b3) / det,
            (c13 * b1 + c23 * b2 + c33 * b3) / det)
