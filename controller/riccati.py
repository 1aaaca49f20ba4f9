"""Finite-horizon discrete Riccati recursion: the exact optimum of the LTV problem in
:mod:`controller.ltv`, for every initial error at once.

Backward from ``P_N = 0``::

    S_i = tau R + Bd_i' P_{i+1} Bd_i
    K_i = -S_i^{-1} Bd_i' P_{i+1} Ad_i                  (u = ud + K x~)
    P_i = tau Q + Ad_i' P_{i+1} (Ad_i + Bd_i K_i)

Only ``S_i`` must be invertible, which ``R > 0`` guarantees: no controllability or
stabilisability condition. The optimal cost from ``x~(0)`` is ``J* = x~(0)' P_0 x~(0)``.

The recursion runs in :mod:`core.small_linalg` (Python floats, fixed order), so the
schedule has the same bits whichever BLAS kernel the CPU gets.
"""
from __future__ import annotations

import numpy as np

from swerve.core import small_linalg as sl


def finite_horizon_lqr(Ad, Bd, Q, R, tau: float, progress: bool = False):
    """Optimal gain schedule of ``J = tau sum x~'Q x~ + ũ'R ũ``.

    Parameters
    ----------
    Ad, Bd : ndarray, shapes (N, 5, 5) and (N, 5, 3)
        Discrete error system (:func:`controller.ltv.error_system`).
    Q, R : ndarray, shapes (5, 5), (3, 3)
        Weights, ``R`` positive definite.
    tau : float
        Step, s (the cost carries it as in the paper).

    Returns
    -------
    K : ndarray, shape (N, 3, 5)
        Gains, ``ũ(i) = K_i x~(i)``.
    P : ndarray, shape (N+1, 5, 5)
        Optimal cost-to-go matrices.
    """
    N, n, m = np.shape(Bd)
    tQ = (tau * np.asarray(Q, float)).tolist()
    tR = (tau * np.asarray(R, float)).tolist()
    Ads, Bds = np.asarray(Ad, float).tolist(), np.asarray(Bd, float).tolist()
    K: list = [None] * N
    P: list = [None] * (N + 1)
    P[N] = [[0.0] * n for _ in range(n)]
    steps = range(N - 1, -1, -1)
    if progress:
        from tqdm import tqdm

        steps = tqdm(steps, total=N, desc="riccati", unit="step", leave=False)
    for i in steps:
        A, B, Pn = Ads[i], Bds[i], P[i + 1]
        BtP = sl.matmul(sl.transpose(B), Pn)
        Ki = sl.solve(sl.add(tR, sl.matmul(BtP, B)), sl.matmul(BtP, A))
        Ki = [[-v for v in row] for row in Ki]
        Pi = sl.add(tQ, sl.matmul(sl.matmul(sl.transpose(A), Pn), sl.add(A, sl.matmul(B, Ki))))
        K[i] = Ki
        P[i] = [[0.5 * (Pi[r][c] + Pi[c][r]) for c in range(n)] for r in range(n)]
    return np.array(K, dtype=float).reshape(N, m, n), np.array(P, dtype=float)
