import numpy as np
import pytest

from swerve.controller.chained import (chained_inputs, chained_rhs, from_chained, inputs_from_chained,
                                singularity_margin, to_chained, wrap_angle)
from swerve.controller.kinematics import Geometry, rk4_step, state_derivative

G = Geometry()
RNG = np.random.default_rng(5)


def random_states(n):
    s = np.column_stack([RNG.uniform(-1, 1, n), RNG.uniform(-1, 1, n), RNG.uniform(-1, 1, n),
                         RNG.uniform(-0.6, 0.6, n), RNG.uniform(-0.6, 0.6, n)])
    return s[singularity_margin(s) > 0.2]


@pytest.mark.parametrize("phi", [0.0, np.pi / 2, -np.pi / 2, np.pi, 0.7])
def test_coordinates_invert(phi):
    s = random_states(200)
    s = s[singularity_margin(s, phi) > 0.2]
    back = from_chained(to_chained(s, G, phi), G, phi)
    np.testing.assert_allclose(back[:, :2], s[:, :2], atol=1e-12)
    np.testing.assert_allclose(wrap_angle(back[:, 2] - s[:, 2]), 0, atol=1e-12)
    np.testing.assert_allclose(back[:, 3:], s[:, 3:], atol=1e-10)


@pytest.mark.parametrize("phi", [0.0, np.pi / 2, 2.0])
def test_inputs_invert(phi):
    s = random_states(200)
    s = s[singularity_margin(s, phi) > 0.2]
    u = np.column_stack([RNG.uniform(-0.13, 0.13, len(s)), RNG.uniform(-2, 2, (len(s), 2))])
    np.testing.assert_allclose(inputs_from_chained(s, chained_inputs(s, u, G, phi), G, phi), u,
                               atol=1e-10)


def test_chain_holds_along_the_flow():
    """d/dt to_chained(s) equals the chained right-hand side at the chained inputs."""
    s = random_states(100)
    u = np.column_stack([RNG.uniform(-0.13, 0.13, len(s)), RNG.uniform(-2, 2, (len(s), 2))])
    h = 1e-6
    f = state_derivative(s, u, G)
    dxdt = (to_chained(s + h * f, G) - to_chained(s - h * f, G)) / (2 * h)
    np.testing.assert_allclose(dxdt, chained_rhs(to_chained(s, G), chained_inputs(s, u, G)),
                               rtol=1e-6, atol=1e-8)


def test_integrating_the_chained_system_reproduces_the_model():
    s = np.array([0.1, -0.2, 0.3, 0.2, -0.1])
    x = to_chained(s, G)
    dt, n = 0.002, 1500
    for k in range(n):
        t = k * dt
        u_phys = np.array([0.1, 0.5 * np.cos(t), -0.4 * np.sin(2 * t)])

        def fx(xc, sc):
            return chained_rhs(xc, chained_inputs(sc, u_phys, G))

        # RK4 on the joint system: the chained inputs follow the physical state
        k1s, k1x = state_derivative(s, u_phys, G), fx(x, s)
        s2, x2 = s + dt / 2 * k1s, x + dt / 2 * k1x
        k2s, k2x = state_derivative(s2, u_phys, G), fx(x2, s2)
        s3, x3 = s + dt / 2 * k2s, x + dt / 2 * k2x
        k3s, k3x = state_derivative(s3, u_phys, G), fx(x3, s3)
        s4, x4 = s + dt * k3s, x + dt * k3x
        k4s, k4x = state_derivative(s4, u_phys, G), fx(x4, s4)
        s = s + dt / 6 * (k1s + 2 * k2s + 2 * k3s + k4s)
        x = x + dt / 6 * (k1x + 2 * k2x + 2 * k3x + k4x)
    assert singularity_margin(s) > 0.2
    np.testing.assert_allclose(x, to_chained(s, G), atol=1e-9)


def test_rotation_invariance_of_the_model():
    """The same physical motion in a rotated frame: chained coords of rotated states agree."""
    s = np.array([0.3, 0.4, 1.2, 0.1, -0.2])
    phi = np.pi / 2
    c, sn = np.cos(phi), np.sin(phi)
    s_rot = np.array([c * s[0] + sn * s[1], -sn * s[0] + c * s[1], s[2] - phi, s[3], s[4]])
    np.testing.assert_allclose(to_chained(s, G, phi), to_chained(s_rot, G, 0.0), atol=1e-14)
    u = np.array([0.1, 0.3, -0.2])
    np.testing.assert_allclose(rk4_step(s, u, 0.1, G)[3:], rk4_step(s_rot, u, 0.1, G)[3:])


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=200, deadline=None)
@given(x=st.floats(-5, 5), y=st.floats(-5, 5), th=st.floats(-3, 3),
       d1=st.floats(-1.2, 1.2), d2=st.floats(-1.2, 1.2),
       k=st.integers(-4, 4), v1=st.floats(-0.2, 0.2), w1=st.floats(-4, 4), w2=st.floats(-4, 4))
def test_transforms_invert_property(x, y, th, d1, d2, k, v1, w1, w2):
    s = np.array([x, y, th, d1, d2])
    phi = k * np.pi / 2
    if singularity_margin(s, phi) < 0.1 or abs(np.sin(d1) - np.sin(d2)) > 1.9:
        return
    xc = to_chained(s, G, phi)
    back = from_chained(xc, G, phi)
    np.testing.assert_allclose(back[:2], s[:2], atol=1e-9)
    np.testing.assert_allclose(wrap_angle(back[2] - s[2]), 0, atol=1e-9)
    np.testing.assert_allclose(back[3:], s[3:], atol=1e-7)
    u = np.array([v1, w1, w2])
    np.testing.assert_allclose(inputs_from_chained(s, chained_inputs(s, u, G, phi), G, phi), u,
                               atol=1e-7)
