"""Find control-table gains meeting the paper's loop specs on this model (Section 2.1).

- Velocity loop: about 2 % overshoot on a velocity step (true output-shaft speed), fastest 2 %
  settle among the candidates.
- Position loop (P only, ``Kpi = Kpd = 0`` as in the paper): the largest Position P gain whose
  steps show no overshoot (the true angle never passes the goal by half an encoder count).

Run ``python -m emulator.physics.tuning`` to print the gains for ``configs/emulator.yaml``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq

from .params import PhysicsConfig, load_config
from .servo_model import ServoModel, wheel_servo
from .steptest import StepMetrics, position_step, velocity_step

VELOCITY_STEP_UNITS = 100           # 22.9 rpm, 46 % of the no-load speed: the loop stays linear
POSITION_STEPS_PULSE = (50, 512, -512)


@dataclass(frozen=True)
class TunedGains:
    """Gains (raw table values) and the step metrics they give."""

    velocity_p_gain: int
    velocity_i_gain: int
    position_p_gain: int
    velocity: StepMetrics
    position: StepMetrics


def _drive(cfg: PhysicsConfig, model: str) -> ServoModel:
    return wheel_servo(cfg, model, steering=False, ideal=True)


def _steer(cfg: PhysicsConfig, model: str) -> ServoModel:
    return wheel_servo(cfg, model, steering=True, ideal=True)


def velocity_overshoot(cfg: PhysicsConfig, kp: int, ki: float, dt_s: float,
                       model: str = "xh430-w210") -> StepMetrics:
    """Metrics of the velocity step with gains ``kp``, ``ki`` (ki rounded to the table integer)."""
    m, *_ = velocity_step(_drive(cfg, model), VELOCITY_STEP_UNITS, dt_s, 1.5,
                          velocity_p_gain=int(kp), velocity_i_gain=int(round(ki)))
    return m


def tune_velocity(cfg: PhysicsConfig, dt_s: float, target_pct: float = 2.0,
                  p_grid=(40, 70, 100, 150, 200, 250, 300)) -> tuple[int, int, StepMetrics]:
    """For each P in ``p_grid`` solve (brentq) the I gain giving ``target_pct`` overshoot; keep the fastest."""
    best = None
    for kp in p_grid:
        f = lambda ki: velocity_overshoot(cfg, kp, ki, dt_s).overshoot_pct - target_pct  # noqa: E731
        lo, hi = 500.0, 16383.0
        if f(lo) > 0 or f(hi) < 0:
            continue
        ki = int(round(brentq(f, lo, hi, xtol=2.0)))
        m = velocity_overshoot(cfg, kp, ki, dt_s)
        if best is None or m.settle_s < best[2].settle_s:
            best = (kp, ki, m)
    if best is None:
        raise RuntimeError("no velocity gains reach the overshoot target")
    return best


def position_overshoots(cfg: PhysicsConfig, kp: int, dt_s: float, model: str = "xh430-w210",
                        tolerance_pulse: float = 0.5) -> bool:
    """True if a step in :data:`POSITION_STEPS_PULSE` carries the true shaft angle past the goal
    by more than ``tolerance_pulse`` (half an encoder count: invisible in Present Position)."""
    for step in POSITION_STEPS_PULSE:
        _, _, y, _ = position_step(_steer(cfg, model), 2048, step, dt_s, 0.8, position_p_gain=kp)
        past = np.sign(step) * (y - (2048 + step))
        if past.max() > tolerance_pulse:
            return True
    return False


def tune_position(cfg: PhysicsConfig, dt_s: float, lo: int = 100, hi: int = 8000) -> tuple[int, StepMetrics]:
    """Largest Position P gain without overshoot (bisection; overshoot grows with P)."""
    if position_overshoots(cfg, lo, dt_s):
        raise RuntimeError("even the lowest position gain overshoots")
    while hi - lo > 10:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if position_overshoots(cfg, mid, dt_s) else (mid, hi)
    m, *_ = position_step(_steer(cfg, "xh430-w210"), 2048, 512, dt_s, 0.8, position_p_gain=lo)
    return lo, m


def tune(cfg: PhysicsConfig, dt_s: float | None = None) -> TunedGains:
    """Tune both loops at the configured physics rate."""
    dt_s = dt_s or 1.0 / cfg.rate_hz
    kvp, kvi, vm = tune_velocity(cfg, dt_s)
    kpp, pm = tune_position(cfg, dt_s)
    return TunedGains(kvp, kvi, kpp, vm, pm)


if __name__ == "__main__":
    g = tune(load_config())
    print(f"velocity_p_gain: {g.velocity_p_gain}\nvelocity_i_gain: {g.velocity_i_gain}\n"
          f"position_p_gain: {g.position_p_gain}\n# velocity {g.velocity}\n# position {g.position}")
