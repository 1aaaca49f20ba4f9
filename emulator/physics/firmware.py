"""The servo firmware's loops as the e-Manual describes them (docs/reference/protocol.md §5).

The controllers work in the firmware's own units, because that is what the control-table gains
are defined in: errors in encoder units (pulse, 0.229 rpm velocity unit), outputs in PWM counts
(885 = 100 %). One firmware "tick" is ``tick_s`` (``firmware.gain_time_base_s``, 1 ms by default):
integral gains add ``K·e`` per tick, derivative and feed-forward gains act on per-tick differences.
The physics step may differ from the tick; the gains are rescaled by ``dt / tick`` so the
behaviour does not depend on the physics rate.

Gain divisors: velocity P/128, velocity I/65536, position P/128, position I/65536,
position D/16, feed-forward 1st and 2nd /4.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from . import units as u
from .jit import jitable


@dataclass(frozen=True)
class VelocityGains:
    """Velocity PI in firmware units: PWM counts per velocity unit (per tick for ``ki``)."""

    kp: float
    ki: float

    @classmethod
    def from_table(cls, p_gain: int, i_gain: int) -> "VelocityGains":
        """Convert Velocity P (78) / I (76) gain items."""
        return cls(kp=p_gain / 128.0, ki=i_gain / 65536.0)


@dataclass(frozen=True)
class PositionGains:
    """Position PID + feed-forward in firmware units (PWM counts per pulse, per tick)."""

    kp: float
    ki: float
    kd: float
    ff1: float
    ff2: float

    @classmethod
    def from_table(cls, p_gain: int, i_gain: int, d_gain: int, ff1_gain: int,
                   ff2_gain: int) -> "PositionGains":
        """Convert Position P (84) / I (82) / D (80) and Feedforward 1st (90) / 2nd (88) items."""
        return cls(kp=p_gain / 128.0, ki=i_gain / 65536.0, kd=d_gain / 16.0,
                   ff1=ff1_gain / 4.0, ff2=ff2_gain / 4.0)


class AntiWindupPI:
    """PI(D) core with output saturation and back-calculation anti-windup (gain ``Ka``).

    Parameters
    ----------
    tick_s : float
        Firmware tick the I gain refers to, s.
    anti_windup_gain : float
        Share of the saturation excess fed back into the integrator per tick.
    """

    def __init__(self, tick_s: float, anti_windup_gain: float):
        self.tick_s = tick_s
        self.ka = anti_windup_gain
        self.integral = 0.0

    def reset(self) -> None:
        """Clear the integrator (torque off, mode switch)."""
        self.integral = 0.0


@jitable
def pi_step(integral: float, ticks: float, ka: float, error: float, kp: float, ki: float, extra: float,
            limit: float) -> tuple[float, float]:
    """One step of the PI(D) core on plain floats: the saturated output
    ``clamp(kp e + I + extra, ±limit)`` and the new integral ``I``, as ``(output, integral)``.

    ``ticks`` is the step in firmware ticks (``dt_s / tick_s``), ``ka`` the anti-windup gain
    (:class:`AntiWindupPI` holds both and the integral between steps).
    """
    integral += ki * error * ticks
    raw = kp * error + integral + extra
    out = -limit if raw < -limit else limit if raw > limit else raw
    if out != raw:                  # back-calculation unwinds the integrator, never past zero
        unwound = integral + ka * min(ticks, 1.0) * (out - raw)
        integral = unwound if unwound * integral > 0.0 else 0.0
    return out, integral


class ProfileGenerator:
    """Velocity-based profile (rectangular / triangular / trapezoidal), in firmware units.

    Position profiles use pulses, pulse/s and pulse/s²; velocity profiles use velocity units and
    velocity units per second. ``inf`` limits mean "no profile" (a step).
    """

    def __init__(self):
        self.position = 0.0
        self.velocity = 0.0
        self.acceleration = 0.0
        self.profile_type = u.PROFILE_NONE
        self.ongoing = False

    def reset(self, position: float, velocity: float = 0.0) -> None:
        """Restart from a measured state (torque on, mode switch)."""
        self.position, self.velocity, self.acceleration = position, velocity, 0.0
        self.ongoing = False


@jitable
def profile_type(position: float, goal: float, v_max: float, a_max: float) -> int:
    """Profile type (Moving Status bits 5:4 as 0..3) of a move from ``position`` to ``goal``."""
    if math.isinf(v_max):
        return u.PROFILE_NONE
    if math.isinf(a_max):
        return u.PROFILE_RECTANGULAR
    dist = abs(goal - position)
    reach = v_max * v_max / a_max          # distance to accelerate to v_max and stop again
    return u.PROFILE_TRAPEZOIDAL if dist >= reach else u.PROFILE_TRIANGULAR


@jitable
def position_profile_step(position: float, velocity: float, ongoing: bool, dt_s: float,
                          goal: float, v_max: float, a_max: float) -> tuple[float, float, float, bool]:
    """Advance a position trajectory one step towards ``goal`` (time-optimal under the limits),
    on plain floats: the new ``(position, velocity, acceleration, ongoing)``."""
    v0 = velocity
    if math.isinf(v_max):
        return goal, 0.0, 0.0, False
    d = goal - position
    s = 1.0 if d >= 0 else -1.0
    v_cmd = s * min(v_max, math.sqrt(2.0 * a_max * abs(d)) if not math.isinf(a_max) else v_max)
    dv = a_max * dt_s
    v1 = v_cmd if abs(v_cmd - v0) <= dv else v0 + math.copysign(dv, v_cmd - v0)
    step = 0.5 * (v0 + v1) * dt_s
    if abs(d) <= abs(step) or (abs(d) <= abs(v1) * dt_s and abs(v1) <= dv + 1e-12):
        position, v1, ongoing = goal, 0.0, False
    else:
        position += step
    return position, v1, (v1 - v0) / dt_s, ongoing


@jitable
def velocity_profile_step(position: float, velocity: float, dt_s: float, goal: float,
                          a_max: float) -> tuple[float, float, float, bool]:
    """Advance a velocity trajectory one step towards ``goal``, at most ``a_max`` per second, on
    plain floats: the new ``(position, velocity, acceleration, ongoing)``."""
    v0 = velocity
    dv = a_max * dt_s
    v1 = goal if abs(goal - v0) <= dv else v0 + math.copysign(dv, goal - v0)
    return position + 0.5 * (v0 + v1) * dt_s, v1, (v1 - v0) / dt_s, v1 != goal
