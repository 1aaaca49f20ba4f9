"""Least-squares rigid-body fit and pose integration."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swerve.emulator.physics.body import RobotBody, contact_matrix, paper_model_rates

A = B = 0.1125
CORNERS = [(A, B), (-A, B), (-A, -B), (A, -B)]     # robot.yaml order: FL, RL, RR, FR
angles = st.floats(-1.4, 1.4)


def wheel_velocities(speeds_mps: np.ndarray, steer_rad: np.ndarray) -> np.ndarray:
    """Stacked wheel contact velocities ``[v_i cos δ_i, v_i sin δ_i, ...]``, shape (2n,)."""
    v, d = np.asarray(speeds_mps, float), np.asarray(steer_rad, float)
    out = np.empty(2 * len(v))
    out[0::2] = v * np.cos(d)
    out[1::2] = v * np.sin(d)
    return out


@settings(max_examples=200, deadline=None)
@given(d1=angles, d2=angles, v1=st.floats(-0.2, 0.2), theta=st.floats(-math.pi, math.pi))
def test_fit_equals_paper_model_when_wheels_agree(d1, d2, v1, theta):
    body = RobotBody(CORNERS, (0.0, 0.0, theta))
    vx, vy, w = body.fit_twist([v1] * 4, [d1, d2, d2, d1])
    xdot, ydot, thdot = paper_model_rates(theta, d1, d2, v1, A, B)
    c, s = math.cos(theta), math.sin(theta)
    np.testing.assert_allclose([c * vx - s * vy, s * vx + c * vy, w], [xdot, ydot, thdot], atol=1e-12)


def test_fighting_wheels_get_the_least_squares_twist_and_a_residual():
    body = RobotBody(CORNERS)
    speeds, steer = [0.1, 0.1, -0.1, -0.1], [0.0, 0.3, 0.0, -0.2]     # left forward, right back
    twist = body.fit_twist(speeds, steer)
    ref, *_ = np.linalg.lstsq(contact_matrix(CORNERS), wheel_velocities(speeds, steer), rcond=None)
    np.testing.assert_allclose(twist, ref, atol=1e-12)
    assert twist[2] < 0                                   # spins clockwise
    assert body.residual_mps.min() > 1e-3                 # no rigid motion satisfies all wheels


def test_constant_twist_integrates_exactly_round_a_circle():
    body = RobotBody(CORNERS)
    d = 0.3
    speeds, steer = [0.1] * 4, [d, -d, -d, d]
    twist = body.fit_twist(speeds, steer)
    period = 2 * math.pi / twist[2]
    n = 1000
    for _ in range(n):
        body.step(period / n, speeds, steer)
    assert body.x_m == pytest.approx(0.0, abs=1e-12) and body.y_m == pytest.approx(0.0, abs=1e-12)
    assert body.theta_rad == pytest.approx(2 * math.pi)
