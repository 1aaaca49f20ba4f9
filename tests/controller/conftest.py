"""Shared fixtures of the controller tests: robot data and short references."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from swerve.controller.kinematics import Geometry, Limits
from swerve.controller.paths import CirclePath
from swerve.controller.reference import build_reference
from swerve.controller.trajectory import Trajectory, load_trajectory


@pytest.fixture(scope="session")
def robot():
    """``(Geometry, Limits)`` of the shipped robot file (read by the application layer)."""
    from swerve.tools.run.geometry import load_robot

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
    return build_reference(short(load_trajectory("line_r_negative", geom), 150), geom, limits)


def numpy_reference(ref, t, phi):
    """What :meth:`Reference.sample` must return at the times ``t`` (n,) in the frames
    ``phi`` (n,), computed with the vectorised functions: states (n, 5), inputs (n, 3),
    xd (n, 5), ud (n, 3); the heading on the branch of the grid's ``states[index(t), 2]``."""
    from swerve.controller.chained import wrap_angle
    from swerve.controller.reference import chained_desired, desired_states

    t = np.clip(t, 0.0, ref.tf_s)
    states, inputs, extra = desired_states(ref.trajectory.path, t, ref.geom)
    v = extra["derivatives"][1]
    near = ref.states[[ref.index(s) for s in t], 2]
    states[:, 2] = near + wrap_angle(np.arctan2(v[1], v[0]) - near)
    xd, ud = chained_desired(states, extra, phi, ref.geom)
    return states, inputs, xd, ud


@pytest.fixture(scope="session")
def numpy_ref():
    """:func:`numpy_reference`, the slow twin of :meth:`Reference.sample`."""
    return numpy_reference


_PROBE_PRELUDE = """
import hashlib, json, numpy as np
from swerve.controller.kinematics import Geometry, Limits
from swerve.controller.ltv import error_system
from swerve.controller.reference import build_reference
from swerve.controller.trajectory import TRAJECTORY_DIR, load_trajectory
from swerve.controller.riccati import finite_horizon_lqr

def h(*arrays):
    d = hashlib.sha256()
    for a in arrays:
        d.update(np.ascontiguousarray(a, dtype=float).tobytes())
    return d.hexdigest()
"""


@pytest.fixture(scope="session")
def probe_prelude():
    """Start of a probe run by the ``other_cpu`` fixture: the controller imports and ``h(*arrays)``,
    a sha256 of the arrays' float64 bytes."""
    return _PROBE_PRELUDE


def damage_cache_file(path, kind: str, flip_at: int, other) -> None:
    """Damage the cache file ``path`` as ``kind`` says: ``truncate`` (half of it), ``flip`` (one
    bit of byte ``flip_at``), ``garbage``, ``empty``, or ``other key`` (the bytes ``other()``
    gives: a whole valid file of another input)."""
    data = path.read_bytes()
    damaged = {"truncate": lambda: data[:len(data) // 2],
               "flip": lambda: data[:flip_at] + bytes([data[flip_at] ^ 0x10]) + data[flip_at + 1:],
               "garbage": lambda: b"not a cache file\n" * 100,
               "empty": lambda: b"",
               "other key": other}[kind]()
    path.write_bytes(damaged)
