"""Exact zero-order holds and Bessel prototypes in 40-digit arithmetic: the same bits on every machine.

``scipy.linalg.expm`` runs LAPACK and BLAS kernels that OpenBLAS picks for the CPU at run time, so
its last bits change from one machine to the next, and a lockstep run integrates them. Here the
matrix exponential is :func:`mpmath.expm` at 40 significant digits (Python integers, no BLAS) and
each entry is then rounded once to the nearest float: the result depends only on the inputs.
A 5 x 5 exponential takes about 4 ms. The physics reaches these through :mod:`.discrete`, which
keeps their results on disk, so that a process whose inputs were computed before imports no
mpmath (its import alone is ~40 ms of CPU).
"""
from __future__ import annotations

import mpmath

#: Working precision, significant decimal digits.
DIGITS = 40


def zoh_rows(a: list[list[float]], b: list[list[float]], dt_s: float) -> list[list[float]]:
    """The rows of ``[Ad Bd] = expm([[A B], [0 0]] dt)`` (n rows of n + m floats) for ``a``
    (n, n) and ``b`` (n, m) given as nested lists of floats (shapes checked by the caller)."""
    n, m = len(b), len(b[0])
    big = [ra + rb for ra, rb in zip(a, b)] + [[0.0] * (n + m) for _ in range(m)]
    with mpmath.workdps(DIGITS):
        e = mpmath.expm(mpmath.matrix(big) * mpmath.mpf(dt_s))
        return [[float(e[i, j]) for j in range(n + m)] for i in range(n)]


def bessel_prototype(cutoff_radps: float, norm: str) -> tuple[float, float]:
    """``(a1, a0)`` of the 2nd-order analogue Bessel ``a0 / (s^2 + a1 s + a0)`` (see
    :func:`.bessel.bessel_coefficients`), each rounded once to the nearest float."""
    with mpmath.workdps(DIGITS):
        wc = mpmath.mpf(cutoff_radps)
        if norm == "delay":
            k1, k0 = mpmath.mpf(3), mpmath.mpf(3)
        elif norm == "phase":
            k1, k0 = mpmath.sqrt(3), mpmath.mpf(1)
        elif norm == "mag":
            phi = (1 + mpmath.sqrt(5)) / 2
            k1, k0 = mpmath.sqrt(3 * phi), phi
        else:
            raise ValueError(f"unknown Bessel norm {norm!r}")
        return float(k1 * wc), float(k0 * wc * wc)
