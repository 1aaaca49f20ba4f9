"""The physics' operators and coefficients agree with NumPy / SciPy to round-off, and are the same
bits whichever BLAS kernel NumPy and SciPy would have used."""
from __future__ import annotations

import json

import numpy as np
import pytest
from scipy import signal
from scipy.linalg import expm

from swerve.emulator.physics import bessel, motor
from swerve.emulator.physics.body import RobotBody, contact_matrix
from swerve.emulator.physics.contact import static_normal_loads_n
from swerve.emulator.physics.discrete import zoh

XY = [(0.1125, 0.1125), (-0.1125, 0.1125), (-0.1125, -0.1125), (0.1125, -0.1125)]
SKEWED = [(0.21, 0.14), (-0.18, 0.16), (-0.2, -0.13), (0.19, -0.15)]


@pytest.mark.parametrize("dt_s", [1e-4, 5e-4, 1e-3, 1 / 3000])
@pytest.mark.parametrize("motor_kind", ["drive_motor", "steering_motor"])
@pytest.mark.parametrize("coasting", [False, True])
def test_zoh_agrees_with_scipy_expm(cfg, motor_kind, dt_s, coasting):
    p = getattr(cfg, motor_kind)
    a, b = motor.state_space(p, p.inertia_kg_m2)
    if coasting:
        a, b = a[1:, 1:], b[1:, 1:]
    n, m = b.shape
    big = np.zeros((n + m, n + m))
    big[:n, :n], big[:n, n:] = a, b
    e = expm(big * dt_s)
    ad, bd = zoh(a, b, dt_s)
    assert ad.shape == (n, n) and bd.shape == (n, m)
    np.testing.assert_allclose(ad, e[:n, :n], rtol=1e-13, atol=1e-13 * np.abs(e[:n, :n]).max())
    np.testing.assert_allclose(bd, e[:n, n:], rtol=1e-13, atol=1e-13 * np.abs(e[:n, n:]).max())


def test_zoh_checks_shapes():
    with pytest.raises(ValueError, match="zoh"):
        zoh(np.eye(2), np.ones((3, 1)), 1e-3)


@pytest.mark.parametrize("norm", ["mag", "phase", "delay"])
@pytest.mark.parametrize("cutoff", [1.0, 32.8, 400.0])
def test_bessel_prototype_agrees_with_scipy(norm, cutoff):
    b, a = signal.bessel(2, cutoff, analog=True, norm=norm)
    a1, a0 = bessel.bessel_coefficients(cutoff, norm)
    np.testing.assert_allclose([a1, a0], np.asarray(a[1:]) / a[0], rtol=1e-13)
    assert b[-1] / a[0] == pytest.approx(a0, rel=1e-13)           # unity DC gain


