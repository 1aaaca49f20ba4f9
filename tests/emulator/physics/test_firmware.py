"""Profile generator, gain divisors, anti-windup."""
import math

import pytest

from swerve.emulator.physics import units as u
from swerve.emulator.physics.firmware import AntiWindupPI, PositionGains, ProfileGenerator, VelocityGains
from swerve.emulator.physics.servo_model import PULSE_PER_S2_PER_ACC_UNIT, PULSE_PER_S_PER_VEL_UNIT

DT = 1.0 / 2000          # physics step, s (2 kHz)


def test_gain_divisors():
    assert VelocityGains.from_table(128, 65536) == VelocityGains(1.0, 1.0)
    assert PositionGains.from_table(256, 65536, 32, 8, 4) == PositionGains(2.0, 1.0, 2.0, 2.0, 1.0)


def test_trapezoidal_profile_acceleration_time_matches_emanual():
    pv, pa = 100, 10                    # e-Manual: t1 = 64 * PV / PA ms = 640 ms
    v_max, a_max = pv * PULSE_PER_S_PER_VEL_UNIT, pa * PULSE_PER_S2_PER_ACC_UNIT
    p = ProfileGenerator()
    p.reset(0.0)
    p.start_position(5000.0, v_max, a_max)
    assert p.profile_type == u.PROFILE_TRAPEZOIDAL
    t_reach = None
    for k in range(1, int(5.0 / DT)):
        p.step_position(DT, 5000.0, v_max, a_max)
        if t_reach is None and p.velocity >= v_max:
            t_reach = k * DT
    assert t_reach == pytest.approx(64 * pv / pa / 1000, abs=2 * DT)
    assert p.position == 5000.0 and p.velocity == 0.0 and not p.ongoing


def test_short_move_is_triangular_and_rectangular_without_acceleration():
    p = ProfileGenerator()
    p.reset(0.0)
    p.start_position(100.0, 2000.0, 1000.0)
    assert p.profile_type == u.PROFILE_TRIANGULAR
    p.start_position(100.0, 2000.0, math.inf)
    assert p.profile_type == u.PROFILE_RECTANGULAR
    peak = 0.0
    for _ in range(400):
        p.step_position(DT, 100.0, 2000.0, math.inf)
        peak = max(peak, p.velocity)
    assert peak == 2000.0 and p.position == 100.0


def test_anti_windup_keeps_integrator_bounded_in_saturation():
    with_aw, without = AntiWindupPI(1e-3, 1.0), AntiWindupPI(1e-3, 0.0)
    for _ in range(2000):
        out = with_aw.update(DT, 100.0, 1.0, 1.0, 0.0, 50.0)
        without.update(DT, 100.0, 1.0, 1.0, 0.0, 50.0)
    assert out == 50.0
    assert abs(with_aw.integral) < 100.0 < abs(without.integral)
