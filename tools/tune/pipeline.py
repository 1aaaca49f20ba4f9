"""The whole ``swerve tune`` sequence on one servo: experiments, identification, design, verification.

Everything is SI except the gains (raw control-table integers, their only unit).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from swerve.driver.control_table import Reg
from swerve.emulator.physics.params import FirmwareParams, MotorParams
from swerve.emulator.physics.steptest import StepMetrics, step_metrics
from swerve.tools.tune.gain_search import Design, DesignError, Plant, Prediction, Spec, design_position, design_velocity
from swerve.tools.tune.gain_search import predict_position, predict_velocity
from swerve.tools.tune.experiments import Experimenter, Limits, SafetyError, servo_session
from swerve.tools.run.ticker import Clock
from swerve.tools.tune.identify import FITTED, Identification, PwmRecord, identify

BRAKE_S = 0.08                 # PWM 0 (motor short-circuited) between the driven steps
STEP_S_MAX = 0.2
VELOCITY_GAINS = ("velocity_p_gain", "velocity_i_gain")
POSITION_GAINS = ("position_p_gain", "position_i_gain", "position_d_gain")


@dataclass(frozen=True)
class Loop:
    """One closed-loop step: measured and predicted, before (original gains) or after tuning."""

    gains: dict[str, int]
    record: dict = field(repr=False)
    measured: StepMetrics
    predicted: Prediction


@dataclass(frozen=True)
class TuneResult:
    """Everything ``swerve tune`` found for one servo."""

    id: int
    group: str                      # "drive" (velocity loop) or "steering" (position loop)
    model: str
    gear_ratio: float
    supply_voltage_v: float
    clock: str
    pwm: list[PwmRecord] = field(repr=False)
    identification: Identification = field(repr=False)
    design: Design = field(repr=False)
    before: Loop = field(repr=False)
    after: Loop = field(repr=False)
    meets_spec: bool
    spec_notes: list[str]


def _ignore(seconds: float) -> None:
    """A progress callback that shows nothing."""


def no_load_speed_radps(p: MotorParams, gear_ratio: float, volts: float) -> float:
    """Steady output speed at ``volts`` without load, rad/s."""
    return volts * p.torque_nm_per_a / (p.resistance_ohm * p.friction_nm_s_per_rad
                                        + p.torque_nm_per_a * p.back_emf_v_s_per_rad) / gear_ratio


def pwm_plan(prior: MotorParams, gear_ratio: float, supply_v: float, limits: Limits, duty_max: float,
             start_rad: float) -> list[tuple[float, float]]:
    """Open-loop steps ``[(duration_s, duty)]`` that stay inside ``limits`` by the prior model.

    Two amplitudes in both directions with short-circuit braking in between; the amplitude is
    cut so the prior's no-load speed stays below 90 % of the speed limit, the durations so each
    step travels at most 40 % of the distance to the nearer range limit.

    Raises
    ------
    SafetyError
        If the range leaves less than five mechanical time constants of motion.
    """
    w1 = no_load_speed_radps(prior, gear_ratio, supply_v)
    duty = min(duty_max, 0.9 * limits.speed_max_radps / w1)
    room = min(start_rad - limits.position_min_rad, limits.position_max_rad - start_rad)
    step_s = min(STEP_S_MAX, 0.4 * room / (duty * w1))
    tau = prior.inertia_kg_m2 * prior.resistance_ohm / (prior.resistance_ohm * prior.friction_nm_s_per_rad
                                                         + prior.back_emf_v_s_per_rad * prior.torque_nm_per_a)
    if step_s < 5 * tau or duty < 0.05:
        raise SafetyError(f"the safe range ({room:.3f} rad from the start) or speed limit leaves no room for a "
                          f"PWM step: need {5 * tau * duty * w1 / 0.4:.3f} rad at {duty:.0%} PWM")
    return [(step_s, duty), (BRAKE_S, 0.0), (step_s, -duty), (BRAKE_S, 0.0),
            (step_s, 0.6 * duty), (BRAKE_S, 0.0), (step_s, -0.6 * duty)]


def _measured(record: dict) -> StepMetrics:
    return step_metrics(record["t_s"], record["y"], record["y0"], record["goal"])


def tune_servo(bus, id_: int, group: str, spec: Spec, prior: MotorParams, *, limits: Limits,
               firmware: FirmwareParams = FirmwareParams(), center_rad: float | None = None,
               duty_max: float = 0.5, ci_target: float = 0.02, max_pwm_runs: int = 4,
               progress: Callable[[str], Callable[[float], None]] | None = None,
               clock: Clock | None = None) -> TuneResult:
    """Run the experiments on servo ``id_``, identify its motor, design and verify gains.

    Parameters
    ----------
    bus : driver.bus.Bus
        Open bus.
    id_ : int
        Servo ID.
    group : {"drive", "steering"}
        Drive servos get the velocity loop tuned (velocity steps), steering servos the position
        loop (position steps about ``center_rad``).
    spec : Spec
        Step-response requirements.
    prior : MotorParams
        Start values; L and Km stay at these (not identifiable).
    limits : Limits
        Safety envelope (range, speed, current).
    firmware : FirmwareParams
        Firmware-loop assumptions of the design model.
    center_rad : float, optional
        Steering: where the experiments start (the wheel's straight-ahead angle).
    duty_max : float
        Largest PWM duty for the open-loop steps (0..1).
    ci_target, max_pwm_runs : float, int
        The PWM experiment is repeated (all runs fitted together, at most ``max_pwm_runs``)
        until every fitted parameter's 95 % interval half-width is within ``ci_target`` of
        its value: a slow or busy bus gives sparse samples.
    progress : callable, optional
        ``progress(phase)`` returns an ``update(seconds)`` callback.
    clock : swerve.tools.run.ticker.Clock, optional
        Experiment time (:class:`~swerve.tools.tune.experiments.Experimenter`): the host's
        monotonic clock by default; a lockstep emulator's robot time makes runs repeatable.

    Returns
    -------
    TuneResult
        Torque off, operating mode restored; the new gains are left in the servo's RAM if the
        verification step met ``spec`` (``meets_spec``), else the original gains are back.
    """
    if group not in ("drive", "steering"):
        raise ValueError(f"group must be 'drive' or 'steering', got {group!r}")
    progress = progress or (lambda phase: _ignore)
    _check_steps(group, spec, limits, center_rad)
    table = bus.table(id_)
    gear = float(table.gear_ratio)
    exp = Experimenter(bus, id_, limits, clock=clock)
    with servo_session(bus, id_) as state:
        names = VELOCITY_GAINS if group == "drive" else POSITION_GAINS
        original = {n: int(state[n]) for n in names}
        supply = bus.read_si(id_, Reg.PRESENT_INPUT_VOLTAGE)
        exp.progress = progress("experiments") or _ignore
        records, ident = [], None
        for _ in range(max_pwm_runs):       # repeat until every fitted parameter is tight enough
            if group == "steering":
                exp.move_to(center_rad)
            start = bus.read_si(id_, Reg.PRESENT_POSITION)
            plan = pwm_plan(prior, gear, supply, limits, duty_max, start)
            record, trace = exp.pwm_steps(plan, prior, gear)
            records.append(record)
            supply = float(np.mean(trace.raw(Reg.PRESENT_INPUT_VOLTAGE)) * table[Reg.PRESENT_INPUT_VOLTAGE].scale)
            progress("identify")
            ident = identify(records, gear, prior, position_lsb_rad=table[Reg.PRESENT_POSITION].scale,
                             current_lsb_a=table[Reg.PRESENT_CURRENT].scale)
            if worst_ci(ident) <= ci_target:
                break
            exp.progress = progress("experiments (again: 95 % interval too wide)") or _ignore
        before_rec = _closed_loop(exp, group, original, spec, center_rad)
        plant = Plant(ident.params, gear, supply, firmware, coulomb_nm=ident.coulomb_nm)
        progress("design")
        try:
            design = design_velocity(plant, spec) if group == "drive" else design_position(plant, spec)
        except DesignError as exc:
            raise DesignError(f"{exc}; torque is off and the original gains are kept") from None
        progress("verify")
        after_rec = _closed_loop(exp, group, design.gains, spec, center_rad)
        after = Loop(dict(design.gains), after_rec, _measured(after_rec), _predict(plant, group, design.gains, spec))
        ok, notes = check_spec(group, spec, after, ident, table[Reg.PRESENT_VELOCITY].scale,
                               table[Reg.PRESENT_POSITION].scale)
        if ok:                          # otherwise the session puts the original gains back
            state["new_gains"] = dict(design.gains)
    before = Loop(original, before_rec, _measured(before_rec), _predict(plant, group, original, spec))
    clock = trace.times()[3]
    return TuneResult(id_, group, table.model, gear, supply, clock, records, ident, design, before, after,
                      ok, notes + [f"{len(records)} PWM run(s), widest 95 % interval +-{100 * worst_ci(ident):.1f} %"])


def _check_steps(group: str, spec: Spec, limits: Limits, center_rad: float | None) -> None:
    """Refuse steps that would leave the safe envelope, before anything moves."""
    if group == "drive" and not abs(spec.velocity_step_radps) < limits.speed_max_radps:
        raise SafetyError(f"velocity step {spec.velocity_step_radps:.2f} rad/s is not below the speed limit "
                          f"{limits.speed_max_radps:.2f} rad/s; nothing was moved")
    if group == "steering":
        if center_rad is None:
            raise ValueError("steering servos need center_rad")
        half = 0.5 * abs(spec.position_step_rad)
        if not limits.position_min_rad <= center_rad - half and center_rad + half <= limits.position_max_rad:
            raise SafetyError(f"position step of {spec.position_step_rad:.3f} rad about {center_rad:.3f} rad leaves "
                              f"the safe range [{limits.position_min_rad:.3f}, {limits.position_max_rad:.3f}] rad; "
                              "nothing was moved")


def worst_ci(ident: Identification) -> float:
    """Largest relative 95 % half-width among the identified parameters."""
    return max(ident.estimates[name].rel_halfwidth for name in FITTED)


def _closed_loop(exp: Experimenter, group: str, gains: dict[str, int], spec: Spec,
                 center_rad: float | None) -> dict:
    if group == "drive":
        return exp.velocity_step(gains, spec.velocity_step_radps)[0]
    return exp.position_step(gains, center_rad - 0.5 * spec.position_step_rad, spec.position_step_rad)[0]


def _predict(plant: Plant, group: str, gains: dict[str, int], spec: Spec) -> Prediction:
    if group == "drive":
        return predict_velocity(plant, gains, spec.velocity_step_radps)
    return predict_position(plant, gains, spec.position_step_rad)


def check_spec(group: str, spec: Spec, after: Loop, ident: Identification, velocity_lsb_radps: float,
               position_lsb_rad: float) -> tuple[bool, list[str]]:
    """Does the measured step after tuning meet ``spec``, allowing for the sensor's resolution?

    Tolerance: one LSB of the reported signal plus three standard deviations of the position
    noise seen at rest (the overshoot of a quantised, noisy signal cannot be read any finer).
    """
    m, notes = after.measured, []
    if group == "drive":
        step = after.record["goal"]
        lsb = 100.0 * velocity_lsb_radps / abs(step)
        limit = 100.0 * spec.velocity_overshoot_max
        ok = m.overshoot_pct <= limit + lsb
        notes.append(f"velocity overshoot {m.overshoot_pct:.2f} % (limit {limit:g} % + {lsb:.2f} % for 1 LSB)")
        if math.isfinite(spec.velocity_settle_max_s):
            ok &= m.settle_s <= spec.velocity_settle_max_s
            notes.append(f"settle {m.settle_s * 1e3:.0f} ms (limit {spec.velocity_settle_max_s * 1e3:g} ms)")
    else:
        span = after.record["goal"] - after.record["y0"]
        past_rad = m.overshoot_pct / 100.0 * abs(span)
        lsb = position_lsb_rad
        tol = spec.position_overshoot_max_rad + lsb + 3 * ident.noise_std["position_pulse"] * lsb
        ok = past_rad <= tol
        notes.append(f"position overshoot {past_rad / lsb:.1f} pulse (tolerance {tol / lsb:.1f} pulse)")
        if math.isfinite(spec.position_settle_max_s):
            ok &= m.settle_s <= spec.position_settle_max_s
            notes.append(f"settle {m.settle_s * 1e3:.0f} ms (limit {spec.position_settle_max_s * 1e3:g} ms)")
    return bool(ok), notes
