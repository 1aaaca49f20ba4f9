import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from swerve.controller.errors import ControllerError
from swerve.controller.ltv import cost, error_system, initial_error, policy_cost_matrices
from swerve.controller.riccati import finite_horizon_lqr
from swerve.controller.synthesis import (BETA_METHODS, conjugate_gradient, cost_and_gradient,
                                  frozen_time_lqr_gains, initial_error_set)

RNG = np.random.default_rng(44)


def problem(ref):
    Ad, Bd = error_system(ref)
    tr = ref.trajectory
    return Ad, Bd, tr.Q, tr.R, tr.tau_s


def test_frame_switch_is_in_the_error_system(switching_reference):
    Ad, _ = error_system(switching_reference)
    i = np.flatnonzero(np.diff(switching_reference.phi_rad[:-1]))
    assert len(i) >= 1
    # off-chain entries appear only where the frame is re-anchored
    mask = np.ones((5, 5), bool)
    mask[[0, 1, 2, 3, 4, 2, 4], [0, 1, 2, 3, 4, 1, 3]] = False
    off = np.abs(Ad[:, mask]).max(axis=1)
    assert set(np.flatnonzero(off > 1e-9)) == set(i)


def complex_step_cost(K, Ad, Bd, Q, R, tau, X0):
    """The cost written out independently, valid for complex gains (complex-step check)."""
    X = X0.astype(complex)
    J = 0.0
    for i in range(K.shape[0]):
        U = K[i] @ X
        J = J + tau * (np.sum(X * (Q @ X)) + np.sum(U * (R @ U)))
        X = (Ad[i] + Bd[i] @ K[i]) @ X
    return J


