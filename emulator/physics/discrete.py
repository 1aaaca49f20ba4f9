"""Exact zero-order-hold discretisation in 40-digit arithmetic: the same bits on every machine.

``scipy.linalg.expm`` runs LAPACK and BLAS kernels that OpenBLAS picks for the CPU at run time, so
its last bits change from one machine to the next, and a lockstep run integrates them. Here the
matrix exponential is :func:`mpmath.expm` at 40 significant digits (Python integers, no BLAS) and
each entry is then rounded once to the nearest float: the result depends only on the inputs.
A 5 x 5 exponential takes about 4 ms; the physics computes a handful per run and caches them.
"""
from __future__ import annotations

import mpmath
import numpy as np

#: Working precision of the exponential, significant decimal digits.
DIGITS = 40


def zoh(a, b, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation ``(Ad (n, n), Bd (n, m))`` of ``dx/dt = A x + B u``
    over ``dt_s`` s, for ``a`` (n, n) and ``b`` (n, m): ``[Ad Bd] = expm([[A B], [0 0]] dt)``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.ndim != 2 or a.shape[0] != a.shape[1] or b.ndim != 2 or b.shape[0] != a.shape[0]:
        raise ValueError(f"zoh: a must be (n, n) and b (n, m), got {a.shape} and {b.shape}")
    n, m = b.shape
    big = [ra + rb for ra, rb in zip(a.tolist(), b.tolist())] + [[0.0] * (n + m) for _ in range(m)]
    with mpmath.workdps(DIGITS):
        e = mpmath.expm(mpmath.matrix(big) * mpmath.mpf(dt_s))
        rows = [[float(e[i, j]) for j in range(n + m)] for i in range(n)]
    return np.array([r[:n] for r in rows]), np.array([r[n:] for r in rows]).reshape(n, m)
