"""Eight servos on the body, driven through their raw control tables."""
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import yaml

from swerve.emulator.physics import units as u
from swerve.emulator.physics.robot import RobotPhysics, load_robot_geometry
from swerve.emulator.physics.steptest import table
from swerve.driver.errors import ConfigError

DT = 1.0 / 2000
ROOT = Path(__file__).resolve().parents[3]


def _tables(cfg, geometry, v1_mps, delta_front, delta_rear):
    g = cfg.paper_spec_gains
    goal = round(v1_mps / geometry.wheel_radius_m / u.RADPS_PER_VEL_UNIT)
    tabs = {}
    for w in geometry.wheels:
        tabs[w.drive_id] = table(operating_mode=u.MODE_VELOCITY, goal_velocity=w.drive_direction * goal,
                                 velocity_p_gain=g["velocity_p_gain"], velocity_i_gain=g["velocity_i_gain"])
        d = delta_front if w.x_m > 0 else delta_rear
        tabs[w.steer_id] = table(operating_mode=u.MODE_POSITION, position_p_gain=g["position_p_gain"],
                                 goal_position=w.center_pulse + round(w.steer_direction * d / u.RAD_PER_PULSE))
    return tabs, goal * u.RADPS_PER_VEL_UNIT * geometry.wheel_radius_m


def _run(robot, tabs, seconds, every=20):
    poses = []
    for k in range(int(round(seconds / DT))):
        robot.step(DT, tabs)
        if k % every == 0:
            poses.append(robot.body.pose)
    return np.array(poses)


def test_equal_speeds_zero_steering_drive_straight_at_v1(cfg, geometry):
    robot = RobotPhysics(cfg, geometry)
    v1 = 0.1
    tabs, _ = _tables(cfg, geometry, v1, 0.0, 0.0)
    _run(robot, tabs, 1.0)
    x0 = robot.body.x_m
    _run(robot, tabs, 2.0)
    assert (robot.body.x_m - x0) / 2.0 == pytest.approx(v1, rel=0.01)
    assert abs(robot.body.y_m) < 1e-3 and abs(robot.body.theta_rad) < 1e-3
    assert robot.body.residual_mps.max() < 1e-3


def test_symmetric_steering_drives_the_predicted_circle(cfg, geometry):
    robot = RobotPhysics(cfg, geometry)
    delta = 0.3
    tabs, _ = _tables(cfg, geometry, 0.1, delta, -delta)
    xs = _run(robot, tabs, 8.0)[100:]                       # drop the first second (transient)
    a = np.c_[2 * xs[:, 0], 2 * xs[:, 1], np.ones(len(xs))]
    c = np.linalg.lstsq(a, xs[:, 0] ** 2 + xs[:, 1] ** 2, rcond=None)[0]
    radius = math.sqrt(c[2] + c[0] ** 2 + c[1] ** 2)
    dq = round(delta / u.RAD_PER_PULSE) * u.RAD_PER_PULSE
    predicted = (0.1125 ** 2 + 0.1125 ** 2) / (0.1125 * math.tan(dq))   # r^2 / (a tan d) = 2a/tan d
    assert radius == pytest.approx(predicted, rel=0.01)


def test_robot_mass_loads_the_drive_motors(cfg, geometry):
    heavy = RobotPhysics(cfg, geometry)
    light = RobotPhysics(dataclasses.replace(cfg, body=dataclasses.replace(cfg.body, load_enabled=False)),
                         geometry)
    tabs, _ = _tables(cfg, geometry, 0.1, 0.0, 0.0)
    drive_id = geometry.wheels[0].drive_id
    impulse = {}                 # ∫ i dt over the speed-up: proportional to the inertia accelerated
    for name, robot in (("heavy", heavy), ("light", light)):
        impulse[name] = sum(abs(robot.step(DT, tabs)[drive_id]["present_current"]) for _ in range(300))
    assert impulse["heavy"] > 1.2 * impulse["light"]


def test_robot_geometry_errors_name_the_key(tmp_path):
    doc = yaml.safe_load((ROOT / "configs" / "robot.yaml").read_text())
    del doc["geometry"]["wheel_radius_m"]
    p = tmp_path / "robot.yaml"
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError, match="wheel_radius_m"):
        load_robot_geometry(p)


def test_step_body_moves_the_body_after_externally_stepped_servos(cfg, geometry):
    robot = RobotPhysics(cfg, geometry)
    tabs, v = _tables(cfg, geometry, 0.1, 0.0, 0.0)
    for _ in range(2000):
        for sid, servo in robot.servos.items():     # what the emulator's own servo loop does
            servo.step(DT, tabs[sid])
        robot.step_body(DT)
    assert robot.body.x_m == pytest.approx(0.1 * 1.0, rel=0.1)
