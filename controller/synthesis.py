"""The paper's synthesis (42)-(59): nonlinear conjugate gradient on all gains K(i) at once.

``k <- k + eta s``, ``s <- -z+ + beta s`` with the beta family (44)::

    beta = [mu g+'z+ + (1 - mu) z+'(g+ - g)] / [nu g'z + (1 - nu) s'(g+ - g)]

(mu, nu) = (1, 0) Dai-Yuan (the paper's choice, default), (1, 1) Fletcher-Reeves, (0, 1)
Polak-Ribiere-Polyak, (0, 0) Hestenes-Stiefel. ``z = g`` is the paper's method; with
``precondition=True``, ``z`` is the gradient scaled block by block by the exact Hessian of J
in K(i) alone, ``2 (tau R + Bd' P_{i+1} Bd) (.) X_i X_i'``, with ``P`` the cost-to-go of the
current gains (a variable-metric preconditioner; the beta formulas are the preconditioned
ones). ``eta`` comes from SciPy's strong-Wolfe line search
(:func:`scipy.optimize.line_search`, Nocedal & Wright Alg. 3.5-3.6).

From K = 0 the full-horizon problem is badly conditioned (open-loop errors grow over
thousands of steps); :func:`conjugate_gradient_continuation` runs the same method on a
growing horizon (64, 128, ... N steps) and reaches 1.01 J* on the line case in about a
second.

The gradient is the exact adjoint recursion (see ``docs/reference/paper.md`` §5;
the paper's printed (55)-(59) has an index typo and drops the ``B K`` term)::

    lambda_N = 0,  lambda_i = 2 tau (Q + K_i'R K_i) x_i + M_i' lambda_{i+1}
    dJ/dK_i = 2 tau R K_i x_i x_i' + Bd_i' lambda_{i+1} x_i'

summed over the errors J sees, in moment form (``lambda_i = 2 P_i x_i``, see
:func:`cost_and_gradient`), so that errors may also enter later in the horizon
(:func:`error_injections`): with errors at t0 only, the late gains barely affect J.

Sign convention: ``u = ud + K x~`` (see :mod:`controller.ltv`).
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import line_search

from swerve.controller.errors import ControllerError
from swerve.controller.ltv import closed_loop, policy_cost_matrices

#: (mu, nu) of each member of the beta family (44).
BETA_METHODS = {"dai-yuan": (1.0, 0.0), "fletcher-reeves": (1.0, 1.0),
                "polak-ribiere": (0.0, 1.0), "hestenes-stiefel": (0.0, 0.0)}
BETA_ALIASES = {"dy": "dai-yuan", "fr": "fletcher-reeves", "prp": "polak-ribiere",
                "pr": "polak-ribiere", "hs": "hestenes-stiefel"}

#: Scales of the unit initial errors used when the start error is zero
#: (x m, x2 1/m, theta rad, x4 -, y m).
BASIS_ERROR_SCALES = (0.05, 0.5, 0.1, 0.1, 0.05)
#: Spacing (steps) of the errors injected along the horizon by :func:`error_injections`:
#: about one second, shorter than the closed loop's settling time.
SPREAD_EVERY_STEPS = 62
#: Relative regularisation of X_i X_i' in the preconditioner (rank-deficient for few errors).
PRECONDITIONER_REG = 1e-10


def initial_error_set(x0, mode: str = "auto") -> np.ndarray:
    """Initial errors to optimise over, shape (5, m).

    ``"start"``: the start error ``x0`` alone. ``"basis"``: the scaled unit errors
    :data:`BASIS_ERROR_SCALES` (J is then a weighted trace of ``P_0``, meaningful for any start).
    ``"both"``: the start error and the basis (gains good in every direction: what the
    nonlinear closed loop needs). ``"auto"``: ``"start"`` unless ``x0`` is (numerically)
    zero, as in the paper's circle case.
    """
    x0 = np.asarray(x0, dtype=float).reshape(5)
    if mode == "auto":
        mode = "start" if np.linalg.norm(x0) > 1e-9 else "basis"
    if mode == "start":
        return x0[:, None].copy()
    if mode == "basis":
        return np.diag(BASIS_ERROR_SCALES)
    if mode == "both":
        return np.column_stack([x0, np.diag(BASIS_ERROR_SCALES)]) if np.any(x0) \
            else np.diag(BASIS_ERROR_SCALES)
    raise ControllerError(f"initial-error mode must be auto, start, basis or both, "
                          f"got {mode!r}")


def error_injections(x0, n_steps: int, mode: str = "spread",
                     every_steps: int = SPREAD_EVERY_STEPS):
    """Errors the paper's cost sums over, and the steps at which they enter.

    Returns ``X0`` (5, m) and ``starts`` (m,) for :func:`cost_and_gradient`. Modes of
    :func:`initial_error_set` enter at step 0. ``"spread"``: those of ``"both"`` at step 0
    plus the scaled unit errors :data:`BASIS_ERROR_SCALES` again every ``every_steps`` steps
    along the horizon, so that every gain is seen by errors that have not decayed yet (with
    errors at step 0 only, the cost barely depends on the late gains).
    """
    if mode != "spread":
        X0 = initial_error_set(x0, mode)
        return X0, np.zeros(X0.shape[1], int)
    X0 = initial_error_set(x0, "both")
    later = np.arange(every_steps, n_steps, every_steps)
    B = np.diag(BASIS_ERROR_SCALES)
    X = np.concatenate([X0, np.tile(B, len(later))], axis=1)
    starts = np.concatenate([np.zeros(X0.shape[1], int), np.repeat(later, 5)])
    return X, starts


def error_moments(M, X0, starts=None):
    """Second moments ``S_i = sum_c x_c(i) x_c(i)'`` of the error trajectories of
    :func:`controller.ltv.rollout`, without forming them: ``S_0 = W_0``,
    ``S_{i+1} = M_i S_i M_i' + W_{i+1}`` with ``W_i`` the moment of the errors entering at i.
    ``M`` (N, 5, 5), ``X0`` (5, m), ``starts`` (m,) -> ``S`` (N+1, 5, 5)."""
    X0 = np.asarray(X0, dtype=float).reshape(5, -1)
    N = M.shape[0]
    s = np.zeros(X0.shape[1], int) if starts is None else np.asarray(starts, int)
    W = np.zeros((N + 1, 5, 5))
    keep = s <= N
    np.add.at(W, s[keep], np.einsum("im,jm->mij", X0[:, keep], X0[:, keep]))
    S = np.empty((N + 1, 5, 5))
    S[0] = W[0]
    MT = np.swapaxes(M, 1, 2)
    for i in range(N):
        S[i + 1] = M[i] @ S[i] @ MT[i] + W[i + 1]
    return S


def cost_and_gradient(K, Ad, Bd, Q, R, tau, X0, starts=None):
    """Cost J and its exact gradient dJ/dK.

    With ``M_i = Ad_i + Bd_i K_i``, ``P`` the cost-to-go of K
    (:func:`controller.ltv.policy_cost_matrices`) and ``S`` the errors' second moments
    (:func:`error_moments`)::

        J = tau sum_i tr((Q + K_i'R K_i) S_i)
        dJ/dK_i = 2 (tau R K_i + Bd_i' P_{i+1} M_i) S_i

    the adjoint recursion of ``docs/reference/paper.md`` §5 summed over the
    errors (``lambda_i = 2 P_i x(i)``). Two 5x5 recursions: the cost does not grow with the
    number of errors.

    Parameters
    ----------
    K : ndarray, shape (N, 3, 5)
    Ad, Bd : ndarray, shapes (N, 5, 5), (N, 5, 3)
    Q, R : ndarray, shapes (5, 5), (3, 3)
    tau : float
    X0 : ndarray, shape (5,) or (5, m)
    starts : ndarray of int, shape (m,), optional
        Step at which each column of ``X0`` enters (:func:`controller.ltv.rollout`).

    Returns
    -------
    J : float
        ``inf`` if the error trajectory overflows.
    G : ndarray, shape (N, 3, 5)
    """
    with np.errstate(over="ignore", invalid="ignore"):
        M = closed_loop(Ad, Bd, K)
        S = error_moments(M, X0, starts)[:-1]
        KS = K @ S
        J = tau * (np.einsum("ij,nji->", Q, S)
                   + np.einsum("ij,nji->", R, KS @ np.swapaxes(K, 1, 2)))
        if not (np.isfinite(J) and J >= 0):    # overflow, or moments too large to be PSD
            return np.inf, np.zeros_like(K)
        P = policy_cost_matrices(Ad, Bd, K, Q, R, tau)
        G = 2 * (tau * R @ KS + np.swapaxes(Bd, 1, 2) @ P[1:] @ M @ S)
    if not np.all(np.isfinite(G)):
        return np.inf, np.zeros_like(K)
    return float(J), G


def _preconditioner(K, Ad, Bd, Q, R, tau, X0, starts=None):
    """Return ``apply(G) -> Z``, the block-diagonal Hessian solve at gains K."""
    P = policy_cost_matrices(Ad, Bd, K, Q, R, tau)
    H = tau * R + np.swapaxes(Bd, 1, 2) @ P[1:] @ Bd             # (N, 3, 3)
    S = error_moments(closed_loop(Ad, Bd, K), X0, starts)[:-1]    # (N, 5, 5)
    tr = np.trace(S, axis1=1, axis2=2)
    eps = PRECONDITIONER_REG * np.maximum(tr, 1e-300) + 1e-300
    if not (np.all(np.isfinite(H)) and np.all(np.isfinite(S))):
        return lambda G: G                     # overflowed gains: plain gradient this step
    Sinv = np.linalg.pinv(S + eps[:, None, None] * np.eye(5), hermitian=True)
    Hinv = np.linalg.pinv(H, hermitian=True)
    return lambda G: 0.5 * Hinv @ G @ Sinv


@dataclass
class SynthesisResult:
    """Outcome of :func:`conjugate_gradient`.

    ``K`` (N, 3, 5) gains, ``cost`` final J, ``evaluations`` cost+gradient evaluations,
    ``iterations``, ``seconds``, ``message``, ``history`` list of (evaluations, seconds, J).
    """

    K: np.ndarray
    cost: float
    evaluations: int
    iterations: int
    seconds: float
    message: str
    history: list = field(default_factory=list)


def conjugate_gradient(Ad, Bd, Q, R, tau, X0, K0=None, beta: str = "dai-yuan",
                       precondition: bool = True, max_iter: int = 2000,
                       target_cost: float | None = None, rtol: float = 1e-10,
                       c2: float = 0.1, refresh: int = 1, max_seconds: float = np.inf,
                       progress: bool = False, starts=None) -> SynthesisResult:
    """Minimise J over all K(i) by nonlinear CG with a strong-Wolfe line search.

    Parameters
    ----------
    Ad, Bd, Q, R, tau : see :func:`cost_and_gradient`.
    X0 : ndarray, shape (5,) or (5, m)
        Initial error(s); J sums over the columns (:func:`initial_error_set`).
    K0 : ndarray, shape (N, 3, 5), optional
        Start gains (default zero, "arbitrary initial values" in the paper).
    beta : str
        ``dai-yuan`` (default), ``fletcher-reeves``, ``polak-ribiere``, ``hestenes-stiefel``
        or their initials.
    precondition : bool
        Block-diagonal Hessian preconditioning (False: the paper's plain method).
    max_iter : int
        Maximum CG iterations.
    target_cost : float, optional
        Stop as soon as J <= target_cost (e.g. ``1.01 * J*``).
    rtol : float
        Stop when an iteration lowers J by less than ``rtol * J`` three times in a row.
    c2 : float
        Curvature constant of the strong Wolfe conditions (< 1/2 for FR/DY theory).
    refresh : int
        Recompute the preconditioner every ``refresh`` iterations (and restart CG then).
    max_seconds : float
        Stop after this much wall time.
    progress : bool
        Show a tqdm progress bar.
    starts : ndarray of int, shape (m,), optional
        Step at which each error enters (:func:`error_injections`); default all at step 0.
    """
    name = BETA_ALIASES.get(beta.lower(), beta.lower())
    if name not in BETA_METHODS:
        raise ControllerError(f"unknown beta method {beta!r}: use one of "
                              f"{', '.join(BETA_METHODS)}")
    mu, nu = BETA_METHODS[name]
    N = Ad.shape[0]
    shape = (N, 3, 5)
    X0 = np.asarray(X0, dtype=float).reshape(5, -1)
    k = np.zeros(N * 15) if K0 is None else np.array(K0, dtype=float).reshape(-1)
    if k.size != N * 15:
        raise ControllerError(f"initial gains must have shape {shape}")
    t0 = time.perf_counter()
    cache = {"x": None, "f": None, "g": None}
    count = [0]
    history = []

    def evaluate(x):
        if cache["x"] is None or not np.array_equal(x, cache["x"]):
            f, G = cost_and_gradient(x.reshape(shape), Ad, Bd, Q, R, tau, X0, starts)
            count[0] += 1
            cache.update(x=x.copy(), f=f, g=G.reshape(-1))
        return cache["f"], cache["g"]

    def fun(x):
        return evaluate(x)[0]

    def grad(x):
        return evaluate(x)[1]

    pre = {"apply": None}

    def precond(x, g, renew=False):
        if not precondition:
            return g
        if renew or pre["apply"] is None:
            pre["apply"] = _preconditioner(x.reshape(shape), Ad, Bd, Q, R, tau, X0, starts)
        return pre["apply"](g.reshape(shape)).reshape(-1)

    f, g = evaluate(k)
    if not np.isfinite(f):
        raise ControllerError("initial gains make the error system overflow")
    history.append((count[0], time.perf_counter() - t0, f))
    z = precond(k, g)
    s = -z
    f_old = f + 0.5 * np.linalg.norm(g)
    message, stalls, it = "maximum iterations reached", 0, 0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=max_iter, desc=f"CG ({name})", unit="it", leave=False)
    try:
        for it in range(1, max_iter + 1):
            if target_cost is not None and f <= target_cost:
                message = "target cost reached"
                break
            if not np.any(g):
                message = "zero gradient (J does not depend on K: zero initial error?)"
                break
            if g @ s >= 0:            # not a descent direction: restart
                s = -z
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                alpha, *_ = line_search(fun, grad, k, s, gfk=g, old_fval=f, old_old_fval=f_old,
                                        c1=1e-4, c2=c2, maxiter=30)
            if alpha is None:
                if np.array_equal(s, -g):
                    message = "line search failed along the gradient"
                    break
                # restart: preconditioned steepest descent, then plain steepest descent
                s = -g if (np.array_equal(s, -z) or not precondition) else -z
                if np.array_equal(s, -g):
                    z = g
                continue
            k_new = k + alpha * s
            f_new, g_new = evaluate(k_new)
            renew = precondition and it % refresh == 0
            z_new = precond(k_new, g_new, renew)
            y = g_new - g
            num = mu * (g_new @ z_new) + (1 - mu) * (z_new @ y)
            den = nu * (g @ z) + (1 - nu) * (s @ y)
            b = num / den if (den != 0 and not (renew and refresh > 1)) else 0.0
            s = -z_new + b * s
            stalls = stalls + 1 if f - f_new <= rtol * abs(f) else 0
            f_old, f, g, z, k = f, f_new, g_new, z_new, k_new
            history.append((count[0], time.perf_counter() - t0, f))
            if bar is not None:
                bar.update(1)
                bar.set_postfix(J=f"{f:.6g}", evals=count[0])
            if stalls >= 3:
                message = "converged (relative decrease below rtol)"
                break
            if time.perf_counter() - t0 > max_seconds:
                message = f"time limit {max_seconds:g} s reached"
                break
        else:
            if target_cost is not None and f <= target_cost:
                message = "target cost reached"
    finally:
        if bar is not None:
            bar.close()
    return SynthesisResult(k.reshape(shape), float(f), count[0], it,
                           time.perf_counter() - t0, message, history)


def frozen_time_lqr_gains(Ad, Bd, Q, R, tau, knot_every: int = 8):
    """Initial gains for :func:`conjugate_gradient`: the stationary (infinite-horizon) discrete
    LQR gain of the error system frozen at knots every ``knot_every`` steps, held between knots.

    Uses :func:`scipy.linalg.solve_discrete_are`; at knots where the frozen system has no
    stabilising solution the previous knot's gain is kept (zero before the first).
    Returns K (N, 3, 5) with the sign convention ``ũ = K x~``.
    """
    from scipy.linalg import solve_discrete_are

    N = Ad.shape[0]
    K = np.zeros((N, 3, 5))
    Kk = np.zeros((3, 5))
    I5 = np.eye(5)
    for i in range(0, N, knot_every):
        A, B = Ad[i], Bd[i]
        if not np.allclose(np.delete(A, (2, 4), axis=0), np.delete(I5, (2, 4), axis=0)):
            A, B = Ad[max(i - 1, 0)], Bd[max(i - 1, 0)]   # a frame switch: use a neighbour
        try:
            P = solve_discrete_are(A, B, tau * Q, tau * R)
            Kk = -np.linalg.solve(tau * R + B.T @ P @ B, B.T @ P @ A)
        except (np.linalg.LinAlgError, ValueError):
            pass
        K[i:i + knot_every] = Kk
    return K


def conjugate_gradient_continuation(Ad, Bd, Q, R, tau, X0, n0: int = 64, growth: int = 2,
                                    stage_iter: int = 20, stage_rtol: float = 1e-3,
                                    **options) -> SynthesisResult:
    """:func:`conjugate_gradient` from K = 0 with horizon continuation.

    From K = 0 the error system is open loop and the cost grows polynomially with the
    horizon, which makes J(K) extremely ill-conditioned for the full N. Solve the first
    ``n0`` steps, then repeatedly extend the horizon by ``growth``: keep the gains of the
    first half, hold the gain of the middle step over the rest (the second half still shows
    the short horizon's end effect), and run at most ``stage_iter`` CG iterations; the last
    stage is the full problem with ``options`` (``target_cost``, ``max_iter``, ``beta``,
    ``precondition``...). Same method, same line search, no Riccati or DARE.

    Returns the :class:`SynthesisResult` of the full problem with evaluations, iterations
    and seconds summed over all stages; ``history`` holds the final stage only, with
    evaluation counts and times offset by the earlier stages.
    """
    from swerve.controller.ltv import cost as exact_cost

    N = Ad.shape[0]
    n = min(int(n0), N)
    K = np.zeros((n, 3, 5))
    evals = iters = 0
    t0 = time.perf_counter()
    max_seconds = options.pop("max_seconds", np.inf)
    X0 = np.asarray(X0, dtype=float).reshape(5, -1)
    starts = options.pop("starts", None)
    starts = np.zeros(X0.shape[1], int) if starts is None else np.asarray(starts, int)
    while True:
        last = n == N
        opts = dict(options, max_seconds=max_seconds - (time.perf_counter() - t0))
        if not last:
            opts.update(max_iter=stage_iter, target_cost=None, rtol=stage_rtol, progress=False)
        cols = starts < n
        res = conjugate_gradient(Ad[:n], Bd[:n], Q, R, tau, X0[:, cols], K0=K,
                                 starts=starts[cols], **opts)
        t_done = time.perf_counter() - t0
        if last:
            offset_t = t_done - res.seconds
            hist = [(e + evals, s + offset_t, f) for e, s, f in res.history]
            return SynthesisResult(res.K, res.cost, evals + res.evaluations,
                                   iters + res.iterations, t_done,
                                   f"{res.message} (horizon continuation from {min(n0, N)} "
                                   "steps)", hist)
        evals += res.evaluations
        iters += res.iterations
        m = min(N, growth * n)
        Kn = np.zeros((m, 3, 5))
        Kn[:n] = res.K
        Kn[n // 2:] = res.K[n // 2]
        with np.errstate(over="ignore", invalid="ignore"):
            cols = starts < m
            if not np.isfinite(exact_cost(Ad[:m], Bd[:m], Kn, Q, R, tau, X0[:, cols],
                                          starts[cols])):
                Kn[n // 2:] = 0.0
                Kn[:n] = res.K
        K, n = Kn, m
