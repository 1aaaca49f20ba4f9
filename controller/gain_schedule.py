"""Offline design in one call: trajectory -> reference -> gain schedule (either method)."""
from __future__ import annotations

import dataclasses

import numpy as np

from swerve.core import small_linalg as sl
from swerve.controller.errors import ControllerError
from swerve.controller.gains_io import GainSchedule
from swerve.controller.kinematics import Geometry, Limits
from swerve.controller.ltv import error_system, initial_error, injected_cost
from swerve.controller.reference import Reference, build_reference
from swerve.controller.simulate import simulate
from swerve.controller.tracking import TrackingLaw
from swerve.controller.trajectory import Trajectory
from swerve.controller.riccati import finite_horizon_lqr

METHODS = ("riccati", "paper")
#: Times the paper's method tightens its J/J* target tenfold while its gains fail the spectrum
#: check (:func:`check_spectrum`).
REFINE_STAGES = 3


def synthesize(traj: Trajectory, method: str = "riccati", geom: Geometry = Geometry(),
               limits: Limits = Limits(), frames: str = "rotating", beta: str = "dai-yuan",
               precondition: bool = True, initial_errors: str = "spread", max_iter: int = 500,
               init: str = "frozen-lqr", target_ratio: float = 1.001,
               progress: bool = False, check: bool = True,
               start=None, lqr=finite_horizon_lqr) -> tuple[Reference, GainSchedule]:
    """Build the reference of ``traj`` and synthesise its gain schedule.

    Parameters
    ----------
    method : ``"riccati"`` (exact optimum) or ``"paper"`` (nonlinear CG, :mod:`.synthesis`).
    frames : ``"rotating"`` (re-anchored chained frames) or ``"fixed"`` (the paper's).
    beta, precondition, max_iter : options of :func:`controller.synthesis.conjugate_gradient`.
    initial_errors : ``spread`` (default: start error and unit errors at t0, and unit errors
        again every second along the horizon), ``both``, ``auto``, ``start`` or ``basis``
        (:func:`.synthesis.error_injections`).
    init : start of the paper's method: ``"frozen-lqr"`` (default,
        :func:`.synthesis.frozen_time_lqr_gains`), ``"continuation"`` (K = 0 with horizon
        continuation, :func:`.synthesis.conjugate_gradient_continuation`) or ``"zero"`` (K = 0
        on the full horizon, the paper as printed).
    target_ratio : the paper's method stops once ``J <= target_ratio * J*`` (J* from the
        Riccati recursion of the same problem); 0 disables this stop.
    check : run :func:`check_gains` on the paper's gains (raises :class:`GainCheckError`).
    start : robot start state (5,); default the trajectory's. Its error is part of the
        paper's cost.
    lqr : the finite-horizon Riccati solver, :func:`controller.riccati.finite_horizon_lqr` or
        one with its signature and results (:meth:`controller.riccati_cache.RiccatiCache.solve`).

    Returns
    -------
    (Reference, GainSchedule)
        ``GainSchedule.cost`` is J from the start error (riccati) or from the optimised set
        (paper); ``meta`` holds ``J_star`` (Riccati optimum of the same set) and, for the
        paper's method, ``evaluations``, ``iterations``, ``seconds``, ``message``, ``beta``.
    """
    if method not in METHODS:
        raise ControllerError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    ref = build_reference(traj, geom, limits, frames)
    Ad, Bd = error_system(ref)
    start = traj.start_state(geom) if start is None else np.asarray(start, float)
    x0 = initial_error(ref, start)
    Kr, P = lqr(Ad, Bd, traj.Q, traj.R, traj.tau_s, progress=progress and method == "riccati")
    meta = dict(frames=frames, initial_error=x0.tolist())
    if method == "riccati":
        J = sl.dot(x0.tolist(), sl.matvec(P[0].tolist(), x0.tolist()))  # same bits on any CPU
        meta.update(J_star=J)
        K = Kr
    else:
        # the paper's method runs on SciPy's line search (~0.3 s to import): only it loads it
        from swerve.controller.synthesis import (conjugate_gradient,
                                                 conjugate_gradient_continuation,
                                                 error_injections, frozen_time_lqr_gains)

        if init not in ("continuation", "zero", "frozen-lqr"):
            raise ControllerError(f"init must be continuation, zero or frozen-lqr, got {init!r}")
        K0 = (frozen_time_lqr_gains(Ad, Bd, traj.Q, traj.R, traj.tau_s)
              if init == "frozen-lqr" else None)
        X0, starts = error_injections(x0, traj.n_steps, initial_errors)
        J_star = injected_cost(P, X0, starts)
        opts = dict(beta=beta, precondition=precondition, max_iter=max_iter,
                    target_cost=target_ratio * J_star if target_ratio > 0 else None,
                    progress=progress, starts=starts)
        if init == "continuation":
            res = conjugate_gradient_continuation(Ad, Bd, traj.Q, traj.R, traj.tau_s, X0, **opts)
        else:
            res = conjugate_gradient(Ad, Bd, traj.Q, traj.R, traj.tau_s, X0, K0=K0, **opts)
        evals, iters, secs = res.evaluations, res.iterations, res.seconds
        # stopping rule on the spectrum: J/J* alone leaves gains on a few steps unconstrained
        ratio = target_ratio
        for _ in range(REFINE_STAGES if check and target_ratio > 0 else 0):
            try:
                check_spectrum(Ad, Bd, res.K, Kr, traj.tau_s)
                break
            except GainCheckError:
                ratio = 1 + (ratio - 1) / 10
                opts.update(target_cost=ratio * J_star)
                res = conjugate_gradient(Ad, Bd, traj.Q, traj.R, traj.tau_s, X0, K0=res.K, **opts)
                evals, iters, secs = evals + res.evaluations, iters + res.iterations, \
                    secs + res.seconds
        K, J = res.K, res.cost
        meta.update(J_star=J_star, evaluations=evals, iterations=iters, target_ratio=ratio,
                    seconds=secs, message=res.message, beta=beta,
                    precondition=precondition, init=init, initial_errors=initial_errors,
                    injected_errors=int(X0.shape[1]))
    gains = GainSchedule(K, ref.phi_rad[:-1].copy(), traj.tau_s, traj.Q, traj.R, traj.name,
                         method, float(J), meta)
    if method == "paper" and check:
        gains.meta["check"] = check_gains(ref, gains, Kr, limits, start)
    return ref, gains


