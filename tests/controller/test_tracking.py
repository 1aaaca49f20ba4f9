import dataclasses

import numpy as np
import pytest

from swerve.controller.chained import inputs_from_chained, to_chained
from swerve.controller.gain_schedule import synthesize
from swerve.controller.errors import ControllerError, SingularityError
from swerve.controller.reference import build_reference
from swerve.controller.trajectory import TRAJECTORY_DIR, load_trajectory
from swerve.controller.simulate import metrics, simulate
from swerve.controller.ltv import chained_error
from swerve.controller.tracking import STATE_MARGIN, TrackingLaw



def short(traj, n_steps):
    """The first ``n_steps`` of a trajectory."""
    return dataclasses.replace(traj, n_steps=n_steps, tf_s=n_steps * traj.tau_s)


def run(name, robot, x0=None, frames="rotating", governor=True, n_steps=None):
    geom, limits = robot
    traj = load_trajectory(name if not name.endswith(".csv") else TRAJECTORY_DIR / name, geom)
    if n_steps:
        traj = short(traj, n_steps)
    ref, gains = synthesize(traj, "riccati", geom, limits, frames=frames)
    law = TrackingLaw(ref, gains, limits, governor=governor)
    res = simulate(law, traj.start_state(geom) if x0 is None else np.asarray(x0, float))
    return res, metrics(res, traj.Q, traj.R, traj.tau_s), law


# (trajectory, start state or None for the file's, bound on max error over t >= tf/4 [m]);
# the tight bounds hold for the weights with R's exponents read negative
CASES = [
    ("line_r_negative", None, 1e-4),
    ("circle", None, 1e-6),
    ("circle_r_negative", [0.0, -0.1, 0.3, 0.0, 0.0], 1e-3),
    ("curvilinear", None, 1e-3),
    ("line_y.csv", [0.0, 0.0, 0.0, 0.0, 0.0], 1e-3),
    ("line_neg_x.csv", [0.0, 0.05, 2.8, 0.0, 0.0], 1e-3),
    ("figure8.csv", [0.0, -0.05, 0.5, 0.0, 0.0], 1e-3),
]


@pytest.mark.slow
@pytest.mark.parametrize("name,x0,bound", CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)])
def test_tracks_in_simulation(name, x0, bound, robot):
    _, limits = robot
    res, m, law = run(name, robot, x0)
    assert m["max_position_error_m"] < bound
    assert m["final_position_error_m"] < bound
    assert np.all(np.isfinite(res.states))
    assert m["max_abs_v1_mps"] <= limits.v1_max_mps + 1e-12
    assert m["max_abs_steer_rate_radps"] <= limits.steer_rate_max_radps + 1e-12
    assert np.abs(res.states[:, 3:]).max() <= limits.steer_angle_max_rad + 1e-9
    assert res.ref_time_s[-1] >= law.reference.tf_s - 0.02   # reached the end of the path


def test_crosses_the_singular_set(robot):
    """The circle passes travel direction +-y at tf/4 and 3tf/4: rotating law is fine there."""
    res, m, law = run("circle_r_negative", robot, [0.0, -0.05, 0.2, 0.0, 0.0])
    k = np.searchsorted(res.ref_time_s, [14.0, 42.0])
    assert np.all(res.position_error_m[k] < 1e-4)
    assert len(set(law.gains.phi_rad)) >= 4


def test_plain_law_tracks_the_line_like_the_paper(robot):
    res, m, _ = run("line_r_negative", robot, frames="fixed")
    res2, m2, _ = run("line_r_negative", robot)
    assert m["max_position_error_m"] < 1e-4
    np.testing.assert_allclose(res.states, res2.states, atol=1e-12)   # same frame there


def test_plain_law_refuses_singular_paths_and_states(robot):
    with pytest.raises(SingularityError, match="singular set"):
        run("circle", robot, frames="fixed")
    with pytest.raises(SingularityError, match="parallel to the world y-axis"):
        run("line", robot, x0=[0, 0, np.pi / 2, 0, 0], frames="fixed", n_steps=200)


def test_governor_prevents_wind_up(robot):
    x0 = [0.0, 0.0, 1.5708 - 1.3, 0.0, 0.0]
    _, m_gov, _ = run("line_y.csv", robot, x0, n_steps=1500)
    _, m_raw, _ = run("line_y.csv", robot, x0, governor=False, n_steps=1500)
    assert m_gov["max_position_error_m"] < 1e-2
    assert m_gov["max_reference_lag_s"] > 0
    assert m_raw["max_position_error_m"] > 100 * m_gov["max_position_error_m"]


