"""LTV error system (28)-(31), (60) of the chained form and the discrete cost (36)-(41).

Sign convention (used everywhere in this package)::

    u = ud + K x~,   x~ = x - xd,   ũ = K x~

(the paper writes ``ud - K x~``: its K is the negative of ours). Discrete error dynamics::

    x~(i+1) = T_i [ (I + tau A_i) x~(i) + tau B_i ũ(i) ] = Ad_i x~(i) + Bd_i ũ(i)

with ``A_i[2,1] = A_i[4,3] = ud1``, ``B_i[0,0] = B_i[1,1] = B_i[3,2] = 1``, ``B_i[2,0] = xd2``,
``B_i[4,0] = xd4`` (0-based) and ``T_i`` the identity except where the chained frame is
re-anchored between steps i and i+1 (then ``T_i`` is the linearised change of chained
coordinates at the reference). Cost ``J = tau sum_{i=0}^{N-1} x~'Q x~ + ũ'R ũ``, summed over
the columns of a set of initial errors ``X0`` (5, m).
"""
from __future__ import annotations

import numpy as np

from swerve.core import small_linalg as sl
from swerve.controller.chained import chained_jacobian, to_chained, wrap_angle


def chained_error(x, xd):
    """``x - xd`` with the heading component (index 2) wrapped to [-pi, pi); shape (..., 5)."""
    e = np.asarray(x, dtype=float) - np.asarray(xd, dtype=float)
    e[..., 2] = wrap_angle(e[..., 2])
    return e


def initial_error(ref, state) -> np.ndarray:
    """Chained error ``x~(0)`` of a robot state (5,) against the reference at t = 0, shape (5,)."""
    return chained_error(to_chained(np.asarray(state, float), ref.geom, ref.phi_rad[0]),
                         ref.xd[0])


def error_system(ref):
    """Discrete LTV error system of a :class:`controller.reference.Reference`.

    Returns
    -------
    Ad : ndarray, shape (N, 5, 5)
    Bd : ndarray, shape (N, 5, 3)

    The change of frame ``T_i`` is applied in :mod:`core.small_linalg` (fixed order), so
    the system has the same bits whichever BLAS kernel the CPU gets.
    """
    N, tau = ref.n_steps, ref.tau_s
    xd, ud = ref.xd[:N], ref.ud[:N]
    Ad = np.broadcast_to(np.eye(5), (N, 5, 5)).copy()
    Ad[:, 2, 1] += tau * ud[:, 0]
    Ad[:, 4, 3] += tau * ud[:, 0]
    Bd = np.zeros((N, 5, 3))
    Bd[:, 0, 0] = tau
    Bd[:, 1, 1] = tau
    Bd[:, 3, 2] = tau
    Bd[:, 2, 0] = tau * xd[:, 1]
    Bd[:, 4, 0] = tau * xd[:, 3]
    for i in np.flatnonzero(np.diff(ref.phi_rad[:N + 1]) != 0):
        s = ref.states[i + 1]
        J_new = chained_jacobian(s, ref.geom, ref.phi_rad[i + 1])
        J_old = chained_jacobian(s, ref.geom, ref.phi_rad[i])
        T = sl.transpose(sl.solve(J_old.T.tolist(), J_new.T.tolist()))     # J_new J_old^-1
        Ad[i] = sl.matmul(T, Ad[i].tolist())
        Bd[i] = sl.matmul(T, Bd[i].tolist())
    return Ad, Bd


def closed_loop(Ad, Bd, K):
    """``M_i = Ad_i + Bd_i K_i``; shapes (N,5,5), (N,5,3), (N,3,5) -> (N,5,5)."""
    return Ad + Bd @ K


def rollout(M, X0, starts=None):
    """Error trajectories ``X(i+1) = M_i X(i)``: X0 (5, m) -> X (N+1, 5, m).

    ``starts`` (m,) ints, optional: column c is zero before step ``starts[c]`` and equals
    ``X0[:, c]`` there (an error injected later in the horizon); default all 0.
    """
    X0 = np.asarray(X0, dtype=float).reshape(5, -1)
    N = M.shape[0]
    X = np.empty((N + 1,) + X0.shape)
    if starts is None:
        X[0] = X0
        for i in range(N):
            np.matmul(M[i], X[i], out=X[i + 1])
        return X
    starts = np.asarray(starts, dtype=int).reshape(-1)
    X[0] = np.where(starts == 0, X0, 0.0)
    inject = {int(i): np.flatnonzero(starts == i) for i in np.unique(starts) if 0 < i <= N}
    for i in range(N):
        np.matmul(M[i], X[i], out=X[i + 1])
        cols = inject.get(i + 1)
        if cols is not None:
            X[i + 1][:, cols] = X0[:, cols]
    return X


def injected_cost(P, X0, starts=None) -> float:
    """``sum_c x_c' P[starts[c]] x_c``: the cost of errors injected at ``starts`` under the
    cost-to-go matrices ``P`` (N+1, 5, 5) (Riccati's for the optimum J*)."""
    X0 = np.asarray(X0, dtype=float).reshape(5, -1)
    s = np.zeros(X0.shape[1], int) if starts is None else np.asarray(starts, int)
    return float(np.einsum("im,mij,jm->", X0, P[s], X0))


def cost(Ad, Bd, K, Q, R, tau, X0, starts=None) -> float:
    """Exact discrete cost ``J`` of gains K (N,3,5) from initial errors X0 (5,) or (5, m)
    injected at steps ``starts`` (see :func:`rollout`)."""
    X = rollout(closed_loop(Ad, Bd, K), X0, starts)[:-1]
    U = K @ X
    return float(tau * (np.einsum("nim,ij,njm->", X, Q, X) + np.einsum("nim,ij,njm->", U, R, U)))


def policy_cost_matrices(Ad, Bd, K, Q, R, tau):
    """Cost-to-go matrices of fixed gains: ``J = sum_columns x0' P_0 x0``.

    ``P_N = 0``, ``P_i = tau (Q + K_i' R K_i) + M_i' P_{i+1} M_i``. Returns (N+1, 5, 5).
    """
    N = K.shape[0]
    M = closed_loop(Ad, Bd, K)
    stage = tau * (Q + np.swapaxes(K, 1, 2) @ R @ K)
    P = np.zeros((N + 1, 5, 5))
    for i in range(N - 1, -1, -1):
        Pi = stage[i] + M[i].T @ P[i + 1] @ M[i]
        P[i] = 0.5 * (Pi + Pi.T)
    return P