#: The nonlinear closed loop "tracks" if its position error over t >= tf/4 stays below this
#: (m) or below :data:`CHECK_RICCATI_FACTOR` times Riccati's largest error from the same start.
CHECK_TRACKING_TOL_M = 0.01
CHECK_RICCATI_FACTOR = 2.0
#: Start perturbations (dx m, dy m, dtheta rad) of the nonlinear check, added to the start.
CHECK_PERTURBATIONS = ((0.02, 0.0, 0.1), (0.0, -0.02, -0.1), (-0.02, 0.02, 0.0))
#: Frozen closed-loop eigenvalues against Riccati's: an eigenvalue with a real part below both
#: ``-CHECK_ALTERNATION`` and Riccati's smallest minus :data:`CHECK_EIG_MARGIN` is a mode that
#: flips sign every step and hardly decays (an Euler pole far faster than the 62.5 Hz loop,
#: which the sampled robot does not reproduce); the spectral radius may exceed max(1,
#: Riccati's) by :data:`CHECK_RADIUS_MARGIN` (0.01 per step: growth by 1.9x/s). Gains that are
#: J-optimal to 1e-6 still show eigenvalues down to -0.95 on a few dozen steps of the drawn
#: square and track like Riccati's, so the bound is near -1; the tracking check decides the rest.
CHECK_EIG_MARGIN = 0.2
CHECK_ALTERNATION = 0.97
CHECK_RADIUS_MARGIN = 0.01
#: A spectrum condition fails only if it holds on this many consecutive steps (0.16 s): a
#: single step's frozen eigenvalues say little about a time-varying loop.
CHECK_PERSIST_STEPS = 10


def _first_run(mask, length):
    """Index where ``mask`` (n,) first holds on ``length`` consecutive entries, else None."""
    run = 0
    for i, m in enumerate(mask):
        run = run + 1 if m else 0
        if run >= length:
            return i - length + 1
    return None


class GainCheckError(ControllerError):
    """A gain schedule failed :func:`check_gains`. Attributes: ``check`` (its name), ``t_s``."""

    def __init__(self, check: str, t_s: float, detail: str):
        self.check, self.t_s = check, t_s
        super().__init__(f"gain check '{check}' fails at t = {t_s:.2f} s: {detail}")