def test_law_api(robot):
    geom, limits = robot
    traj = short(load_trajectory("line", geom), 300)
    ref, gains = synthesize(traj, "riccati", geom, limits)
    law = TrackingLaw(ref, gains, limits)
    v1, w1, w2 = law.command(0.0, ref.start_state())
    assert abs(v1) <= limits.v1_max_mps and max(abs(w1), abs(w2)) <= limits.steer_rate_max_radps
    goals = law.wheel_goals(0.016, ref.start_state())
    assert goals.shape == (8,)
    np.testing.assert_allclose(goals[:4], goals[0])
    np.testing.assert_allclose(goals[[4, 5]], goals[[7, 6]])
    with pytest.raises(ControllerError, match="time went backwards"):
        law.command(0.0, ref.start_state())
    with pytest.raises(ControllerError, match="5 finite numbers"):
        law.command(0.1, [0, 0, np.nan, 0, 0])
    with pytest.raises(ControllerError, match="5 finite numbers"):
        law.command(0.1, [0, 0, 0])
    assert law.command(10.0, ref.start_state()) == (0.0, 0.0, 0.0)   # after tf: stop
    other = build_reference(short(load_trajectory("line", geom), 200), geom, limits)
    with pytest.raises(ControllerError, match="does not fit"):
        TrackingLaw(other, gains, limits)


@pytest.mark.slow
@pytest.mark.parametrize("name,x0", [("line", None), ("circle", [0.0, -0.1, 0.3, 0.0, 0.0]),
                                     ("figure8.csv", [0.0, -0.05, 0.5, 0.0, 0.0])])
def test_law_equals_the_vectorised_chained_law(name, x0, robot, numpy_ref):
    """command() (float math; reference from the grid table or the scalar path) against the
    law written with the package's numpy functions, over whole closed-loop runs: on the grid
    (line) and off it (start errors saturate v1, the governor slows the reference clock)."""
    geom, limits = robot
    res, _, law = run(name, robot, x0)
    ref, s = law.reference, res.ref_time_s
    i = np.array([ref.index(v) for v in s])
    phi = law.gains.phi_rad[i]
    rate = np.ones_like(s)                         # the governor's clock rate at each step
    with np.errstate(divide="ignore"):
        rate[1:] = np.minimum(1.0, limits.v1_max_mps / np.abs(res.raw_inputs[:-1, 0]))
    np.testing.assert_array_equal(s[1:], s[:-1] + np.diff(res.t_s) * rate[1:])
    on_grid = s == ref.times_s[i]
    assert on_grid.all() if x0 is None else on_grid.mean() < 0.01
    sd, _, xd, ud = numpy_ref(ref, s, phi)
    np.testing.assert_allclose(res.ref_states, sd, rtol=1e-13, atol=1e-15)
    e = chained_error(to_chained(res.states, geom, phi), xd)
    u = rate[:, None] * ud + np.einsum("nij,nj->ni", law.gains.K[i], e)
    raw = inputs_from_chained(res.states, u, geom, phi)
    sig = 0.5 * (res.states[:, 3] + res.states[:, 4]) + res.states[:, 2] - phi
    plain = np.abs(np.cos(sig)) >= STATE_MARGIN    # outside the floored band: the plain form
    assert plain.mean() > 0.95
    np.testing.assert_allclose(res.errors[plain], e[plain], rtol=1e-10, atol=1e-13)
    # u - ud cancels terms of the size of u: its absolute error scales with |u|
    atol = 1e-13 * max(1.0, float(np.abs(u).max()))
    np.testing.assert_allclose(res.u_tilde[plain], (u - ud)[plain], rtol=1e-10, atol=atol)
    np.testing.assert_allclose(res.raw_inputs[plain], raw[plain], rtol=1e-10, atol=atol)


def test_step_is_a_typed_output_whose_goals_integrate_the_rates(robot):
    """LawOutput: the saturated inputs, the steering goals δ + ωτ within the angle limit and
    the diagnostics; command() and wheel_goals() are views of the same step."""
    import dataclasses

    from swerve.controller.tracking import LawOutput

    geom, limits = robot
    traj = short(load_trajectory("circle", geom), 300)
    ref, gains = synthesize(traj, "riccati", geom, limits)
    law, twin, again = (TrackingLaw(ref, gains, limits) for _ in range(3))
    state = np.array(ref.start_state()) + [0.01, -0.02, 0.05, 0.1, -0.1]
    for k in range(5):
        t = k * ref.tau_s
        out = law.step(t, state)
        assert isinstance(out, LawOutput) and not out.finished
        assert out.inputs == twin.command(t, state)
        np.testing.assert_array_equal(out.wheel_goals, again.wheel_goals(t, state))
        tau, dmax = ref.tau_s, limits.steer_angle_max_rad
        assert out.delta1_rad == min(max(state[3] + out.omega1_radps * tau, -dmax), dmax)
        assert out.delta2_rad == min(max(state[4] + out.omega2_radps * tau, -dmax), dmax)
        assert out.error.shape == (5,) and out.u.shape == out.ud.shape == out.raw.shape == (3,)
        assert out.desired_state.shape == (5,) and out.index == ref.index(out.reference_time_s)
        state = np.array([*state[:3], out.delta1_rad, out.delta2_rad])
    with pytest.raises(dataclasses.FrozenInstanceError):
        out.v1_mps = 0.0
    plain = TrackingLaw(ref, gains, limits, governor=False)   # reference clock = t
    end = plain.step(traj.tf_s, state)
    assert end.finished and end.inputs == (0.0, 0.0, 0.0) and np.isnan(end.error).all()
    assert (end.delta1_rad, end.delta2_rad) == (state[3], state[4])
