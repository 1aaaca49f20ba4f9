"""One servo through its raw control table: paper-spec steps, limits, modes, sensors."""
import dataclasses

import numpy as np
import pytest

from swerve.emulator.physics import units as u
from swerve.emulator.physics.steptest import position_step, simulate, table, velocity_step

DT = 1.0 / 2000          # physics step, s (2 kHz)


def test_velocity_step_with_paper_gains_overshoots_about_2pct(cfg, drive):
    g = cfg.paper_spec_gains
    m, t, y, outs = velocity_step(drive(), 100, DT, 1.0, velocity_p_gain=g["velocity_p_gain"],
                                  velocity_i_gain=g["velocity_i_gain"])
    print(f"velocity step: {m}")
    assert m.overshoot_pct == pytest.approx(2.0, abs=0.3)
    assert m.settle_s < 0.2
    assert outs[-1]["present_velocity"] == 100 and outs[-1]["velocity_trajectory"] == 100


@pytest.mark.parametrize("step", [50, 512, -512, 2000])
def test_position_step_with_paper_gains_does_not_overshoot(cfg, steer, step):
    m, t, y, outs = position_step(steer(), 2048, step, DT, 1.0,
                                  position_p_gain=cfg.paper_spec_gains["position_p_gain"])
    print(f"position step {step}: {m}")
    goal = 2048 + step
    assert (np.sign(step) * (y - goal)).max() < 0.5     # never past the goal by half a count
    assert abs(outs[-1]["present_position"] - goal) <= 1
    assert m.settle_s < 0.8


def test_higher_velocity_i_gain_is_faster_and_overshoots_more(drive):
    lo, *_ = velocity_step(drive(), 100, DT, 1.0, velocity_p_gain=100, velocity_i_gain=1920)
    hi, *_ = velocity_step(drive(), 100, DT, 1.0, velocity_p_gain=100, velocity_i_gain=4000)
    assert hi.rise_s < lo.rise_s and hi.overshoot_pct > lo.overshoot_pct + 5


def test_higher_velocity_p_gain_damps(drive):
    lo, *_ = velocity_step(drive(), 100, DT, 1.0, velocity_p_gain=100, velocity_i_gain=4000)
    hi, *_ = velocity_step(drive(), 100, DT, 1.0, velocity_p_gain=200, velocity_i_gain=4000)
    assert hi.overshoot_pct < lo.overshoot_pct


def test_higher_position_p_gain_is_faster(steer):
    lo, *_ = position_step(steer(), 2048, 50, DT, 1.0, position_p_gain=300)
    hi, *_ = position_step(steer(), 2048, 50, DT, 1.0, position_p_gain=1200)
    assert hi.rise_s < 0.5 * lo.rise_s


def test_strong_p_gain_chatters_only_with_the_filter_in_the_feedback(cfg, drive):
    fb, *_ = velocity_step(drive(), 100, DT, 1.0, velocity_p_gain=1600, velocity_i_gain=1920)
    ref_fw = dataclasses.replace(cfg.firmware, bessel_placement="reference")
    ref, *_ = velocity_step(drive(firmware=ref_fw), 100, DT, 1.0, velocity_p_gain=1600,
                            velocity_i_gain=1920)
    assert fb.overshoot_pct > 50 and ref.overshoot_pct < 5


def test_goal_pwm_and_velocity_limit_saturate(drive):
    s = drive()
    _, y, outs = simulate(s, table(goal_velocity=1000, goal_pwm=300), 0.5, DT)
    assert max(abs(o["present_pwm"]) for o in outs) <= 300
    assert y[-1] < 0.4 * 218
    s = drive()
    _, y, outs = simulate(s, table(goal_velocity=1000, velocity_limit=80), 0.8, DT)
    assert outs[-1]["present_velocity"] == 80


def test_position_limits_clamp_the_goal_in_position_mode(steer):
    s = steer()
    _, _, outs = simulate(s, table(operating_mode=u.MODE_POSITION, goal_position=3000,
                                   max_position_limit=1000), 1.5, DT)
    assert abs(outs[-1]["present_position"] - 1000) <= 1


def test_extended_position_mode_ignores_limits(steer):
    s = steer()
    _, _, outs = simulate(s, table(operating_mode=u.MODE_EXTENDED_POSITION, goal_position=5000,
                                   max_position_limit=1000), 2.0, DT)
    assert abs(outs[-1]["present_position"] - 5000) <= 1


