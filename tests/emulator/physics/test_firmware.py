"""Profile generator, gain divisors, anti-windup."""
import math

import pytest

from swerve.emulator.physics import units as u
from swerve.emulator.physics.firmware import (PositionGains, VelocityGains, pi_step, position_profile_step,
                                               profile_type)
from swerve.emulator.physics.servo_model import PULSE_PER_S2_PER_ACC_UNIT, PULSE_PER_S_PER_VEL_UNIT

DT = 1.0 / 2000          # physics step, s (2 kHz)


def test_gain_divisors():
    assert VelocityGains.from_table(128, 65536) == VelocityGains(1.0, 1.0)
    assert PositionGains.from_table(256, 65536, 32, 8, 4) == PositionGains(2.0, 1.0, 2.0, 2.0, 1.0)


def test_trapezoidal_profile_acceleration_time_matches_emanual():
    pv, pa = 100, 10                    # e-Manual: t1 = 64 * PV / PA ms = 640 ms
    v_max, a_max = pv * PULSE_PER_S_PER_VEL_UNIT, pa * PULSE_PER_S2_PER_ACC_UNIT
    assert profile_type(0.0, 5000.0, v_max, a_max) == u.PROFILE_TRAPEZOIDAL
    pos, vel, ongoing = 0.0, 0.0, True
    t_reach = None
    for k in range(1, int(5.0 / DT)):
        pos, vel, _, ongoing = position_profile_step(pos, vel, ongoing, DT, 5000.0, v_max, a_max)
        if t_reach is None and vel >= v_max:
            t_reach = k * DT
    assert t_reach == pytest.approx(64 * pv / pa / 1000, abs=2 * DT)
    assert pos == 5000.0 and vel == 0.0 and not ongoing


def test_short_move_is_triangular_and_rectangular_without_acceleration():
    assert profile_type(0.0, 100.0, 2000.0, 1000.0) == u.PROFILE_TRIANGULAR
    assert profile_type(0.0, 100.0, 2000.0, math.inf) == u.PROFILE_RECTANGULAR
    pos, vel, ongoing = 0.0, 0.0, True
    peak = 0.0
    for _ in range(400):
        pos, vel, _, ongoing = position_profile_step(pos, vel, ongoing, DT, 100.0, 2000.0, math.inf)
        peak = max(peak, vel)
    assert peak == 2000.0 and pos == 100.0


def test_anti_windup_keeps_integrator_bounded_in_saturation():
    ticks = DT / 1e-3                  # firmware tick 1 ms
    with_aw = without = 0.0             # the integrators, with anti-windup gain 1 and 0
    for _ in range(2000):
        out, with_aw = pi_step(with_aw, ticks, 1.0, 100.0, 1.0, 1.0, 0.0, 50.0)
        _, without = pi_step(without, ticks, 0.0, 100.0, 1.0, 1.0, 0.0, 50.0)
    assert out == 50.0
    assert abs(with_aw) < 100.0 < abs(without)
