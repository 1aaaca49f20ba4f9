"""Armature-controlled DC motor behind a gearbox, discretised exactly (zero-order hold).

Motor-side state ``x = [i (A), omega_m (rad/s), theta_m (rad)]``, inputs ``u = [v (V), tau (N·m)]``
with ``tau`` a load torque at the motor shaft::

    L di/dt      = v - R i - Ke omega_m
    J dω_m/dt    = Km i - b omega_m - tau
    dθ_m/dt      = omega_m

The electrical pole (``R/L`` ≈ 3 kHz) is stiff, so each step uses the exact ZOH transition
``[Ad Bd] = expm([[A B], [0 0]] dt)`` (:func:`.discrete.zoh`: 40 digits, the same bits on every
machine), cached per ``(dt, J)``. With the torque disabled the bridge is open: ``i = 0`` and only
the mechanical part (friction, load) acts.

Optional gearbox friction (:class:`GearFrictionParams`, output side) uses a stick/slip state
(Karnopp): while slipping, Coulomb + Stribeck + viscous torque opposes the motion and is held over
the step like any load; a step that would reverse the speed ends at rest and the shaft sticks.
While stuck the speed is exactly 0 (only the armature circuit evolves) until the driving torque
exceeds the breakaway torque. No smoothing, so no chattering around zero speed.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

from .discrete import zoh
from .jit import jitable
from .params import GearFrictionParams, MotorParams


def state_space(p: MotorParams, inertia_kg_m2: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous ``(A (3, 3), B (3, 2))`` of the motor with total motor-side inertia, SI units."""
    r, l, ke, km, b = (p.resistance_ohm, p.inductance_h, p.back_emf_v_s_per_rad,
                       p.torque_nm_per_a, p.friction_nm_s_per_rad)
    j = inertia_kg_m2
    a = np.array([[-r / l, -ke / l, 0.0], [km / j, -b / j, 0.0], [0.0, 1.0, 0.0]])
    bm = np.array([[1.0 / l, 0.0], [0.0, -1.0 / j], [0.0, 0.0]])
    return a, bm


@lru_cache(maxsize=64)
def _discrete(p: MotorParams, inertia_kg_m2: float, dt_s: float, coasting: bool) -> tuple:
    a, b = state_space(p, inertia_kg_m2)
    if coasting:                       # drop the current: states [omega, theta], input [tau]
        a, b = a[1:, 1:], b[1:, 1:]
    ad, bd = zoh(a, b, dt_s)
    # Python floats: the per-step products then cost a fraction of NumPy scalar arithmetic (same IEEE results).
    return tuple(tuple(map(float, r)) for r in ad), tuple(tuple(map(float, r)) for r in bd)


class GearedMotor:
    """A DC motor and an ideal gearbox (ratio ``gear_ratio`` motor turns per output turn).

    Parameters
    ----------
    params : MotorParams
        Motor-side electro-mechanical constants.
    gear_ratio : float
        Reduction, e.g. 212.6 for XH430-W210.
    friction : GearFrictionParams, optional
        Gearbox friction at the output shaft; ``None`` or all zero: none.
    """

    def __init__(self, params: MotorParams, gear_ratio: float, friction: GearFrictionParams | None = None):
        self.params = params
        self.gear_ratio = float(gear_ratio)
        self.friction = friction if friction is not None and friction.enabled else None
        self.stuck = self.friction is not None    # stick/slip state (at rest: stuck)
        self.blocked = False            # shaft held by the outside world (a stall test)
        self.friction_torque_nm = 0.0   # output side, opposing positive speed, last step
        self.current_a = 0.0
        self.speed_radps = 0.0          # motor side
        self.angle_rad = 0.0            # motor side
        self.load_torque_nm = 0.0       # output side
        self.load_inertia_kg_m2 = 0.0   # output side
        self._coefs: dict[tuple, tuple] = {}     # (dt, load inertia, coasting) -> (Ad, Bd)

    @property
    def inertia_kg_m2(self) -> float:
        """Total inertia seen at the motor shaft (rotor + load reflected through the gear)."""
        return self.params.inertia_kg_m2 + self.load_inertia_kg_m2 / self.gear_ratio ** 2

    @property
    def output_speed_radps(self) -> float:
        """Output-shaft speed, rad/s."""
        return self.speed_radps / self.gear_ratio

    @property
    def output_angle_rad(self) -> float:
        """Output-shaft angle, rad (continuous, multi-turn)."""
        return self.angle_rad / self.gear_ratio

    def prepare(self, dt_s: float) -> None:
        """Compute (cache) the driven and coasting discretisations for steps of ``dt_s``."""
        for coasting in (False, True):
            _discrete(self.params, self.inertia_kg_m2, dt_s, coasting)

    def coefficients(self, dt_s: float, coasting: bool) -> tuple:
        """``(Ad, Bd)`` as nested tuples of floats for steps of ``dt_s`` at the present load inertia;
        driven: states ``[i, omega_m, theta_m]``, inputs ``[v, tau]``; ``coasting``: ``[omega_m, theta_m]``, ``[tau]``."""
        key = (dt_s, self.load_inertia_kg_m2, coasting)
        coef = self._coefs.get(key)
        if coef is None:                # _discrete caches the expm; this dict skips hashing the params
            if len(self._coefs) >= 16:
                self._coefs.clear()
            coef = self._coefs[key] = _discrete(self.params, self.inertia_kg_m2, dt_s, coasting)
        return coef

    def step(self, dt_s: float, voltage_v: float | None) -> None:
        """Advance ``dt_s`` with the armature voltage held at ``voltage_v`` (None: bridge open)."""
        if self.friction is None and not self.blocked:
            self._step_linear(dt_s, voltage_v, self.load_torque_nm)
            return
        (ad, bd), (cd, cb) = self.coefficients(dt_s, False), self.coefficients(dt_s, True)
        p, f = self.params, self.friction
        (self.current_a, self.speed_radps, self.angle_rad, self.stuck, self.friction_torque_nm) = friction_step(
            voltage_v is not None, 0.0 if voltage_v is None else voltage_v, self.current_a, self.speed_radps,
            self.angle_rad, self.load_torque_nm, self.blocked, self.stuck, self.friction_torque_nm,
            self.gear_ratio, self.gear_ratio * p.torque_nm_per_a, electrical_decay(p, dt_s), p.resistance_ohm,
            *((0.0, 0.0, 1.0, 0.0) if f is None else friction_terms(f)), *ad[0][:2], *ad[1][:2], *ad[2][:2],
            *bd[0], *bd[1], *bd[2], *cd[0], *cd[1], cb[0][0], cb[1][0])

    def _step_linear(self, dt_s: float, voltage_v: float | None, load_torque_nm: float) -> None:
        tau = load_torque_nm / self.gear_ratio
        coasting = voltage_v is None
        ad, bd = self.coefficients(dt_s, coasting)
        if coasting:
            (a00, a01), (a10, a11) = ad
            (b0,), (b1,) = bd
            w, th = self.speed_radps, self.angle_rad
            self.current_a = 0.0
            self.speed_radps = a00 * w + a01 * th + b0 * tau
            self.angle_rad = a10 * w + a11 * th + b1 * tau
            return
        i, w, th = self.current_a, self.speed_radps, self.angle_rad
        (a00, a01, _), (a10, a11, _), (a20, a21, _) = ad
        (b00, b01), (b10, b11), (b20, b21) = bd
        self.current_a = a00 * i + a01 * w + b00 * voltage_v + b01 * tau
        self.speed_radps = a10 * i + a11 * w + b10 * voltage_v + b11 * tau
        self.angle_rad = a20 * i + a21 * w + th + b20 * voltage_v + b21 * tau

    def no_load_output_speed_radps(self, voltage_v: float) -> float:
        """Steady output speed at ``voltage_v`` without load (friction included), rad/s."""
        p = self.params
        w = voltage_v * p.torque_nm_per_a / (p.resistance_ohm * p.friction_nm_s_per_rad
                                             + p.torque_nm_per_a * p.back_emf_v_s_per_rad)
        return w / self.gear_ratio