def closed_loop_spectrum(Ad, Bd, K):
    """Frozen-time closed-loop eigenvalues of ``Ad_i + Bd_i K_i``: spectral radius (N,) and
    most negative real part (N,)."""
    ev = np.linalg.eigvals(Ad + Bd @ K)
    return np.abs(ev).max(axis=1), ev.real.min(axis=1)


def check_spectrum(Ad, Bd, K, K_riccati, tau_s: float):
    """The ``spectrum`` check of :func:`check_gains` (raises :class:`GainCheckError`).

    Returns the spectral radius (N,), most negative real part (N,) and Riccati's (N,)."""
    t = np.arange(K.shape[0]) * tau_s
    rho, low = closed_loop_spectrum(Ad, Bd, K)
    rho_r, low_r = closed_loop_spectrum(Ad, Bd, K_riccati)
    n = CHECK_PERSIST_STEPS
    i = _first_run(rho > np.maximum(rho_r, 1.0) + CHECK_RADIUS_MARGIN, n)
    if i is not None:
        raise GainCheckError("spectrum", t[i], f"closed-loop spectral radius {rho[i]:.3f} "
                             f"(Riccati's {rho_r[i]:.3f}) for {n}+ steps: the error grows")
    floor = min(low_r.min() - CHECK_EIG_MARGIN, -CHECK_ALTERNATION)
    i = _first_run(low < floor, n)
    if i is not None:
        raise GainCheckError("spectrum", t[i], f"closed-loop eigenvalue {low[i]:.2f} below "
                             f"{floor:.2f} (Riccati's lowest {low_r.min():.2f}) for {n}+ "
                             "steps: the loop alternates from step to step")
    return rho, low, low_r


def check_gains(ref: Reference, gains: GainSchedule, K_riccati, limits: Limits, start,
                tol_m: float = CHECK_TRACKING_TOL_M) -> dict:
    """Refuse gains that the robot should not run (raises :class:`GainCheckError`).

    Checks, in order: ``spectrum`` (:func:`check_spectrum`: frozen closed-loop eigenvalues
    along the reference against Riccati's for :data:`CHECK_PERSIST_STEPS` consecutive steps,
    see :data:`CHECK_ALTERNATION`, :data:`CHECK_RADIUS_MARGIN`); ``tracking`` (the nonlinear
    closed loop on model (1)-(5) from ``start`` (5,) and from :data:`CHECK_PERTURBATIONS` of it
    keeps the position error over t >= tf/4 below ``tol_m`` or :data:`CHECK_RICCATI_FACTOR`
    times that of Riccati's gains from the same start). Returns the measured numbers.
    """
    Ad, Bd = error_system(ref)
    rho, low, low_r = check_spectrum(Ad, Bd, gains.K, K_riccati, ref.tau_s)
    starts = [np.asarray(start, float)] + [np.asarray(start, float) + np.r_[d, 0.0, 0.0]
                                           for d in CHECK_PERTURBATIONS]
    worst = 0.0
    riccati = dataclasses.replace(gains, K=np.asarray(K_riccati), method="riccati")
    for k, x0 in enumerate(starts):
        res_r = simulate(TrackingLaw(ref, riccati, limits), x0)
        bound = max(tol_m, CHECK_RICCATI_FACTOR * float(
            res_r.position_error_m[res_r.t_s >= res_r.tf_s / 4].max()))
        res = simulate(TrackingLaw(ref, gains, limits), x0)
        e = res.position_error_m
        late = res.t_s >= res.tf_s / 4
        over = np.flatnonzero(late & ~(e <= bound))
        if over.size:
            i = over[0]
            what = ("the start state" if k == 0
                    else f"the start perturbed by {CHECK_PERTURBATIONS[k - 1]}")
            raise GainCheckError("tracking", res.t_s[i], f"from {what} the position error "
                                 f"reaches {e[over].max():.4g} m, above the bound {bound:.4g} m, "
                                 "on the nonlinear model")
        worst = max(worst, float(e[late].max()))
    return dict(max_spectral_radius=float(rho.max()), min_eigenvalue_real=float(low.min()),
                riccati_min_eigenvalue_real=float(low_r.min()),
                max_tracking_error_m=worst, starts_checked=len(starts))
