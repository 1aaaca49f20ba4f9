import numpy as np
import pytest
import yaml

from swerve.configs import shipped
from swerve.core.errors import ConfigError
from swerve.controller.errors import ControllerError
from swerve.controller.kinematics import (Geometry, drive_angular_speed, rk4_step, state_derivative,
                                          symmetric_steering, wheel_commands)
from swerve.tools.run.geometry import load_robot


def test_load_robot_reads_the_config(robot):
    geom, limits = robot
    cfg = yaml.safe_load(shipped("robot.yaml").read_text())
    assert geom.a_m == cfg["geometry"]["a_m"]
    assert geom.wheel_radius_m == cfg["geometry"]["wheel_radius_m"]
    assert limits.v1_max_mps == cfg["limits"]["v1_max_mps"]
    assert limits.steer_rate_max_radps == cfg["limits"]["steer_rate_max_radps"]


def test_load_robot_bad_file(tmp_path):
    p = tmp_path / "robot.yaml"
    p.write_text("geometry: {a_m: 0.1}\n")
    with pytest.raises(ConfigError, match="robot.yaml"):
        load_robot(p)


def test_wheel_commands_order():
    np.testing.assert_allclose(wheel_commands(0.1, 0.2, -0.3),
                               [0.1, 0.1, 0.1, 0.1, 0.2, -0.3, -0.3, 0.2])


def test_drive_angular_speed(robot):
    geom, _ = robot
    np.testing.assert_allclose(drive_angular_speed(0.13, geom.wheel_radius_m),
                               0.13 / geom.wheel_radius_m)
    with pytest.raises(ControllerError):
        drive_angular_speed(0.1, 0.0)


def test_straight_and_symmetric_motion():
    g = Geometry()
    d = state_derivative([0, 0, 0.3, 0, 0], [0.1, 0, 0], g)
    np.testing.assert_allclose(d, [0.1 * np.cos(0.3), 0.1 * np.sin(0.3), 0, 0, 0], atol=1e-15)
    # symmetric steering: body moves along its axis on a circle of the predicted curvature
    kappa = 1.0
    delta, v1 = symmetric_steering(kappa, 0.1, g)
    np.testing.assert_allclose(np.tan(delta), 2 * g.a_m * kappa)     # a = b: tan d = 2 a k
    d = state_derivative([0, 0, 0, delta, -delta], [v1, 0, 0], g)
    np.testing.assert_allclose(d[:2], [0.1, 0.0], atol=1e-15)
    np.testing.assert_allclose(d[2] / 0.1, kappa)


def test_rk4_closes_a_circle():
    g = Geometry()
    delta, v1 = symmetric_steering(1.0, 0.1, g)
    s = np.array([0, 0, 0, delta, -delta])
    n = 400
    dt = 2 * np.pi / 0.1 / n
    for _ in range(n):
        s = rk4_step(s, [v1, 0, 0], dt, g)
    np.testing.assert_allclose(s[:2], [0, 0], atol=1e-6)
    np.testing.assert_allclose(s[2], 2 * np.pi, atol=1e-6)


def _rk4_numpy(s, u, dt, g, substeps):
    """Classical RK4 on the vectorised state_derivative (rk4_step's numpy twin)."""
    h = dt / substeps
    for _ in range(substeps):
        k1 = state_derivative(s, u, g)
        k2 = state_derivative(s + 0.5 * h * k1, u, g)
        k3 = state_derivative(s + 0.5 * h * k2, u, g)
        k4 = state_derivative(s + h * k3, u, g)
        s = s + (h / 6.0) * (k1 + 2 * k2 + 2 * k3 + k4)
    return s


def test_rk4_step_equals_rk4_on_the_vectorised_model():
    g = Geometry(0.12, 0.1, 0.03)
    rng = np.random.default_rng(3)
    for _ in range(300):
        s = rng.uniform(-3, 3, 5)
        u = rng.uniform([-0.2, -4, -4], [0.2, 4, 4])
        dt, n = rng.uniform(0, 0.1), int(rng.integers(1, 4))
        np.testing.assert_allclose(rk4_step(s, u, dt, g, n), _rk4_numpy(s, u, dt, g, n),
                                   rtol=1e-14, atol=1e-15)
