"""Shared fixtures of the controller tests: robot data and short references."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from controller.kinematics import Geometry, Limits, load_robot
from controller.paths import CirclePath
from controller.reference import Trajectory, build_reference, load_trajectory


@pytest.fixture(scope="session")
def robot():
    return load_robot()


def short(traj: Trajectory, n_steps: int) -> Trajectory:
    """The first ``n_steps`` of a trajectory (same tau, weights and start)."""
    return dataclasses.replace(traj, n_steps=n_steps, tf_s=n_steps * traj.tau_s)


@pytest.fixture(scope="session")
def switching_reference():
    """A fast small circle (limits relaxed) whose 1.6 s horizon re-anchors the chained frame."""
    geom = Geometry()
    path = CirclePath(radius_m=0.3, period_s=4.0, t_end_s=4.0)
    traj = Trajectory("small-circle", path, 1.6, 100, 0.016, np.diag([1e3, 1, 1e2, 1, 1e3]),
                      np.diag([1e-2, 1e-2, 1e-2]), np.array([0.0, -0.02, 0.1, 0.0, 0.0]))
    ref = build_reference(traj, geom, Limits(10.0, 100.0, 1.5708))
    assert len(set(ref.phi_rad)) > 1
    return ref


@pytest.fixture(scope="session")
def short_line_reference(robot):
    geom, limits = robot
    return build_reference(short(load_trajectory("line", geom), 150), geom, limits)
