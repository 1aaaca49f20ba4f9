"""The world can disagree with the controller: profiles, gearbox friction, tyre contact, tolerances,
supply sag and protection, on the pure physics (no bus)."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from swerve.configs import shipped
from swerve.core.errors import ConfigError
from swerve.driver.control_table import HardwareError
from swerve.emulator.physics import units as u
from swerve.emulator.physics.body import RobotBody
from swerve.emulator.physics.contact import ContactBody, static_normal_loads_n, wheel_coupling_number
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.profiles import EFFECTS, resolve_emulator_config, single_effect
from swerve.emulator.physics.robot import RobotPhysics, load_robot_geometry
from swerve.emulator.physics.servo_model import ServoModel

IDEAL = load_config(resolve_emulator_config("ideal"))
REAL = load_config(resolve_emulator_config("realistic"))
GEO = load_robot_geometry(shipped("robot.yaml"))
GEAR = IDEAL.gear_ratio("xh430-w210")
DT = 1e-3


def items(mode: int, **kw) -> dict[str, int]:
    t = dict(torque_enable=1, operating_mode=mode, drive_mode=0, goal_pwm=885, goal_current=0, goal_velocity=0,
             goal_position=2048, profile_acceleration=0, profile_velocity=0, velocity_i_gain=4543,
             velocity_p_gain=250, position_d_gain=0, position_i_gain=0, position_p_gain=1310,
             feedforward_1st_gain=0, feedforward_2nd_gain=0, pwm_limit=885, current_limit=648,
             velocity_limit=210, max_position_limit=4095, min_position_limit=0, moving_threshold=10,
             homing_offset=0, bus_watchdog=0)
    t.update(kw)
    return t


def wheel_tables(speeds_mps, steer_rad) -> dict[int, dict[str, int]]:
    """Goal tables for the 8 servos: per-wheel ground speed (m/s) and steering angle (rad)."""
    out = {}
    for w, v, d in zip(GEO.wheels, speeds_mps, steer_rad):
        out[w.drive_id] = items(u.MODE_VELOCITY, goal_velocity=round(
            w.drive_direction * v / GEO.wheel_radius_m / u.RADPS_PER_VEL_UNIT))
        out[w.steer_id] = items(u.MODE_POSITION, goal_position=round(
            w.center_pulse + w.steer_direction * d / u.RAD_PER_PULSE))
    return out


def drive(cfg, speeds, steer, duration_s: float, dt_s: float = DT) -> RobotPhysics:
    robot = RobotPhysics(cfg, GEO, np.random.default_rng(0))
    tables = wheel_tables(speeds, steer)
    for _ in range(round(duration_s / dt_s)):
        robot.step(dt_s, tables)
    return robot


# ---- profiles -----------------------------------------------------------------------------------
def test_ideal_profile_is_the_shipped_emulator_config_with_every_effect_off():
    assert resolve_emulator_config("ideal") == shipped("emulator.yaml")
    assert not IDEAL.contact.enabled and not IDEAL.protection.enabled and not IDEAL.supply.enabled
    assert not IDEAL.drive_friction.enabled and not IDEAL.tolerances.enabled
    assert isinstance(RobotPhysics(IDEAL, GEO).body, RobotBody)


def test_realistic_profile_switches_every_effect_on_over_the_same_motor():
    assert REAL.contact.enabled and REAL.protection.enabled and REAL.supply.enabled
    assert REAL.drive_friction.enabled and REAL.tolerances.enabled
    assert REAL.drive_motor == IDEAL.drive_motor and REAL.firmware == IDEAL.firmware
    for effect, fields in EFFECTS.items():       # each effect alone changes only its own fields
        one = single_effect(IDEAL, REAL, effect)
        changed = {f.name for f in dataclasses.fields(one) if getattr(one, f.name) != getattr(IDEAL, f.name)}
        assert changed == set(fields), effect


def test_unknown_profile_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="not a profile"):
        resolve_emulator_config("realstic")
    path = tmp_path / "mine.yaml"
    path.write_text("x: 1\n")
    assert resolve_emulator_config(path) == path


@pytest.mark.parametrize("section, text, match", [
    ("contact", "contact: {enabled: 1}", "contact.enabled"),
    ("tolerances", "tolerances: {wheel_radius_scale: [1, 1]}", "tolerances.wheel_radius_scale"),
    ("gearbox_friction", "gearbox_friction: {drive: {coulomb_nm: 0.05, static_nm: 0.01}}", "static_nm"),
], ids=["flag", "list-length", "static-below-coulomb"])
def test_bad_realism_sections_name_the_key(tmp_path, section, text, match):
    path = tmp_path / "bad.yaml"
    path.write_text(shipped("emulator.yaml").read_text() + "\n" + text + "\n")
    with pytest.raises(ConfigError, match=match):
        load_config(path)


# ---- gearbox friction ----------------------------------------------------------------------------
def test_breakaway_pwm_matches_the_configured_static_torque():
    f = REAL.drive_friction
    m = REAL.drive_motor
    expected = f.breakaway_nm / (GEAR * m.torque_nm_per_a) * m.resistance_ohm / REAL.supply_voltage_v * 885
    servo = ServoModel(m, GEAR, REAL.supply_voltage_v, REAL.firmware, friction=f)
    first_moving = None
    for pwm in range(0, 40):
        start = servo.shaft_angle_rad
        for _ in range(200):
            servo.step(DT, items(u.MODE_PWM, goal_pwm=pwm))
        if servo.shaft_angle_rad != start:
            first_moving = pwm
            break
        assert servo.shaft_speed_radps == 0.0       # stuck means exactly at rest: no creep, no chatter
    assert first_moving == math.ceil(expected)     # 20.6 counts -> the shaft starts at 21
    ideal = ServoModel(m, GEAR, IDEAL.supply_voltage_v, IDEAL.firmware)
    ideal.step(DT, items(u.MODE_PWM, goal_pwm=1))
    ideal.step(DT, items(u.MODE_PWM, goal_pwm=1))
    assert ideal.shaft_speed_radps > 0             # without friction any PWM turns the shaft


def test_low_speed_velocity_step_sticks_until_the_integrator_breaks_it_loose():
    """Goal 1 unit (0.024 rad/s) with soft gains: the shaft stays exactly at rest while the I term
    winds up to the breakaway torque, then slips; the frictionless shaft follows at once."""
    gains = dict(velocity_p_gain=50, velocity_i_gain=300)
    results = {}
    for name, cfg in (("ideal", IDEAL), ("friction", REAL)):
        servo = ServoModel(cfg.drive_motor, GEAR, cfg.supply_voltage_v, cfg.firmware, friction=cfg.drive_friction)
        speeds = []
        for _ in range(6000):
            servo.step(DT, items(u.MODE_VELOCITY, goal_velocity=1, **gains))
            speeds.append(servo.shaft_speed_radps)
        results[name] = np.array(speeds)
    stuck = np.flatnonzero(results["friction"] == 0.0)
    assert stuck.size > 1000 and np.all(np.diff(stuck[:1000]) == 1)   # one long stick from the start
    breakaway_s = (stuck[-1] + 1) * DT
    assert 1.0 < breakaway_s < 5.0
    assert np.all(results["friction"][stuck[-1] + 1:] > 0.0)          # then it slips and keeps moving
    assert np.count_nonzero(results["ideal"][100:] == 0.0) == 0
    # the I term needed to overcome breakaway: ki * e per tick, e ~ 1 unit while stuck
    need_counts = REAL.drive_friction.breakaway_nm / (GEAR * REAL.drive_motor.torque_nm_per_a) \
        * REAL.drive_motor.resistance_ohm / REAL.supply_voltage_v * 885
    p_counts = 50 / 128 * 1
    predicted_s = (need_counts - p_counts) / (300 / 65536) * 1e-3
    assert breakaway_s == pytest.approx(predicted_s, rel=0.1)


# ---- tyre contact --------------------------------------------------------------------------------
def test_static_normal_loads_share_the_weight_equally_on_a_symmetric_robot():
    xy = [(w.x_m, w.y_m) for w in GEO.wheels]
    n = static_normal_loads_n(xy, 4.75, 9.81)
    np.testing.assert_allclose(n, 4.75 * 9.81 / 4)


def test_wheel_tyre_loop_is_well_inside_its_stability_bound():
    j_out = REAL.drive_motor.inertia_kg_m2 * GEAR ** 2
    k = wheel_coupling_number(DT, GEO.wheel_radius_m, REAL.contact.slip_stiffness_n_s_per_m, j_out)
    assert k < 0.2


def test_contact_body_is_stable_with_a_very_stiff_tyre():
    """The implicit body update: even 1000x the stiffness (tyre time constant 16 µs << dt) settles."""
    params = dataclasses.replace(REAL.contact, slip_stiffness_n_s_per_m=3e5)
    body = ContactBody([(w.x_m, w.y_m) for w in GEO.wheels], 4.75, params)
    for _ in range(500):
        body.step(DT, [0.1] * 4, [0.0] * 4)
    np.testing.assert_allclose(body.twist, [0.1, 0.0, 0.0], atol=1e-9)


def test_contact_pushes_back_on_the_drive_shafts_while_the_body_accelerates():
    robot = RobotPhysics(single_effect(IDEAL, REAL, "contact"), GEO)
    tables = wheel_tables([0.1] * 4, [0.0] * 4)
    for _ in range(30):
        robot.step(DT, tables)
    assert np.all(robot.body.force_long_n > 0.5)                     # the tyres push the body forward
    for w in GEO.wheels:                                               # and load every drive shaft
        s = robot.servos[w.drive_id]
        assert s.motor.load_torque_nm * w.drive_direction > 0


def test_consistent_commands_reproduce_straight_line_and_circle_within_half_a_percent():
    contact = single_effect(IDEAL, REAL, "contact")
    robot = drive(contact, [0.1] * 4, [0.0] * 4, 3.0)
    assert isinstance(robot.body, ContactBody)
    ideal = drive(IDEAL, [0.1] * 4, [0.0] * 4, 3.0)
    assert robot.body.x_m == pytest.approx(ideal.body.x_m, rel=5e-3)
    np.testing.assert_allclose(robot.body.twist, [0.1, 0, 0], atol=5e-4)
    radius = 0.5                                    # every wheel square to the same centre (0, R)
    xy = np.array([(w.x_m, w.y_m) for w in GEO.wheels])
    w = 0.1 / radius
    vel = np.stack([-w * (xy[:, 1] - radius), w * xy[:, 0]], 1)
    robot = drive(contact, np.hypot(vel[:, 0], vel[:, 1]), np.arctan2(vel[:, 1], vel[:, 0]), 3.0)
    vx, vy, om = robot.body.twist
    assert math.hypot(vx, vy) / om == pytest.approx(radius, rel=5e-3)
    assert np.max(robot.body.residual_mps) < 1e-3


def test_one_wheel_steered_20_degrees_off_yaws_the_body_and_scrubs():
    contact = single_effect(IDEAL, REAL, "contact")
    straight = drive(contact, [0.1] * 4, [0.0] * 4, 2.0)
    off = drive(contact, [0.1] * 4, [math.radians(20), 0, 0, 0], 2.0)
    assert abs(straight.body.theta_rad) < 2e-3
    assert off.body.theta_rad > 0.05                       # front-left pushes left: the body turns left
    assert np.all(off.body.residual_mps > 3e-3)             # every wheel slips against the others
    assert off.body.slip_energy_j > 100 * straight.body.slip_energy_j


def test_halving_the_step_changes_a_scrubbing_run_little():
    contact = single_effect(IDEAL, REAL, "contact")
    a = drive(contact, [0.1] * 4, [math.radians(20), 0, 0, 0], 1.0, dt_s=1e-3)
    b = drive(contact, [0.1] * 4, [math.radians(20), 0, 0, 0], 1.0, dt_s=5e-4)
    np.testing.assert_allclose(a.body.pose, b.body.pose, rtol=0.01, atol=2e-4)


def test_low_friction_floor_saturates_the_tyres_and_the_body_lags():
    slippery = dataclasses.replace(single_effect(IDEAL, REAL, "contact"),
                                   contact=dataclasses.replace(REAL.contact, friction_coefficient=0.02))
    robot = drive(slippery, [0.1] * 4, [0.0] * 4, 0.3)
    assert robot.body.saturated_steps > 0
    limit = 0.02 * 9.81 * 0.3                              # friction-limited: a <= mu g
    assert 0.9 * limit < robot.body.twist[0] <= limit * 1.001


# ---- tolerances and supply ------------------------------------------------------------------------
def test_tolerances_change_the_true_wheels_but_not_what_the_encoders_say():
    tol = single_effect(IDEAL, REAL, "tolerances")
    robot = RobotPhysics(tol, GEO)
    np.testing.assert_allclose(robot.wheel_radius_m / GEO.wheel_radius_m, REAL.tolerances.wheel_radius_scale)
    for w in GEO.wheels:
        assert math.floor(robot.servos[w.steer_id].position_pulse) == w.center_pulse   # reads straight
    speeds, steer = robot.wheel_state()
    enc = np.array(REAL.tolerances.encoder_offset_pulse) * u.RAD_PER_PULSE
    np.testing.assert_allclose(steer, -enc - np.array(REAL.tolerances.steer_zero_offset_rad), atol=1e-8)


def test_backlash_holds_the_wheel_until_the_horn_takes_up_the_play():
    cfg = dataclasses.replace(IDEAL, tolerances=dataclasses.replace(IDEAL.tolerances, steer_backlash_rad=0.01))
    robot = RobotPhysics(cfg, GEO)
    steer_servo = robot.servos[GEO.wheels[0].steer_id]
    _, before = robot.wheel_state()
    steer_servo.set_shaft_angle(steer_servo.shaft_angle_rad + 0.004)       # within the 0.005 half play
    assert robot.wheel_state()[1][0] == before[0]
    steer_servo.set_shaft_angle(steer_servo.shaft_angle_rad + 0.004)       # now 0.003 beyond it
    assert robot.wheel_state()[1][0] == pytest.approx(before[0] + 0.003)


def test_supply_sags_under_load_and_present_input_voltage_shows_it():
    cfg = single_effect(IDEAL, REAL, "supply")
    robot = RobotPhysics(cfg, GEO)
    idle = items(u.MODE_PWM, goal_pwm=0)
    loaded = {sid: dict(idle, goal_pwm=885) if sid <= 4 else idle for sid in robot.servos}
    for _ in range(300):
        out = robot.step(DT, {sid: idle for sid in robot.servos})
    rest_v = robot.bus_voltage_v
    assert rest_v == pytest.approx(12.0 - 0.15 * 8 * 0.04)
    for s in robot.servos.values():
        s.motor.blocked = True                         # stalled: the largest current
    for _ in range(300):
        out = robot.step(DT, loaded)
    current = sum(s.supply_current_a for s in robot.servos.values()) + 8 * 0.04
    assert current > 4.0                               # four stalled drives at ~1.2 A each
    assert robot.bus_voltage_v == pytest.approx(12.0 - 0.15 * current, abs=0.02)
    assert out[1]["present_input_voltage"] == round(robot.bus_voltage_v * 10)
    assert out[1]["present_input_voltage"] < 115


# ---- protection ------------------------------------------------------------------------------------
def test_sustained_stall_current_raises_overload_after_the_configured_time():
    p = REAL.protection
    servo = ServoModel(REAL.drive_motor, GEAR, 12.0, REAL.firmware, protection=p)
    servo.motor.blocked = True
    bits, t = 0, 0.0
    while not bits and t < 5.0:
        servo.step(DT, items(u.MODE_PWM, goal_pwm=885))
        t += DT
        bits = servo.take_hardware_error()
    assert bits == HardwareError.OVERLOAD
    assert t == pytest.approx(p.overload_time_s, abs=5 * DT)   # plus the sub-ms current rise
    servo.step(DT, items(u.MODE_PWM, goal_pwm=885))
    assert servo.take_hardware_error() == 0                    # reported once until a reboot
    servo.reboot()
    assert servo.protection.overload_timer_s == 0.0


def test_hot_winding_and_low_voltage_raise_their_bits():
    servo = ServoModel(REAL.drive_motor, GEAR, 9.0, REAL.firmware, protection=REAL.protection)
    servo.temperature_c = 85.0
    servo.step(DT, items(u.MODE_PWM, goal_pwm=0))
    assert servo.take_hardware_error() == HardwareError.OVERHEATING | HardwareError.INPUT_VOLTAGE


def test_p_only_steering_stops_short_by_the_friction_deadband():
    """Position P only (the paper's steering gains): near the goal the P output falls below the
    breakaway PWM and the shaft sticks short by breakaway / Kp pulses; without friction it arrives."""
    kp_counts_per_pulse = IDEAL.paper_spec_gains["position_p_gain"] / 128
    f, m = REAL.steering_friction, REAL.steering_motor
    breakaway_counts = f.breakaway_nm / (GEAR * m.torque_nm_per_a) * m.resistance_ohm / REAL.supply_voltage_v * 885
    deadband = breakaway_counts / kp_counts_per_pulse                    # 2.0 pulses
    for cfg, short in ((IDEAL, 0), (REAL, -math.floor(deadband))):
        servo = ServoModel(m, GEAR, 12.0, cfg.firmware, friction=cfg.steering_friction)
        servo.set_shaft_angle(2048 * u.RAD_PER_PULSE)
        for goal in (2048, 2148):
            for _ in range(600):
                out = servo.step(DT, items(u.MODE_POSITION, goal_position=goal))
        assert out["present_position"] - 2148 == short
        assert servo.shaft_speed_radps == 0.0 or cfg is IDEAL


def test_slow_steering_ramp_moves_in_stick_slip_jumps():
    """A goal creeping at 5 pulse/s under P-only steering: with friction the shaft sticks until the
    error reaches the deadband, jumps, and sticks again (a staircase); without it, it never stops."""
    cycles = {}
    for cfg in (IDEAL, REAL):
        servo = ServoModel(cfg.steering_motor, GEAR, 12.0, cfg.firmware, friction=cfg.steering_friction)
        servo.set_shaft_angle(2048 * u.RAD_PER_PULSE)
        stuck = []
        for k in range(4000):
            servo.step(DT, items(u.MODE_POSITION, goal_position=2048 + int(5 * k * DT)))
            stuck.append(servo.shaft_speed_radps == 0.0)
        stuck = np.array(stuck[1000:], int)
        cycles[cfg is REAL] = (stuck.mean(), int(np.sum(np.diff(stuck) == -1)))
    assert cycles[False] == (0.0, 0)
    stuck_share, breakaways = cycles[True]
    assert stuck_share > 0.5 and breakaways >= 10      # ~one jump per 2 pulses of goal (0.4 s)
