"""The paper's fixed 2nd-order Bessel low-pass filter (Table 2, ``omega_n = 32.8 rad/s``).

The analogue prototype comes from :func:`scipy.signal.bessel` and is discretised exactly (ZOH,
:func:`scipy.signal.cont2discrete`) for the physics step. The state is ``[y, dy/dt]``, so filtering
a position also yields a filtered velocity (what the firmware uses as its velocity estimate).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy import signal

from .jit import jitable


@lru_cache(maxsize=32)
def bessel_coefficients(cutoff_radps: float, norm: str = "mag") -> tuple[float, float]:
    """Return ``(a1, a0)`` of ``H(s) = a0 / (s^2 + a1 s + a0)``, the 2nd-order analogue Bessel.

    ``norm`` is SciPy's: ``"mag"`` puts -3 dB at ``cutoff_radps``. Cached: the design takes
    0.5 ms, and every servo's filter is reset with it when torque or mode changes.
    """
    b, a = signal.bessel(2, cutoff_radps, btype="low", analog=True, norm=norm)
    a = np.asarray(a, float) / a[0]
    if not np.isclose(b[-1] / a[0], a[2]):
        raise ValueError("unexpected Bessel prototype: DC gain is not 1")
    return float(a[1]), float(a[2])


@lru_cache(maxsize=32)
def _discrete(cutoff_radps: float, norm: str, dt_s: float) -> tuple:
    a1, a0 = bessel_coefficients(cutoff_radps, norm)
    a = np.array([[0.0, 1.0], [-a0, -a1]])
    b = np.array([[0.0], [a0]])
    ad, bd, *_ = signal.cont2discrete((a, b, np.eye(2), np.zeros((2, 1))), dt_s, method="zoh")
    return tuple(tuple(map(float, r)) for r in ad), (float(bd[0, 0]), float(bd[1, 0]))   # Python floats: fast


@jitable
def bessel_reset(value: float, rate: float, a1: float, a0: float) -> tuple[float, float]:
    """Steady state ``(y, dy)`` of the filter ``a0 / (s^2 + a1 s + a0)`` on an input at ``value``
    moving at ``rate`` per second."""
    return float(value) - float(rate) * a1 / a0, float(rate)


@jitable
def bessel_step(y: float, dy: float, u: float, a00: float, a01: float, a10: float, a11: float, b0: float,
                b1: float) -> tuple[float, float]:
    """One step of the discrete filter with input ``u`` held: the new state ``(y, dy)`` from the
    state ``(y, dy)`` and the discrete matrices ``Ad = [[a00, a01], [a10, a11]]``, ``Bd = [b0, b1]``."""
    return a00 * y + a01 * dy + b0 * u, a10 * y + a11 * dy + b1 * u


class BesselFilter:
    """Discrete 2nd-order Bessel low-pass with unity DC gain.

    Parameters
    ----------
    cutoff_radps : float
        Cut-off frequency, rad/s.
    norm : str
        Frequency normalisation passed to :func:`scipy.signal.bessel`.
    """

    def __init__(self, cutoff_radps: float = 32.8, norm: str = "mag"):
        self.cutoff_radps = float(cutoff_radps)
        self.norm = norm
        self.y = 0.0
        self.dy = 0.0
        self._dt_s = 0.0                # step of the cached coefficients
        self._coef: tuple = ()

    def reset(self, value: float = 0.0, rate: float = 0.0) -> None:
        """Put the filter in steady state on an input at ``value`` moving at ``rate`` per second."""
        self.y, self.dy = bessel_reset(value, rate, *bessel_coefficients(self.cutoff_radps, self.norm))

    def prepare(self, dt_s: float) -> None:
        """Compute (cache) the coefficients for steps of ``dt_s``."""
        self._dt_s, self._coef = dt_s, _discrete(self.cutoff_radps, self.norm, dt_s)

    def step(self, dt_s: float, u: float) -> float:
        """Advance ``dt_s`` with input ``u`` held; return the output ``y``."""
        if dt_s != self._dt_s:
            self._dt_s, self._coef = dt_s, _discrete(self.cutoff_radps, self.norm, dt_s)
        ((a00, a01), (a10, a11)), (b0, b1) = self._coef
        self.y, self.dy = bessel_step(self.y, self.dy, u, a00, a01, a10, a11, b0, b1)
        return self.y
