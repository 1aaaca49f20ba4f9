"""DC motor + gearbox: exact ZOH, no-load speed, step-size independence."""
import numpy as np
import pytest
from scipy import signal
from scipy.integrate import solve_ivp

from swerve.emulator.physics import units as u
from swerve.emulator.physics.discrete import zoh
from swerve.emulator.physics.motor import GearedMotor, state_space
from swerve.emulator.physics.steptest import position_step, simulate, table, velocity_step

DT = 1.0 / 2000          # physics step, s (2 kHz)


def test_zoh_agrees_with_cont2discrete(cfg):
    a, b = state_space(cfg.drive_motor, cfg.drive_motor.inertia_kg_m2)
    ad, bd = zoh(a, b, DT)
    ad2, bd2, *_ = signal.cont2discrete((a, b, np.eye(3), np.zeros((3, 2))), DT, method="zoh")
    np.testing.assert_allclose(ad, ad2, rtol=1e-10, atol=1e-14)
    np.testing.assert_allclose(bd, bd2, rtol=1e-10, atol=1e-14)


def test_voltage_step_matches_ode_solution(cfg):
    m = GearedMotor(cfg.drive_motor, 212.6)
    a, b = state_space(cfg.drive_motor, cfg.drive_motor.inertia_kg_m2)
    sol = solve_ivp(lambda t, x: a @ x + b @ [12.0, 0.0], (0, 0.02), [0, 0, 0], method="Radau",
                    rtol=1e-10, atol=1e-12, dense_output=True)
    for k in range(40):
        m.step(DT, 12.0)
    np.testing.assert_allclose([m.current_a, m.speed_radps], sol.sol(40 * DT)[:2], rtol=1e-6)


def test_no_load_speed_at_full_pwm(cfg, drive):
    s = drive()
    simulate(s, table(operating_mode=u.MODE_PWM, goal_pwm=885), 0.3, DT)
    ideal = cfg.supply_voltage_v / cfg.drive_motor.back_emf_v_s_per_rad / 212.6    # V/Ke/gear
    assert s.shaft_speed_radps == pytest.approx(s.motor.no_load_output_speed_radps(12.0), rel=1e-6)
    assert s.shaft_speed_radps == pytest.approx(ideal, rel=0.05)   # friction takes 4.6 %
    assert s.shaft_speed_radps < ideal


def _halving_error(run):
    t1, y1 = run(DT)
    t2, y2 = run(DT / 2)
    return np.max(np.abs(y1 - np.interp(t1, t2, y2))) / abs(y1[-1] - y1[0])


@pytest.mark.parametrize("kind", ["pwm", "velocity", "position"])
def test_halving_the_step_changes_the_step_response_by_under_1pct(cfg, drive, steer, kind):
    g = cfg.paper_spec_gains

    def run(dt):
        if kind == "pwm":
            t, y, _ = simulate(drive(), table(operating_mode=u.MODE_PWM, goal_pwm=885), 0.1, dt)
        elif kind == "velocity":
            _, t, y, _ = velocity_step(drive(), 100, dt, 0.3, velocity_p_gain=g["velocity_p_gain"],
                                       velocity_i_gain=g["velocity_i_gain"])
        else:
            _, t, y, _ = position_step(steer(), 2048, 512, dt, 0.4, position_p_gain=g["position_p_gain"])
        return t, y

    assert _halving_error(run) < 0.01


def test_torque_off_coasts_with_zero_current(drive):
    s = drive()
    simulate(s, table(operating_mode=u.MODE_PWM, goal_pwm=885), 0.2, DT)
    w0 = s.shaft_speed_radps
    _, y, outs = simulate(s, table(operating_mode=u.MODE_PWM, goal_pwm=885, torque_enable=0), 0.05, DT)
    assert s.motor.current_a == 0.0 and outs[-1]["present_pwm"] == 0
    assert 0 < s.shaft_speed_radps < w0          # friction slows it, no back-EMF braking current
    assert s.shaft_speed_radps > 0.5 * w0        # 0.05 s << J/b = 0.14 s
