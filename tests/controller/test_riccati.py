"""The Riccati gain schedule, what feeds it and the law that uses it have the same bits
whichever BLAS kernel the CPU gets; the schedule still equals the NumPy/LAPACK recursion to
round-off."""
import inspect
import json

import numpy as np
import pytest

from swerve.controller.chained import chained_jacobian
from swerve.controller.kinematics import Geometry, Limits
from swerve.controller.ltv import error_system
from swerve.controller.reference import build_reference
from swerve.controller.trajectory import load_trajectory
from swerve.controller.riccati import finite_horizon_lqr


def numpy_lqr(Ad, Bd, Q, R, tau):
    """The recursion of :mod:`controller.riccati` with NumPy's ``@`` and LAPACK's solve."""
    N, n, m = Bd.shape
    K, P = np.zeros((N, m, n)), np.zeros((N + 1, n, n))
    for i in range(N - 1, -1, -1):
        A, B, Pn = Ad[i], Bd[i], P[i + 1]
        BtP = B.T @ Pn
        K[i] = -np.linalg.solve(tau * R + BtP @ B, BtP @ A)
        Pi = tau * Q + A.T @ Pn @ (A + B @ K[i])
        P[i] = 0.5 * (Pi + Pi.T)
    return K, P


@pytest.fixture(scope="module")
def line_problem():
    geom = Geometry()
    traj = load_trajectory("line", geom)
    Ad, Bd = error_system(build_reference(traj, geom, Limits()))
    return Ad, Bd, traj.Q, traj.R, traj.tau_s


def test_line_schedule_agrees_with_numpy(line_problem):
    K, P = finite_horizon_lqr(*line_problem)
    K0, P0 = numpy_lqr(*line_problem)
    assert K.shape == K0.shape == (2500, 3, 5) and P.shape == P0.shape == (2501, 5, 5)
    np.testing.assert_allclose(K, K0, rtol=1e-9, atol=1e-9 * np.abs(K0).max())
    np.testing.assert_allclose(P, P0, rtol=1e-9, atol=1e-9 * np.abs(P0).max())
    assert np.array_equal(P, np.swapaxes(P, 1, 2))


def test_reanchored_frames_agree_with_numpy(switching_reference):
    ref, tau = switching_reference, switching_reference.tau_s
    Ad, Bd = error_system(ref)
    switches = np.flatnonzero(np.diff(ref.phi_rad[:-1]))
    assert len(switches) >= 1
    for i in switches:
        A, B = np.eye(5), np.zeros((5, 3))
        A[2, 1] = A[4, 3] = tau * ref.ud[i, 0]
        B[0, 0] = B[1, 1] = B[3, 2] = tau
        B[2, 0], B[4, 0] = tau * ref.xd[i, 1], tau * ref.xd[i, 3]
        s = ref.states[i + 1]
        T = (chained_jacobian(s, ref.geom, ref.phi_rad[i + 1])
             @ np.linalg.inv(chained_jacobian(s, ref.geom, ref.phi_rad[i])))
        np.testing.assert_allclose(Ad[i], T @ A, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(Bd[i], T @ B, rtol=1e-12, atol=1e-14)
    tr = ref.trajectory
    K, P = finite_horizon_lqr(Ad, Bd, tr.Q, tr.R, tau)
    K0, P0 = numpy_lqr(Ad, Bd, tr.Q, tr.R, tau)
    np.testing.assert_allclose(K, K0, rtol=1e-9, atol=1e-9 * np.abs(K0).max())
    np.testing.assert_allclose(P, P0, rtol=1e-9, atol=1e-9 * np.abs(P0).max())


_PROBE = """
from swerve.controller.tracking import TrackingLaw
from swerve.controller.gains_io import GainSchedule

geom, limits = Geometry(), Limits()
out = {}
line = load_trajectory("line", geom)
ref = build_reference(line, geom, limits)
Ad, Bd = error_system(ref)
K, P = finite_horizon_lqr(Ad, Bd, line.Q, line.R, line.tau_s)
out["line K, P"] = h(K, P)
out["numpy K"] = h(numpy_lqr(Ad, Bd, line.Q, line.R, line.tau_s)[0])
law = TrackingLaw(ref, GainSchedule(K, ref.phi_rad[:-1], line.tau_s, line.Q, line.R, "line",
                                    "riccati", float("nan")), limits)
start = ref.start_state() + np.array([0.01, -0.02, 0.05, 0.0, 0.0])
out["law u"] = h([law.step(k * 0.016, start).u for k in range(0, 2400, 7)])
circle = build_reference(load_trajectory("circle", geom), geom, limits)
out["circle Ad, Bd"] = h(*error_system(circle))
s_curve = build_reference(load_trajectory(TRAJECTORY_DIR / "s_curve.csv", geom), geom, limits)
out["s_curve xd, ud"] = h(s_curve.xd, s_curve.ud)
print(json.dumps(out))
"""


def test_same_bits_under_different_blas_kernels(other_cpu, probe_prelude):
    code = probe_prelude + inspect.getsource(numpy_lqr) + _PROBE
    out = {core: json.loads(other_cpu({"OPENBLAS_CORETYPE": core}, "-c", code)) for core in ("Nehalem", "Haswell")}
    # the probe can tell the kernels apart: the same recursion in NumPy/LAPACK differs
    assert out["Nehalem"].pop("numpy K") != out["Haswell"].pop("numpy K")
    assert out["Nehalem"] == out["Haswell"]
