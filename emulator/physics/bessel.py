"""The paper's fixed 2nd-order Bessel low-pass filter (Table 2, ``omega_n = 32.8 rad/s``).

The analogue prototype is :func:`scipy.signal.bessel`'s, in closed form (the 2nd-order Bessel
polynomial ``s^2 + 3 s + 3`` rescaled in frequency), and is discretised exactly (ZOH,
:func:`.discrete.zoh`) for the physics step; both in 40-digit arithmetic (:mod:`.exact`, kept on
disk by :mod:`.discrete`), so the coefficients are the same bits on every machine. The state is
``[y, dy/dt]``, so filtering a position also yields a filtered velocity (what the firmware uses
as its velocity estimate).
"""
from __future__ import annotations

from functools import lru_cache

from .discrete import bessel_prototype, zoh
from .jit import jitable


@lru_cache(maxsize=32)
def bessel_coefficients(cutoff_radps: float, norm: str = "mag") -> tuple[float, float]:
    """Return ``(a1, a0)`` of ``H(s) = a0 / (s^2 + a1 s + a0)``, the 2nd-order analogue Bessel.

    ``norm`` is :func:`scipy.signal.bessel`'s, with ``wc = cutoff_radps``: ``"delay"``: group
    delay ``1 / wc`` at DC, ``a1 = 3 wc``, ``a0 = 3 wc^2``; ``"phase"``: ``a1 = √3 wc``,
    ``a0 = wc^2``; ``"mag"``: -3 dB at ``wc`` (``|H(j wc)|^2 = 1/2``), ``a1 = √(3 φ) wc``,
    ``a0 = φ wc^2`` with ``φ = (1 + √5) / 2``. Each computed in 40 digits and rounded once to
    the nearest float (:func:`.exact.bessel_prototype`, kept on disk by :mod:`.discrete`).
    """
    return bessel_prototype(cutoff_radps, norm)


@lru_cache(maxsize=32)
def _discrete(cutoff_radps: float, norm: str, dt_s: float) -> tuple:
    a1, a0 = bessel_coefficients(cutoff_radps, norm)
    ad, bd = zoh([[0.0, 1.0], [-a0, -a1]], [[0.0], [a0]], dt_s)
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