@pytest.mark.parametrize("ref_name", ["switching_reference", "short_line_reference"])
def test_gradient_equals_finite_differences(ref_name, request):
    ref = request.getfixturevalue(ref_name)
    Ad, Bd, Q, R, tau = problem(ref)
    N = Ad.shape[0]
    K0, _ = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    K = 0.7 * K0 + 0.05 * RNG.standard_normal((N, 3, 5))
    X0 = np.c_[initial_error(ref, ref.start_state()), 0.05 * RNG.standard_normal(5)]
    J, G = cost_and_gradient(K, Ad, Bd, Q, R, tau, X0)
    assert J == pytest.approx(cost(Ad, Bd, K, Q, R, tau, X0), rel=1e-12)
    for _ in range(3):                                   # directional derivatives
        D = RNG.standard_normal(K.shape)
        h = 1e-20
        cs = complex_step_cost(K + 1j * h * D, Ad, Bd, Q, R, tau, X0).imag / h
        np.testing.assert_allclose(np.sum(G * D), cs, rtol=1e-9)
        h = 1e-4 / np.linalg.norm(D)                     # central differences, too
        fd = (cost(Ad, Bd, K + h * D, Q, R, tau, X0)
              - cost(Ad, Bd, K - h * D, Q, R, tau, X0)) / (2 * h)
        np.testing.assert_allclose(np.sum(G * D), fd, rtol=1e-6,
                                   atol=1e-6 * np.linalg.norm(G) * np.linalg.norm(D))
    for idx in [(0, 0, 2), (N // 2, 1, 1), (N - 2, 2, 3), (N // 3, 0, 4)]:   # single entries
        E = np.zeros_like(K)
        E[idx] = 1.0
        h = 1e-5 * max(1.0, abs(K[idx]))
        fd = (cost(Ad, Bd, K + h * E, Q, R, tau, X0)
              - cost(Ad, Bd, K - h * E, Q, R, tau, X0)) / (2 * h)
        np.testing.assert_allclose(G[idx], fd, rtol=1e-6, atol=1e-9 * abs(J))


@pytest.mark.parametrize("ref_name", ["switching_reference", "short_line_reference"])
def test_riccati_cost_is_exact(ref_name, request):
    ref = request.getfixturevalue(ref_name)
    Ad, Bd, Q, R, tau = problem(ref)
    K, P = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    np.testing.assert_allclose(P, policy_cost_matrices(Ad, Bd, K, Q, R, tau), rtol=1e-9,
                               atol=1e-12)
    for _ in range(3):
        x0 = RNG.standard_normal(5)
        np.testing.assert_allclose(x0 @ P[0] @ x0, cost(Ad, Bd, K, Q, R, tau, x0), rtol=1e-9)
    # optimality: no perturbation of the gains does better
    x0 = RNG.standard_normal(5)
    J = cost(Ad, Bd, K, Q, R, tau, x0)
    for _ in range(3):
        assert cost(Ad, Bd, K + 1e-3 * RNG.standard_normal(K.shape), Q, R, tau, x0) >= J


def test_riccati_approaches_the_stationary_lqr_on_the_line(robot):
    from swerve.controller.reference import build_reference
    from swerve.controller.trajectory import load_trajectory

    ref = build_reference(load_trajectory("line_r_negative"), *robot)
    Ad, Bd, Q, R, tau = problem(ref)
    K, _ = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    P = solve_discrete_are(Ad[0], Bd[0], tau * Q, tau * R)
    Kinf = -np.linalg.solve(tau * R + Bd[0].T @ P @ Bd[0], Bd[0].T @ P @ Ad[0])
    np.testing.assert_allclose(K[0], Kinf, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(K[-1], 0)          # no terminal cost: last gain is zero


def test_riccati_needs_no_controllability():
    """An uncontrollable, unstable mode: the recursion still gives the exact optimum."""
    N, tau = 50, 0.1
    Ad = np.broadcast_to(np.diag([1.1, 1, 1, 1, 1]), (N, 5, 5)).copy()
    Bd = np.zeros((N, 5, 3))
    Bd[:, 1:4, :] = np.eye(3) * tau
    Q, R = np.eye(5), np.eye(3)
    K, P = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    x0 = np.ones(5)
    assert np.all(np.isfinite(K))
    np.testing.assert_allclose(x0 @ P[0] @ x0, cost(Ad, Bd, K, Q, R, tau, x0), rtol=1e-10)


@pytest.mark.parametrize("precondition", [False, True])
def test_paper_method_never_beats_jstar_and_approaches_it(short_line_reference, precondition):
    Ad, Bd, Q, R, tau = problem(short_line_reference)
    x0 = initial_error(short_line_reference, short_line_reference.start_state())
    _, P = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    J_star = x0 @ P[0] @ x0
    res = conjugate_gradient(Ad, Bd, Q, R, tau, x0, precondition=precondition, max_iter=150)
    costs = np.array([h[2] for h in res.history])
    assert np.all(np.diff(costs) <= 1e-12 * costs[0])          # monotone
    assert res.cost >= J_star * (1 - 1e-9)
    assert res.cost <= 1.1 * J_star
    assert costs[0] > 1.4 * J_star                               # it did real work


@pytest.mark.parametrize("beta", list(BETA_METHODS) + ["dy", "prp"])
def test_beta_family(short_line_reference, beta):
    Ad, Bd, Q, R, tau = problem(short_line_reference)
    x0 = initial_error(short_line_reference, short_line_reference.start_state())
    res = conjugate_gradient(Ad, Bd, Q, R, tau, x0, beta=beta, precondition=False, max_iter=20)
    assert res.cost < 0.85 * res.history[0][2]


def test_unknown_beta(short_line_reference):
    Ad, Bd, Q, R, tau = problem(short_line_reference)
    with pytest.raises(ControllerError, match="unknown beta"):
        conjugate_gradient(Ad, Bd, Q, R, tau, np.ones(5), beta="newton")


def test_zero_initial_error_uses_a_basis(switching_reference):
    Ad, Bd, Q, R, tau = problem(switching_reference)
    X0 = initial_error_set(np.zeros(5))
    assert X0.shape == (5, 5) and np.linalg.matrix_rank(X0) == 5
    res0 = conjugate_gradient(Ad, Bd, Q, R, tau, np.zeros(5), max_iter=5)
    assert res0.cost == 0 and "zero gradient" in res0.message
    _, P = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    J_star = np.einsum("im,ij,jm->", X0, P[0], X0)
    res = conjugate_gradient(Ad, Bd, Q, R, tau, X0, max_iter=200)
    assert J_star * (1 - 1e-9) <= res.cost <= 1.05 * J_star


def test_warm_start_is_close_on_the_line(short_line_reference):
    Ad, Bd, Q, R, tau = problem(short_line_reference)
    x0 = initial_error(short_line_reference, short_line_reference.start_state())
    _, P = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    K0 = frozen_time_lqr_gains(Ad, Bd, Q, R, tau)
    J0 = cost(Ad, Bd, K0, Q, R, tau, x0)
    assert x0 @ P[0] @ x0 <= J0 <= 1.2 * (x0 @ P[0] @ x0)


def test_horizon_continuation_reaches_jstar(robot):
    """Cold start K = 0 with horizon continuation: within 1 % of J* on a 600-step line."""
    import dataclasses

    from swerve.controller.reference import build_reference
    from swerve.controller.trajectory import load_trajectory
    from swerve.controller.synthesis import conjugate_gradient_continuation

    traj = load_trajectory("line_r_negative")
    traj = dataclasses.replace(traj, n_steps=600, tf_s=600 * traj.tau_s)
    ref = build_reference(traj, *robot)
    Ad, Bd, Q, R, tau = problem(ref)
    x0 = initial_error(ref, ref.start_state())
    _, P = finite_horizon_lqr(Ad, Bd, Q, R, tau)
    J_star = x0 @ P[0] @ x0
    res = conjugate_gradient_continuation(Ad, Bd, Q, R, tau, x0, target_cost=1.01 * J_star,
                                          max_iter=400)
    assert J_star * (1 - 1e-9) <= res.cost <= 1.01 * J_star
    assert res.K.shape == (600, 3, 5) and "continuation" in res.message
    assert res.cost == pytest.approx(cost(Ad, Bd, res.K, Q, R, tau, x0), rel=1e-10)


def test_initial_error_sets():
    x0 = np.array([0.0, 0.0, -0.5, -1.0, 0.0])
    np.testing.assert_allclose(initial_error_set(x0, "start"), x0[:, None])
    both = initial_error_set(x0, "both")
    assert both.shape == (5, 6)
    np.testing.assert_allclose(both[:, 0], x0)
    assert np.linalg.matrix_rank(both) == 5
    assert initial_error_set(np.zeros(5), "both").shape == (5, 5)
    with pytest.raises(ControllerError, match="initial-error mode"):
        initial_error_set(x0, "all")


def test_spread_errors_cost_and_gradient(switching_reference):
    """Errors entering along the horizon: J is the sum of x' P_start x under the gains' own
    cost-to-go, and the moment-form gradient matches central differences."""
    from swerve.controller.ltv import injected_cost
    from swerve.controller.synthesis import error_injections

    Ad, Bd, Q, R, tau = problem(switching_reference)
    N = Ad.shape[0]
    X0, starts = error_injections(np.array([0.01, 0.0, 0.05, 0.0, -0.01]), N, "spread",
                                  every_steps=20)
    assert X0.shape == (5, 6 + 5 * len(range(20, N, 20))) and starts.max() == 80
    K = frozen_time_lqr_gains(Ad, Bd, Q, R, tau, knot_every=10) + 0.1 * RNG.standard_normal(
        (N, 3, 5))
    J, G = cost_and_gradient(K, Ad, Bd, Q, R, tau, X0, starts)
    P = policy_cost_matrices(Ad, Bd, K, Q, R, tau)
    assert J == pytest.approx(injected_cost(P, X0, starts), rel=1e-10)
    assert J == pytest.approx(cost(Ad, Bd, K, Q, R, tau, X0, starts), rel=1e-10)
    for i, r, c in [(0, 0, 0), (25, 1, 2), (61, 2, 4), (99, 0, 3)]:
        dK = np.zeros_like(K)
        dK[i, r, c] = 1e-5
        fd = (cost(Ad, Bd, K + dK, Q, R, tau, X0, starts)
              - cost(Ad, Bd, K - dK, Q, R, tau, X0, starts)) / 2e-5
        assert G[i, r, c] == pytest.approx(fd, rel=1e-4, abs=1e-8)


@pytest.mark.slow
def test_default_paper_gains_track_the_curvilinear_path(robot):
    """The default paper synthesis (spread errors, frozen-time LQR start, CG to 1.001 J*) passes
    its own check and tracks the curvilinear path like Riccati; the former default (errors at
    t0 only, horizon continuation) diverged there."""
    from swerve.controller.gain_schedule import synthesize
    from swerve.controller.trajectory import load_trajectory
    from swerve.controller.simulate import metrics, simulate
    from swerve.controller.tracking import TrackingLaw

    geom, limits = robot
    traj = load_trajectory("curvilinear", geom)
    ref, gains = synthesize(traj, "paper", geom, limits)
    assert gains.cost <= 1.001 * gains.meta["J_star"]
    assert gains.meta["check"]["max_tracking_error_m"] < 1e-3
    m = metrics(simulate(TrackingLaw(ref, gains, limits), traj.start_state(geom)),
                traj.Q, traj.R, traj.tau_s)
    assert m["max_position_error_m"] < 1e-3 and m["final_position_error_m"] < 1e-4
