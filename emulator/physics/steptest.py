"""Step-response helpers shared by the tests, the tuning routine and the benchmark.

Pure functions over :class:`ServoModel`; nothing here touches a clock or a port.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import units as u
from .servo_model import ServoModel

# e-Manual defaults of the items ServoModel.step reads (XH430-W210), torque on, velocity mode.
DEFAULT_TABLE: dict[str, int] = dict(
    torque_enable=1, operating_mode=u.MODE_VELOCITY, drive_mode=0, goal_pwm=885, goal_current=648,
    goal_velocity=0, goal_position=0, profile_acceleration=0, profile_velocity=0,
    velocity_i_gain=1920, velocity_p_gain=100, position_d_gain=0, position_i_gain=0,
    position_p_gain=900, feedforward_1st_gain=0, feedforward_2nd_gain=0, pwm_limit=885,
    current_limit=648, velocity_limit=1023, max_position_limit=4095, min_position_limit=0,
    moving_threshold=10, homing_offset=0, bus_watchdog=0)


def table(**items: int) -> dict[str, int]:
    """Return :data:`DEFAULT_TABLE` with ``items`` replaced."""
    unknown = set(items) - set(DEFAULT_TABLE)
    if unknown:
        raise KeyError(f"unknown control-table items: {sorted(unknown)}")
    return {**DEFAULT_TABLE, **items}


@dataclass(frozen=True)
class StepMetrics:
    """Overshoot (% of the step), 2 % settle time (s) and 10-90 % rise time (s)."""

    overshoot_pct: float
    settle_s: float
    rise_s: float
    final: float


def step_metrics(t_s: np.ndarray, y: np.ndarray, y0: float, target: float,
                 band: float = 0.02) -> StepMetrics:
    """Metrics of a step from ``y0`` to ``target`` sampled at ``t_s`` (shape (n,)), step at t = 0."""
    t_s, y = np.asarray(t_s, float), np.asarray(y, float)
    span = target - y0
    x = (y - y0) / span                               # normalised: 0 -> 1
    overshoot = max(0.0, float(x.max()) - 1.0) * 100.0
    outside = np.nonzero(np.abs(x - 1.0) > band)[0]
    settle = 0.0 if outside.size == 0 else float(t_s[min(outside[-1] + 1, len(t_s) - 1)])
    r10, r90 = np.argmax(x >= 0.1), np.argmax(x >= 0.9)
    rise = float(t_s[r90] - t_s[r10]) if x.max() >= 0.9 else float("nan")
    return StepMetrics(overshoot, settle, rise, float(y[-1]))


def simulate(model: ServoModel, items: dict[str, int], duration_s: float, dt_s: float,
             signal: str = "speed") -> tuple[np.ndarray, np.ndarray, list[dict[str, int]]]:
    """Step ``model`` for ``duration_s`` under fixed ``items``.

    Returns ``(t (n,), y (n,), outputs)`` where ``y`` is the true output-shaft speed in velocity
    units (``signal="speed"``) or angle in pulses (``signal="angle"``), after each step.
    """
    n = int(round(duration_s / dt_s))
    t = np.arange(1, n + 1) * dt_s
    y = np.empty(n)
    outs = []
    scale = u.RADPS_PER_VEL_UNIT if signal == "speed" else u.RAD_PER_PULSE
    for k in range(n):
        outs.append(model.step(dt_s, items))
        y[k] = (model.shaft_speed_radps if signal == "speed" else model.shaft_angle_rad) / scale
    return t, y, outs


def velocity_step(model: ServoModel, goal_units: int, dt_s: float, duration_s: float = 1.5,
                  **items: int) -> tuple[StepMetrics, np.ndarray, np.ndarray, list[dict[str, int]]]:
    """Velocity-mode step from rest to ``goal_units`` (0.229 rpm). Returns metrics, t, y, outputs."""
    t, y, outs = simulate(model, table(operating_mode=u.MODE_VELOCITY, goal_velocity=goal_units, **items),
                          duration_s, dt_s, "speed")
    return step_metrics(t, y, 0.0, goal_units), t, y, outs


def position_step(model: ServoModel, start_pulse: int, step_pulse: int, dt_s: float,
                  duration_s: float = 1.0, **items: int
                  ) -> tuple[StepMetrics, np.ndarray, np.ndarray, list[dict[str, int]]]:
    """Position-mode step: settle at ``start_pulse`` for 1 s, then goal += ``step_pulse``."""
    simulate(model, table(operating_mode=u.MODE_POSITION, goal_position=start_pulse, **items), 1.0, dt_s)
    y0 = model.shaft_angle_rad / u.RAD_PER_PULSE
    t, y, outs = simulate(model, table(operating_mode=u.MODE_POSITION,
                                       goal_position=start_pulse + step_pulse, **items),
                          duration_s, dt_s, "angle")
    return step_metrics(t, y, y0, start_pulse + step_pulse), t, y, outs