@pytest.mark.parametrize("norm", ["mag", "phase", "delay"])
@pytest.mark.parametrize("dt_s", [5e-4, 1e-3])
def test_bessel_discretisation_agrees_with_cont2discrete(norm, dt_s):
    a1, a0 = bessel.bessel_coefficients(32.8, norm)
    ad_ref, bd_ref, *_ = signal.cont2discrete((np.array([[0.0, 1.0], [-a0, -a1]]), np.array([[0.0], [a0]]),
                                               np.eye(2), np.zeros((2, 1))), dt_s, method="zoh")
    ad, bd = bessel._discrete(32.8, norm, dt_s)
    np.testing.assert_allclose(ad, ad_ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(bd, bd_ref.ravel(), rtol=1e-12, atol=1e-14)


def test_unknown_bessel_norm_is_refused():
    with pytest.raises(ValueError, match="norm"):
        bessel.bessel_coefficients(32.8, "bogus")


@pytest.mark.parametrize("xy", [XY, SKEWED])
def test_least_squares_operators_agree_with_numpy(xy):
    np.testing.assert_allclose(RobotBody(xy)._pinv, np.linalg.pinv(contact_matrix(xy)), rtol=1e-13, atol=1e-14)
    a = np.vstack([np.ones(4), np.array(xy).T])
    np.testing.assert_allclose(static_normal_loads_n(xy, 4.75, 9.81), np.linalg.pinv(a) @ [4.75 * 9.81, 0, 0],
                               rtol=1e-13)


def test_fit_twist_is_the_step_fit_bit_for_bit():
    rng = np.random.default_rng(3)
    body = RobotBody(SKEWED)
    for _ in range(50):
        speeds, steer = rng.normal(size=4), rng.normal(size=4)
        twist = body.fit_twist(speeds, steer)
        body.step(1e-3, speeds.tolist(), steer.tolist())
        assert twist.tolist() == body.twist.tolist()
        w = np.array([v * f(d) for v, d in zip(speeds, steer) for f in (np.cos, np.sin)])
        r = (contact_matrix(SKEWED) @ twist - w).reshape(-1, 2)
        np.testing.assert_allclose(body.residual_mps, np.hypot(r[:, 0], r[:, 1]), atol=1e-14)


_PROBE = """
import json, numpy as np
from scipy.linalg import expm
from swerve.emulator.physics import bessel, motor
from swerve.emulator.physics.body import RobotBody, contact_matrix
from swerve.emulator.physics.contact import ContactBody, static_normal_loads_n
from swerve.emulator.physics.params import ContactParams, load_config
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.physics.robot import RobotPhysics, load_robot_geometry
from swerve.emulator.physics.steptest import table
from swerve.emulator.physics import units as u

xy = %r
out = []
def put(*values):
    for v in values:
        out.extend(float.hex(float(x)) for x in np.ravel(np.asarray(v, dtype=float)))
put(RobotBody(xy)._pinv, static_normal_loads_n(xy, 4.75, 9.81))
geometry = load_robot_geometry()
for profile in ("ideal", "realistic"):
    cfg = load_config(resolve_emulator_config(profile))
    for p in (cfg.drive_motor, cfg.steering_motor):
        for coasting in (False, True):
            ad, bd = motor._discrete(p, p.inertia_kg_m2 * 1.7, 1 / 2000, coasting)
            put([v for r in ad + bd for v in r])
    for norm in ("mag", "phase", "delay"):
        (ad, bd) = bessel._discrete(cfg.firmware.bessel_cutoff_radps, norm, 1 / 2000)
        put(bessel.bessel_coefficients(cfg.firmware.bessel_cutoff_radps, norm), [v for r in ad for v in r], bd)
    robot = RobotPhysics(cfg, geometry, rng=np.random.default_rng(5))
    g = cfg.paper_spec_gains
    tabs = {}
    for w in geometry.wheels:
        tabs[w.drive_id] = table(operating_mode=u.MODE_VELOCITY, goal_velocity=w.drive_direction * 150,
                                 velocity_p_gain=g["velocity_p_gain"], velocity_i_gain=g["velocity_i_gain"])
        tabs[w.steer_id] = table(operating_mode=u.MODE_POSITION, position_p_gain=g["position_p_gain"],
                                 goal_position=w.center_pulse + (80 if w.x_m > 0 else -80))
    for _ in range(600):
        robot.step(1 / 2000, tabs)
    put(robot.body.pose, robot.body.twist, robot.body.residual_mps, robot.bus_voltage_v)
rng = np.random.default_rng(7)
steps = [(rng.normal(size=4).tolist(), rng.normal(size=4).tolist()) for _ in range(200)]
body = RobotBody(xy)
put(body.step_many(1e-3, steps), body.residual_mps)
contact = ContactBody(xy, 4.75, ContactParams(enabled=True))
for v, d in steps:
    contact.step(1e-3, [0.05 * x for x in v], d)
put(contact.pose, contact.residual_mps, contact.force_n, contact.slip_energy_j)
n = len(out)
# the same through NumPy's and SciPy's BLAS: the kernels' own last bits, to show they differ
big = np.zeros((5, 5))
big[:3, :3], big[:3, 3:] = motor.state_space(cfg.drive_motor, cfg.drive_motor.inertia_kg_m2)
put(np.linalg.pinv(contact_matrix(xy)), expm(big / 2000))
print(json.dumps([n, out]))
"""


@pytest.mark.slow
def test_same_bits_under_different_blas_kernels(other_cpu):
    out = {core: json.loads(other_cpu({"OPENBLAS_CORETYPE": core}, "-c", _PROBE % (SKEWED,)))
           for core in ("Nehalem", "Haswell")}
    (n, nehalem), (_, haswell) = out["Nehalem"], out["Haswell"]
    assert nehalem[:n] == haswell[:n]
    # the probe can tell the kernels apart: NumPy's pinv and SciPy's expm of the same matrices differ
    assert nehalem[n:] != haswell[n:]