def electrical_decay(p: MotorParams, dt_s: float) -> float:
    """``exp(-R/L dt)``: the armature current's decay over a step with the shaft at rest."""
    return math.exp(-p.resistance_ohm / p.inductance_h * dt_s)


def friction_terms(f: GearFrictionParams) -> tuple[float, float, float, float]:
    """``(coulomb, breakaway, stribeck speed, viscous)`` of ``f`` as :func:`friction_step` takes them."""
    return float(f.coulomb_nm), float(f.breakaway_nm), float(f.stribeck_speed_radps), float(f.viscous_nm_s_per_rad)


@jitable
def friction_step(driven, voltage, i, w, th, load, blocked, stuck, friction_torque, gear, gear_km, decay, r,
                  coulomb, breakaway, stribeck, viscous, a00, a01, a10, a11, a20, a21, b00, b01, b10, b11, b20,
                  b21, c00, c01, c10, c11, cb0, cb1):
    """One step of :meth:`GearedMotor.step` with gearbox friction or a held shaft, on plain floats.

    ``driven``: the bridge applies ``voltage`` (V), else it is open. State: current (A), motor
    speed (rad/s) and angle (rad); ``load``: output-side load torque (N·m); ``blocked``,
    ``stuck``, ``friction_torque`` (N·m). Constants: gear ratio, ``gear·Km`` (N·m/A), the
    current's decay at rest (:func:`electrical_decay`), R (Ω), :func:`friction_terms`, and the
    driven ``(a, b)`` / coasting ``(c, cb)`` discretisations (:meth:`GearedMotor.coefficients`).
    Returns ``(i, w, th, stuck, friction_torque)``.
    """
    if blocked or stuck:            # armature circuit alone with the shaft at rest (exact for a held voltage)
        i = i * decay + (1.0 - decay) * voltage / r if driven else 0.0
        w = 0.0
        drive = gear_km * i - load
        if blocked or abs(drive) <= breakaway:
            return i, w, th, stuck, 0.0 if blocked else drive
        stuck = False               # breakaway: slip from rest in the direction of the drive
        direction = math.copysign(1.0, drive)
    else:
        direction = math.copysign(1.0, w)
    w_out = w / gear
    ratio = w_out / stribeck        # (squared as a product: ** is libm's pow, not always x·x)
    tf = direction * (coulomb + (breakaway - coulomb) * math.exp(-(ratio * ratio))) + viscous * w_out
    tau = (load + tf) / gear
    if driven:
        i, w, th = (a00 * i + a01 * w + b00 * voltage + b01 * tau, a10 * i + a11 * w + b10 * voltage + b11 * tau,
                    a20 * i + a21 * w + th + b20 * voltage + b21 * tau)
    else:
        i, w, th = 0.0, c00 * w + c01 * th + cb0 * tau, c10 * w + c11 * th + cb1 * tau
    if w * direction <= 0.0:        # friction stopped the shaft within the step
        w = 0.0
        stuck = True
    return i, w, th, stuck, tf
