"""Closed-loop simulation on the nonlinear model (1)-(5) with the robot's own TrackingLaw.

Inputs are held for one step tau (zero-order hold, as on the robot) and the model is
integrated with RK4. The run ends when the reference clock reaches tf (or at
``max_time_factor * tf`` if the governor keeps it back).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swerve.controller.kinematics import rk4_step
from swerve.controller.tracking import TrackingLaw


@dataclass
class SimResult:
    """Simulation record, one row per control step.

    ``t_s`` (n,), ``states`` (n, 5), ``inputs`` (n, 3) applied (saturated) inputs,
    ``raw_inputs`` (n, 3) before saturation, ``ref_time_s`` (n,), ``ref_states`` (n, 5) desired
    states at the reference time, ``errors`` (n, 5) chained errors, ``u_tilde`` (n, 3)
    chained input corrections ``K x~``.
    """

    t_s: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    raw_inputs: np.ndarray
    ref_time_s: np.ndarray
    ref_states: np.ndarray
    errors: np.ndarray
    u_tilde: np.ndarray
    tf_s: float

    @property
    def position_error_m(self) -> np.ndarray:
        """Distance between robot and reference point, m, shape (n,)."""
        return np.hypot(*(self.states[:, :2] - self.ref_states[:, :2]).T)


def simulate(law: TrackingLaw, x0, substeps: int = 2, max_time_factor: float = 1.5) -> SimResult:
    """Run ``law`` from state ``x0`` (5,) until its reference ends.

    Returns a :class:`SimResult`; raises whatever the law raises (e.g.
    :class:`controller.errors.SingularityError` for the plain law on a singular path).
    """
    ref = law.reference
    tau, geom = ref.tau_s, ref.geom
    law.reset()
    x = np.asarray(x0, dtype=float).copy()
    n_max = int(np.ceil(max_time_factor * ref.tf_s / tau))
    rows = []
    for k in range(n_max):
        t = k * tau
        out = law.step(t, x)
        if out.finished:
            break
        u = out.inputs
        rows.append((t, x.copy(), np.array(u), out.raw, out.reference_time_s, out.desired_state,
                     out.error, out.u - out.ud))
        x = rk4_step(x, u, tau, geom, substeps)
    cols = list(zip(*rows))
    return SimResult(np.array(cols[0]), np.array(cols[1]), np.array(cols[2]),
                     np.array(cols[3]), np.array(cols[4]), np.array(cols[5]),
                     np.array(cols[6]), np.array(cols[7]), ref.tf_s)


def metrics(res: SimResult, Q, R, tau: float) -> dict:
    """Summary numbers of a run (SI units).

    ``rms_position_error_m`` and ``max_position_error_m`` over t >= tf/4,
    ``final_position_error_m``, ``max_abs_v1_mps``, ``max_abs_steer_rate_radps``,
    ``cost`` (``tau sum x~'Q x~ + ũ'R ũ`` of the run in chained coordinates),
    ``max_reference_lag_s`` (governor), ``saturated_fraction``, ``duration_s``.
    """
    e = res.position_error_m
    late = res.t_s >= res.tf_s / 4
    X, U = res.errors, res.u_tilde
    J = tau * (np.einsum("ni,ij,nj->", X, Q, X) + np.einsum("ni,ij,nj->", U, R, U))
    sat = np.any(np.abs(res.raw_inputs - res.inputs) > 1e-12, axis=1)
    return dict(
        rms_position_error_m=float(np.sqrt(np.mean(e[late] ** 2))),
        max_position_error_m=float(e[late].max()),
        final_position_error_m=float(e[-1]),
        max_abs_v1_mps=float(np.abs(res.inputs[:, 0]).max()),
        max_abs_steer_rate_radps=float(np.abs(res.inputs[:, 1:]).max()),
        cost=float(J),
        max_reference_lag_s=float(np.max(res.t_s - res.ref_time_s)),
        saturated_fraction=float(sat.mean()),
        duration_s=float(res.t_s[-1] + tau),
    )
