"""Offline design in one call: trajectory -> reference -> gain schedule (either method)."""
from __future__ import annotations

import numpy as np

from swerve.controller.errors import ControllerError
from swerve.controller.gains_io import GainSchedule
from swerve.controller.kinematics import Geometry, Limits
from swerve.controller.ltv import error_system, initial_error
from swerve.controller.reference import Reference, Trajectory, build_reference
from swerve.controller.riccati import finite_horizon_lqr

METHODS = ("riccati", "paper")


def synthesize(traj: Trajectory, method: str = "riccati", geom: Geometry = Geometry(),
               limits: Limits = Limits(), frames: str = "rotating", beta: str = "dai-yuan",
               precondition: bool = True, initial_errors: str = "both", max_iter: int = 500,
               init: str = "continuation", target_ratio: float = 1.001,
               progress: bool = False) -> tuple[Reference, GainSchedule]:
    """Build the reference of ``traj`` and synthesise its gain schedule.

    Parameters
    ----------
    method : ``"riccati"`` (exact optimum) or ``"paper"`` (nonlinear CG, :mod:`.synthesis`).
    frames : ``"rotating"`` (re-anchored chained frames) or ``"fixed"`` (the paper's).
    beta, precondition, max_iter : options of :func:`controller.synthesis.conjugate_gradient`.
    initial_errors : ``both`` (default), ``auto``, ``start`` or ``basis``
        (:func:`.synthesis.initial_error_set`).
    init : start of the paper's method: ``"continuation"`` (K = 0 with horizon continuation,
        :func:`.synthesis.conjugate_gradient_continuation`, default), ``"zero"`` (K = 0 on the
        full horizon, the paper as printed) or ``"frozen-lqr"``
        (:func:`.synthesis.frozen_time_lqr_gains`).
    target_ratio : the paper's method stops once ``J <= target_ratio * J*`` (J* from the
        Riccati recursion of the same problem); 0 disables this stop.

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
    x0 = initial_error(ref, traj.start_state(geom))
    Kr, P = finite_horizon_lqr(Ad, Bd, traj.Q, traj.R, traj.tau_s,
                               progress=progress and method == "riccati")
    meta = dict(frames=frames, initial_error=x0.tolist())
    if method == "riccati":
        J = float(x0 @ P[0] @ x0)
        meta.update(J_star=J)
        K = Kr
    else:
        from swerve.controller.synthesis import (conjugate_gradient, conjugate_gradient_continuation,
                                          frozen_time_lqr_gains, initial_error_set)

        if init not in ("continuation", "zero", "frozen-lqr"):
            raise ControllerError(f"init must be continuation, zero or frozen-lqr, got {init!r}")
        K0 = (frozen_time_lqr_gains(Ad, Bd, traj.Q, traj.R, traj.tau_s)
              if init == "frozen-lqr" else None)
        X0 = initial_error_set(x0, initial_errors)
        J_star = float(np.einsum("im,ij,jm->", X0, P[0], X0))
        opts = dict(beta=beta, precondition=precondition, max_iter=max_iter,
                    target_cost=target_ratio * J_star if target_ratio > 0 else None,
                    progress=progress)
        if init == "continuation":
            res = conjugate_gradient_continuation(Ad, Bd, traj.Q, traj.R, traj.tau_s, X0, **opts)
        else:
            res = conjugate_gradient(Ad, Bd, traj.Q, traj.R, traj.tau_s, X0, K0=K0, **opts)
        K, J = res.K, res.cost
        meta.update(J_star=J_star, evaluations=res.evaluations, iterations=res.iterations,
                    seconds=res.seconds, message=res.message, beta=beta,
                    precondition=precondition, init=init, initial_errors=X0.tolist())
    gains = GainSchedule(K, ref.phi_rad[:-1].copy(), traj.tau_s, traj.Q, traj.R, traj.name,
                         method, float(J), meta)
    return ref, gains
