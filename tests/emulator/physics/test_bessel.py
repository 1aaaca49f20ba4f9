"""The fixed 2nd-order Bessel filter block on its own."""
import numpy as np
import pytest
from scipy import signal

from swerve.emulator.physics.bessel import BesselFilter, bessel_coefficients

DT = 1.0 / 2000          # physics step, s (2 kHz)


@pytest.mark.parametrize("norm", ["mag", "phase", "delay"])
def test_step_response_matches_analytic_bessel(norm):
    b, a = signal.bessel(2, 32.8, analog=True, norm=norm)
    t = np.arange(0, 801) * DT                     # scipy: T[0] is the initial instant
    _, y_ref = signal.step((b, a), T=t)
    f = BesselFilter(32.8, norm)
    y = np.array([0.0] + [f.step(DT, 1.0) for _ in t[1:]])
    np.testing.assert_allclose(y, y_ref, atol=1e-9)
    assert y.max() - 1.0 < 0.005        # a Bessel step barely overshoots (0.43 %)


def test_mag_norm_puts_minus_3db_at_cutoff():
    a1, a0 = bessel_coefficients(32.8, "mag")
    _, h = signal.freqs([a0], [1.0, a1, a0], worN=[32.8])
    assert abs(h[0]) == pytest.approx(2 ** -0.5, rel=1e-6)


def test_derivative_state_is_the_filtered_rate():
    f = BesselFilter(32.8)
    f.reset(0.0, 10.0)
    for k in range(1, 2001):
        f.step(DT, 10.0 * k * DT)
    assert f.dy == pytest.approx(10.0, rel=1e-4)    # staircase input: ZOH ripple
