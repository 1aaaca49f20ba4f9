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
"""
from __future__ import annotations

import math

import numpy as np

from .params import ContactParams


def static_normal_loads_n(wheel_xy_m: np.ndarray, mass_kg: float, gravity_mps2: float) -> np.ndarray:
    """Per-wheel normal load (N), shape (n,): least-norm loads with ``ΣN = m·g`` and no moment
    about the centroid (the centre of mass is assumed there)."""
    xy = np.asarray(wheel_xy_m, float)
    a = np.vstack([np.ones(len(xy)), xy[:, 0], xy[:, 1]])
    return np.linalg.pinv(a) @ np.array([mass_kg * gravity_mps2, 0.0, 0.0])


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
        self._m = np.diag([self.mass_kg, self.mass_kg, self.yaw_inertia_kg_m2])
        self._p = np.zeros((n, 2, 3))
        self._p[:, 0, 0] = 1.0
        self._p[:, 0, 2] = -self.wheel_xy_m[:, 1]
        self._p[:, 1, 1] = 1.0
        self._p[:, 1, 2] = self.wheel_xy_m[:, 0]
        self.x_m, self.y_m, self.theta_rad = map(float, pose)
        self.twist = np.zeros(3)
        self.residual_mps = np.zeros(n)          # slip speed per wheel, m/s
        self.force_n = np.zeros((n, 2))          # force on the body per wheel, body frame, N
        self.force_long_n = np.zeros(n)          # its component along the wheel's rolling direction
        self.slip_energy_j = 0.0                 # work dissipated in the tyres
        self.saturated_steps = 0                 # wheel-steps on the friction limit
        self.wheel_steps = 0

    def _slip(self, v: np.ndarray, rot: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Slip velocity per wheel in the wheel frame, shape (n, 2)."""
        contact = self._p @ v                                   # (n, 2) body frame
        s = np.einsum("nji,nj->ni", rot, contact)               # Rᵀ · contact
        s[:, 0] -= u
        return s

    def step(self, dt_s: float, speeds_mps, steer_rad) -> tuple[float, float, float]:
        """Advance by ``dt_s`` with wheel surface speeds (m/s) and steering angles (rad), shape (n,)
        each, held over the step; return the world pose."""
        u = np.asarray(speeds_mps, float)
        d = np.asarray(steer_rad, float)
        c, sn = np.cos(d), np.sin(d)
        rot = np.empty((len(d), 2, 2))                          # wheel frame -> body frame
        rot[:, 0, 0], rot[:, 0, 1], rot[:, 1, 0], rot[:, 1, 1] = c, -sn, sn, c
        p = self.params
        aniso = np.array([1.0, p.lateral_stiffness_ratio])
        v = self.twist
        s0 = self._slip(v, rot, u)
        f0 = p.slip_stiffness_n_s_per_m * np.hypot(s0[:, 0], s0[:, 1] * aniso[1])
        scale = np.where(f0 > self.limit_n, self.limit_n / np.maximum(f0, 1e-300), 1.0)
        k = p.slip_stiffness_n_s_per_m * scale                  # secant stiffness per wheel
        kw = rot * aniso[None, None, :]                         # R · diag(1, k_lat)
        stiff = np.einsum("n,nij,nkj->nik", k, kw, rot)         # K_i = k R diag Rᵀ (body frame)
        a = self._m + dt_s * np.einsum("nji,njk,nkl->il", self._p, stiff, self._p)
        drive = np.einsum("n,nij,nj->ni", k * u, kw, np.tile([1.0, 0.0], (len(u), 1)))
        coriolis = np.array([self.mass_kg * v[2] * v[1], -self.mass_kg * v[2] * v[0], 0.0])
        rhs = self._m @ v + dt_s * (np.einsum("nji,nj->i", self._p, drive) + coriolis)
        v_new = np.linalg.solve(a, rhs)
        s1 = self._slip(v_new, rot, u)
        f_wheel = -(k[:, None] * aniso[None, :]) * s1            # wheel frame
        self.force_n = np.einsum("nij,nj->ni", rot, f_wheel)
        self.force_long_n = f_wheel[:, 0]
        self.residual_mps = np.hypot(s1[:, 0], s1[:, 1])
        self.slip_energy_j += dt_s * float(-np.sum(f_wheel * s1))
        self.saturated_steps += int(np.count_nonzero(scale < 0.999))
        self.wheel_steps += len(u)
        self.twist = v_new
        self._move(dt_s, *(float(x) for x in v_new))
        return self.pose

    def _move(self, dt_s: float, vx: float, vy: float, w: float) -> None:
        h = w * dt_s
        if abs(h) > 1e-9:                         # exact SE(2) motion at constant twist
            s, c = math.sin(h) / w, (1.0 - math.cos(h)) / w
            dx, dy = s * vx - c * vy, c * vx + s * vy
        else:
            dx, dy = vx * dt_s, vy * dt_s
        ct, st = math.cos(self.theta_rad), math.sin(self.theta_rad)
        self.x_m += ct * dx - st * dy
        self.y_m += st * dx + ct * dy
        self.theta_rad += h

    @property
    def pose(self) -> tuple[float, float, float]:
        """World pose ``(x_m, y_m, theta_rad)``."""
        return self.x_m, self.y_m, self.theta_rad
