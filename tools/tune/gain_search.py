"""Gain design: search control-table gains that meet a step-response spec on the identified model.

The model is the emulator's own servo (:class:`emulator.physics.servo_model.ServoModel`: profile
generator, velocity PI / position PID with anti-windup, Bessel velocity filter, DC motor) with
the identified motor constants, stepped by :mod:`emulator.physics.steptest`. Gains are raw
control-table integers (their only unit); everything else is SI.

- Velocity loop (drive servos): for each Velocity P gain on a grid, the Velocity I gain that
  gives the target overshoot (``brentq``; overshoot grows with I), then the fastest 2 % settle.
- Position loop (steering servos, P only as in the paper): the largest Position P gain whose
  steps never carry the true shaft past the goal (bisection; overshoot grows with P).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from swerve.driver.errors import SwerveError
from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import FirmwareParams, GearFrictionParams, MotorParams
from swerve.emulator.physics.servo_model import ServoModel
from swerve.emulator.physics.steptest import StepMetrics, simulate, step_metrics, table, velocity_step

VELOCITY_P_GRID = (50, 100, 150, 200, 300, 400, 600, 800)
GAIN_MAX = 16383


class DesignError(SwerveError):
    """No gains on the search grid meet the spec (the message says what was closest)."""


@dataclass(frozen=True)
class Spec:
    """Step-response requirements (SI; fractions, not percent).

    Attributes
    ----------
    velocity_overshoot_max : float
        Largest velocity-step overshoot, fraction of the step (paper: about 0.02).
    position_overshoot_max_rad : float
        How far the true shaft may pass a position goal, rad (default half an encoder count:
        invisible in Present Position, i.e. "no overshoot").
    velocity_settle_max_s, position_settle_max_s : float
        Upper bounds on the 2 % settle time, s (``inf``: none, just the fastest).
    velocity_step_radps : float
        Output-shaft velocity step used to design and verify, rad/s.
    position_step_rad : float
        Position step, rad (the design also checks the reverse step).
    margin : float
        Design overshoot target as a fraction of the allowed maximum (model error allowance).
    """

    velocity_overshoot_max: float = 0.02
    position_overshoot_max_rad: float = 0.5 * u.RAD_PER_PULSE
    velocity_settle_max_s: float = math.inf
    position_settle_max_s: float = math.inf
    velocity_step_radps: float = 100 * u.RADPS_PER_VEL_UNIT
    position_step_rad: float = 512 * u.RAD_PER_PULSE
    margin: float = 0.75

    def __post_init__(self):
        if not 0.0 < self.velocity_overshoot_max < 1.0:
            raise DesignError(f"velocity overshoot limit {self.velocity_overshoot_max:g} must be in (0, 1)")
        if self.position_overshoot_max_rad < 0:
            raise DesignError("position overshoot limit must be >= 0")
        if not 0.0 < self.margin <= 1.0:
            raise DesignError("design margin must be in (0, 1]")


@dataclass(frozen=True)
class Prediction:
    """Predicted step of the model: metrics on the true shaft and on what the servo reports.

    ``true`` uses the shaft speed/angle; ``reported`` uses Present Velocity / Present Position
    (Bessel-filtered, quantised), which is what a measurement can be compared with.
    ``t_s``, ``y_true``, ``y_reported``: arrays, shape (n,), SI (rad/s or rad).
    """

    true: StepMetrics
    reported: StepMetrics
    t_s: np.ndarray = field(repr=False)
    y_true: np.ndarray = field(repr=False)
    y_reported: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class Design:
    """Gains (raw control-table values) and the predicted steps."""

    gains: dict[str, int]
    velocity: Prediction | None = None
    position: Prediction | None = None
    searched: list = field(default_factory=list, repr=False)


@dataclass(frozen=True)
class Plant:
    """What the design simulates: identified motor, gear, supply, firmware assumptions."""

    params: MotorParams
    gear_ratio: float
    supply_voltage_v: float = 12.0
    firmware: FirmwareParams = FirmwareParams()
    dt_s: float = 1e-3
    coulomb_nm: float = 0.0
    """Identified Coulomb friction at the output, N m (static taken equal; 0 = viscous only)."""

    def model(self) -> ServoModel:
        """A fresh noiseless servo model."""
        friction = (GearFrictionParams(coulomb_nm=self.coulomb_nm, static_nm=self.coulomb_nm)
                    if self.coulomb_nm > 0.0 else None)
        return ServoModel(self.params, self.gear_ratio, self.supply_voltage_v, self.firmware, friction=friction)


def predict_velocity(plant: Plant, gains: dict[str, int], step_radps: float,
                     duration_s: float = 1.0) -> Prediction:
    """Simulate a velocity-mode step from rest to ``step_radps`` with ``gains``."""
    goal = round(step_radps / u.RADPS_PER_VEL_UNIT)
    m, t, y, outs = velocity_step(plant.model(), goal, plant.dt_s, duration_s,
                                  velocity_p_gain=gains["velocity_p_gain"],
                                  velocity_i_gain=gains["velocity_i_gain"])
    rep = np.array([o["present_velocity"] for o in outs], float)
    return Prediction(m, step_metrics(t, rep, 0.0, goal), t, y * u.RADPS_PER_VEL_UNIT,
                      rep * u.RADPS_PER_VEL_UNIT)


def predict_position(plant: Plant, gains: dict[str, int], step_rad: float, start_rad: float = math.pi,
                     duration_s: float = 0.8) -> Prediction:
    """Simulate a position-mode step of ``step_rad`` from rest at ``start_rad``.

    The model starts at rest on ``start_rad`` and gets the new goal on its first tick, which is
    what a settled servo sees (no settling phase needs simulating).
    """
    start, step = round(start_rad / u.RAD_PER_PULSE), round(step_rad / u.RAD_PER_PULSE)
    items = {k: gains[k] for k in ("position_p_gain", "position_i_gain", "position_d_gain") if k in gains}
    model = plant.model()
    model.set_shaft_angle((start + 0.5) * u.RAD_PER_PULSE)          # mid-pulse: Present Position = start
    t, y, outs = simulate(model, table(operating_mode=u.MODE_POSITION, goal_position=start + step, **items),
                          duration_s, plant.dt_s, "angle")
    rep = np.array([o["present_position"] for o in outs], float)
    return Prediction(step_metrics(t, y, float(start), start + step), step_metrics(t, rep, float(start), start + step),
                      t, (y - start) * u.RAD_PER_PULSE, (rep - start) * u.RAD_PER_PULSE)


def design_velocity(plant: Plant, spec: Spec, p_grid=VELOCITY_P_GRID) -> Design:
    """Velocity P/I meeting ``spec`` with the fastest settle.

    Raises
    ------
    DesignError
        If no P on ``p_grid`` reaches the overshoot target with an I gain in range, or none
        settles within ``spec.velocity_settle_max_s``.
    """
    target = 100.0 * spec.velocity_overshoot_max * spec.margin          # percent

    def overshoot(kp, ki):                 # 0.6 s shows the peak; a slower settle loses anyway
        return predict_velocity(plant, {"velocity_p_gain": kp, "velocity_i_gain": int(round(ki))},
                                spec.velocity_step_radps, duration_s=0.6).true

    searched, best = [], None
    for kp in p_grid:
        lo, hi = 1.0, float(GAIN_MAX)
        if overshoot(kp, lo).overshoot_pct > target:
            searched.append((kp, None, "overshoots even with I = 1"))
            continue
        if overshoot(kp, hi).overshoot_pct < target:
            ki = GAIN_MAX
        else:
            ki = int(brentq(lambda k: overshoot(kp, k).overshoot_pct - target, lo, hi, xtol=4.0))
            while ki > 1 and overshoot(kp, ki).overshoot_pct > target:   # land on the safe side
                ki -= max(1, ki // 100)
        m = overshoot(kp, ki)
        searched.append((kp, ki, m))
        if m.settle_s <= spec.velocity_settle_max_s and (best is None or m.settle_s < best[2].settle_s):
            best = (kp, ki, m)
    if best is None:
        tried = [s for s in searched if s[1] is not None]
        closest = min(tried, key=lambda s: s[2].settle_s) if tried else None
        why = (f"fastest found: P={closest[0]}, I={closest[1]} settles in {closest[2].settle_s * 1e3:.0f} ms"
               if closest else "every P on the grid overshoots")
        raise DesignError(f"no velocity gains meet the spec (overshoot <= {100 * spec.velocity_overshoot_max:g} %, "
                          f"settle <= {spec.velocity_settle_max_s * 1e3:g} ms) on the identified model; {why}")
    gains = {"velocity_p_gain": int(best[0]), "velocity_i_gain": int(best[1])}
    return Design(gains, velocity=predict_velocity(plant, gains, spec.velocity_step_radps), searched=searched)


def _position_overshoot_rad(plant: Plant, kp: int, spec: Spec) -> float:
    worst = -math.inf
    for step in (spec.position_step_rad, -spec.position_step_rad):
        pr = predict_position(plant, {"position_p_gain": kp}, step)
        worst = max(worst, float(np.max(np.sign(step) * (pr.y_true - step))))
    return worst


def design_position(plant: Plant, spec: Spec, lo: int = 50, hi: int = GAIN_MAX) -> Design:
    """Largest Position P gain (I = D = 0) without overshoot, if it settles in time.

    Raises
    ------
    DesignError
        If even ``lo`` overshoots, or the best gain does not settle within
        ``spec.position_settle_max_s``.
    """
    limit = spec.position_overshoot_max_rad
    if _position_overshoot_rad(plant, lo, spec) > limit:
        raise DesignError(f"even Position P gain {lo} overshoots on the identified model")
    if _position_overshoot_rad(plant, hi, spec) <= limit:
        lo = hi
    while hi - lo > max(4, lo // 100):
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if _position_overshoot_rad(plant, mid, spec) > limit else (mid, hi)
    gains = {"position_p_gain": int(lo), "position_i_gain": 0, "position_d_gain": 0}
    pred = predict_position(plant, gains, spec.position_step_rad)
    if pred.true.settle_s > spec.position_settle_max_s:
        raise DesignError(f"no Position P gain meets the spec: the largest without overshoot (P={lo}) settles "
                          f"in {pred.true.settle_s * 1e3:.0f} ms > {spec.position_settle_max_s * 1e3:g} ms")
    return Design(gains, position=pred)