def test_profile_drives_moving_status_and_trajectories(steer):
    s = steer()
    simulate(s, table(operating_mode=u.MODE_POSITION, goal_position=1000), 1.0, DT)
    items = table(operating_mode=u.MODE_POSITION, goal_position=2000, profile_velocity=100,
                  profile_acceleration=10)
    _, _, outs = simulate(s, items, 0.2, DT)
    o = outs[-1]
    assert o["moving"] == 1 and o["moving_status"] & u.PROFILE_ONGOING
    assert (o["moving_status"] >> 4) & 3 in (u.PROFILE_TRIANGULAR, u.PROFILE_TRAPEZOIDAL)
    assert 0 < o["velocity_trajectory"] < 100 and 1000 < o["position_trajectory"] < 2000
    _, _, outs = simulate(s, items, 3.0, DT)
    o = outs[-1]
    assert o["moving"] == 0 and o["moving_status"] & u.IN_POSITION
    assert o["position_trajectory"] == 2000


def test_velocity_profile_acceleration_ramps_the_trajectory(drive):
    _, _, outs = simulate(drive(), table(goal_velocity=200, profile_acceleration=100), 0.05, DT)
    # 100 * 214.577 rev/min^2 = 357.6 rpm/s -> after 50 ms: 17.9 rpm = 78 units
    assert outs[-1]["velocity_trajectory"] == pytest.approx(78, abs=1)


def test_torque_off_resets_integrator_and_reports_zero_pwm(drive):
    s = drive()
    simulate(s, table(goal_velocity=100), 0.5, DT)
    assert s.loop.integral != 0.0
    _, _, outs = simulate(s, table(goal_velocity=100, torque_enable=0), 0.01, DT)
    assert s.loop.integral == 0.0 and outs[-1]["present_pwm"] == 0 and outs[-1]["present_current"] == 0


def test_tripped_watchdog_stops_the_wheel(drive):
    s = drive()
    simulate(s, table(goal_velocity=150), 0.5, DT)
    _, y, outs = simulate(s, table(goal_velocity=150, bus_watchdog=u.WATCHDOG_TRIPPED), 1.0, DT)
    assert abs(outs[-1]["present_velocity"]) <= 1 and abs(y[-1]) < 1


def test_drive_mode_reverse_turns_the_shaft_the_other_way(drive):
    s = drive()
    _, _, outs = simulate(s, table(goal_velocity=100, drive_mode=1), 1.0, DT)
    assert s.shaft_speed_radps < 0 and outs[-1]["present_velocity"] == 100


def test_pwm_mode_reports_goal_pwm_and_current_mode_tracks_goal_current(drive):
    _, _, outs = simulate(drive(), table(operating_mode=u.MODE_PWM, goal_pwm=-400), 0.1, DT)
    assert outs[-1]["present_pwm"] == -400 and outs[-1]["present_velocity"] < 0
    s = drive()
    s.external_load(torque_nm=1.0)      # held against a load: the current loop settles at the goal
    _, _, outs = simulate(s, table(operating_mode=u.MODE_CURRENT, goal_current=200), 0.05, DT)
    assert outs[-1]["present_current"] == pytest.approx(200, abs=2)


def test_encoder_quantisation_and_static_sensors(drive):
    s = drive()
    _, y, outs = simulate(s, table(goal_velocity=37), 0.4, DT)
    assert outs[-1]["present_position"] == np.floor(s.shaft_angle_rad / u.RAD_PER_PULSE)
    assert outs[-1]["present_input_voltage"] == 120 and outs[-1]["present_temperature"] == 25


def test_stall_heats_the_winding(drive, cfg):
    th = dataclasses.replace(cfg.thermal, time_constant_s=1.0)
    s = drive(thermal=th)
    s.external_load(torque_nm=10.0)
    _, _, outs = simulate(s, table(operating_mode=u.MODE_PWM, goal_pwm=885), 3.0, DT)
    assert outs[-1]["present_temperature"] > 60 and outs[-1]["present_current"] > 400


def test_position_noise_is_seeded_and_visible(drive, cfg):
    noisy = dataclasses.replace(cfg.sensors, position_noise_std_pulse=2.0)
    runs = []
    for _ in range(2):
        s = drive(sensors=noisy, rng=np.random.default_rng(7))
        _, _, outs = simulate(s, table(torque_enable=0), 0.05, DT)
        runs.append([o["present_position"] for o in outs])
    assert runs[0] == runs[1] and len(set(runs[0])) > 3


def test_load_inertia_slows_the_pwm_step(drive):
    items = table(operating_mode=u.MODE_PWM, goal_pwm=885)
    t, free, _ = simulate(drive(), items, 0.2, DT)
    s = drive()
    s.external_load(0.0, 4.75 / 4 * 0.033 ** 2)     # a quarter of the robot's mass on the wheel
    _, loaded, _ = simulate(s, items, 0.2, DT)
    t63 = lambda y: t[np.argmax(y >= 0.632 * y[-1])]  # noqa: E731
    ratio = (5e-8 + 4.75 / 4 * 0.033 ** 2 / 212.6 ** 2) / 5e-8
    assert t63(loaded) / t63(free) == pytest.approx(ratio, rel=0.05)


def test_mode_switch_rewraps_position_and_resets_loop(steer):
    s = steer()
    _, _, outs = simulate(s, table(operating_mode=u.MODE_EXTENDED_POSITION, goal_position=6000), 2.0, DT)
    assert abs(outs[-1]["present_position"] - 6000) <= 1
    _, _, outs = simulate(s, table(operating_mode=u.MODE_POSITION, goal_position=6000 - 4096), 0.5, DT)
    assert abs(outs[-1]["present_position"] - (6000 - 4096)) <= 1


def test_velocity_feedforward_cuts_the_following_error(steer):
    def worst_lag(ff1):
        s = steer()
        simulate(s, table(operating_mode=u.MODE_POSITION, goal_position=1000), 1.0, DT)
        _, _, outs = simulate(s, table(operating_mode=u.MODE_POSITION, goal_position=3000, profile_velocity=100,
                                       profile_acceleration=20, position_p_gain=400,
                                       feedforward_1st_gain=ff1), 1.0, DT)
        return max(abs(o["position_trajectory"] - o["present_position"]) for o in outs)

    # FF1 ≈ 4 · 885 / (218 units · 15.6 pulse/s/unit · 1 ms) ≈ 1040 supplies the PWM the speed needs
    assert worst_lag(1000) < 0.2 * worst_lag(0)


def test_position_d_gain_damps_the_step(steer):
    plain, *_ = position_step(steer(), 2048, 50, DT, 1.0, position_p_gain=3000)
    damped, *_ = position_step(steer(), 2048, 50, DT, 1.0, position_p_gain=3000, position_d_gain=2000)
    assert damped.overshoot_pct < 0.7 * plain.overshoot_pct


def test_in_position_uses_the_limited_goal(steer):
    s = steer()
    _, _, outs = simulate(s, table(operating_mode=u.MODE_POSITION, goal_position=3000,
                                   max_position_limit=1000), 1.5, DT)
    assert outs[-1]["moving_status"] & u.IN_POSITION


def test_clear_multi_turn_and_reboot_rewrap_present_position(steer):
    s = steer()
    _, _, outs = simulate(s, table(operating_mode=u.MODE_EXTENDED_POSITION, goal_position=9000), 3.0, DT)
    assert abs(outs[-1]["present_position"] - 9000) <= 1
    s.clear_multi_turn()
    _, _, outs = simulate(s, table(operating_mode=u.MODE_EXTENDED_POSITION, goal_position=9000,
                                   torque_enable=0), 0.01, DT)
    assert abs(outs[-1]["present_position"] - 9000 % 4096) <= 1
    s.reboot()
    assert s.loop.integral == 0.0 and not s.profile.ongoing


def test_prepare_leaves_no_discretisation_for_the_first_steps(drive):
    """After prepare(dt) neither torque-on nor coasting steps compute a matrix exponential."""
    from swerve.emulator.physics import motor

    m = drive()
    m.external_load(0.0, 1.234e-3)                    # an inertia no other test uses
    m.prepare(DT)
    misses = motor._discrete.cache_info().misses
    items = table(torque_enable=1, operating_mode=u.MODE_VELOCITY, goal_velocity=50)
    for _ in range(5):
        m.step(DT, items)
    m.step(DT, dict(items, torque_enable=0))
    assert motor._discrete.cache_info().misses == misses
    assert m.outputs()["present_velocity"] != 0 or m.velocity_radps != 0.0
