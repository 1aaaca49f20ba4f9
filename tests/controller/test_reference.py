import dataclasses
import json

import numpy as np
import pytest

from swerve.controller.chained import chained_inputs, to_chained
from swerve.controller.errors import ControllerError, SingularityError
from swerve.controller.kinematics import Geometry, Limits, state_derivative
from swerve.controller.paths import LinePath
from swerve.controller.reference import build_reference, desired_states, frame_schedule, sample_at
from swerve.controller.trajectory import TRAJECTORY_DIR, load_trajectory


@pytest.mark.parametrize("name,tf,n,q0,r0", [("line", 40, 2500, 1e3, 1e4),
                                             ("line_r_negative", 40, 2500, 1e3, 1e-4),
                                             ("circle", 56, 3500, 1e4, 1e2),
                                             ("circle_r_negative", 56, 3500, 1e4, 1e-2),
                                             ("curvilinear", 140, 8750, 1e2, 1.0)])
def test_paper_cases(name, tf, n, q0, r0):
    tr = load_trajectory(name)
    assert (tr.tf_s, tr.n_steps, tr.tau_s) == (tf, n, 0.016)
    assert tr.Q[0, 0] == q0 and tr.R[0, 0] == r0


def test_start_states(robot):
    geom, _ = robot
    np.testing.assert_allclose(load_trajectory("line").start_state(geom), 0)
    a = np.arctan(2 * geom.a_m / 1.0)
    np.testing.assert_allclose(load_trajectory("circle").start_state(geom), [0, 0, 0, a, -a])
    np.testing.assert_allclose(load_trajectory("curvilinear").start_state(geom),
                               [0, 0, 0, 0.46, 0.46])
    ref = build_reference(load_trajectory("curvilinear", geom), *robot)
    np.testing.assert_allclose(ref.states[0, :2], [0, -0.1], atol=1e-15)   # offset c = 3/5
    np.testing.assert_allclose(ref.states[0, 2], np.arctan(0.5))            # 0.46 = atan(1/2)


def test_line_closed_forms(robot):
    ref = build_reference(load_trajectory("line"), *robot)
    np.testing.assert_allclose(ref.xd[:, 1], 0, atol=1e-15)
    np.testing.assert_allclose(ref.xd[:, 2], np.pi / 4)
    np.testing.assert_allclose(ref.xd[:, 3], 1.0)
    np.testing.assert_allclose(ref.ud, np.tile([0.05, 0, 0], (2501, 1)), atol=1e-15)


def test_circle_closed_forms(robot):
    ref = build_reference(load_trajectory("circle"), *robot)
    w = 2 * np.pi / 56
    t = ref.times_s
    keep = (ref.phi_rad == 0)
    assert keep.sum() > 500
    t = t[keep]
    xd, ud = ref.xd[keep], ref.ud[keep]
    np.testing.assert_allclose(xd[:, 1], 1 / np.cos(w * t), rtol=1e-9)
    np.testing.assert_allclose(xd[:, 2], w * t, atol=1e-12)
    np.testing.assert_allclose(xd[:, 3], np.tan(w * t), atol=1e-12)
    np.testing.assert_allclose(ud[:, 0], w * np.cos(w * t), atol=1e-12)
    np.testing.assert_allclose(ud[:, 1], w * np.sin(w * t) / np.cos(w * t) ** 2, atol=1e-9)
    np.testing.assert_allclose(ud[:, 2], w / np.cos(w * t) ** 2, atol=1e-9)


@pytest.mark.parametrize("name", ["circle", "curvilinear", "figure8.csv", "s_curve.csv",
                                  "reverse_arc.csv"])
def test_desired_states_and_inputs_are_consistent(name, robot):
    geom, limits = robot
    src = name if not name.endswith(".csv") else TRAJECTORY_DIR / name
    traj = load_trajectory(src, geom)
    ref = build_reference(traj, geom, limits)
    # the desired inputs drive the desired states through model (1)-(5): the states are the
    # integral of f (a fitted path's curvature is only C1, so differences of the states
    # would not resolve its knots)
    from scipy.integrate import cumulative_trapezoid

    h = 2e-4
    t = np.arange(0.0, min(traj.tf_s, 20.0), h)
    states, inputs, _ = desired_states(traj.path, t, geom, traj.direction)
    f = state_derivative(states, inputs, geom)
    np.testing.assert_allclose(states - states[0], cumulative_trapezoid(f, t, axis=0, initial=0),
                               atol=1e-5)
    # and the chained inputs (16)-(18) of the desired inputs are ud in each step's frame
    u = chained_inputs(ref.states, ref.inputs, geom, ref.phi_rad)
    np.testing.assert_allclose(u, ref.ud, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(to_chained(ref.states, geom, ref.phi_rad), ref.xd)


def test_heading_is_unwrapped(robot):
    ref = build_reference(load_trajectory("circle"), *robot)
    assert np.all(np.diff(ref.states[:, 2]) > 0)
    np.testing.assert_allclose(ref.states[-1, 2], 2 * np.pi, atol=1e-9)


def test_frame_schedule_keeps_the_chained_form_regular(robot):
    for name in ["circle", "curvilinear"]:
        ref = build_reference(load_trajectory(name), *robot)
        assert np.abs(np.cos(ref.states[:, 2] - ref.phi_rad)).min() >= np.cos(1.2) - 1e-9
        assert np.all(np.isfinite(ref.xd)) and np.abs(ref.xd[:, 3]).max() <= np.tan(1.2) + 1e-9
    np.testing.assert_allclose(frame_schedule(np.full(5, np.pi / 2)), np.pi / 2)
    np.testing.assert_allclose(frame_schedule(np.full(5, np.pi)), 0.0)   # -x: frame 0 works


@pytest.mark.parametrize("name", ["circle", "curvilinear", "line_y.csv"])
def test_fixed_frame_refuses_singular_paths(name, robot):
    src = name if not name.endswith(".csv") else TRAJECTORY_DIR / name
    with pytest.raises(SingularityError, match="singular set"):
        build_reference(load_trajectory(src), *robot, frames="fixed")


def test_fixed_frame_accepts_the_line(robot):
    ref = build_reference(load_trajectory("line"), *robot, frames="fixed")
    np.testing.assert_allclose(ref.phi_rad, 0)


def write(tmp_path, text, name="p.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


def csv_rows(t, x, y):
    return "t,x,y\n" + "".join(f"{a},{b},{c}\n" for a, b, c in zip(t, x, y))


@pytest.mark.parametrize("text,match", [
    ("t,x,y\n0,0,0\n1,0.1\n", "expected columns t,x,y"),
    ("t,x,y\n0,0,0\n1,a,0\n", "not a number"),
    ("0,0,0\n1,nan,0\n", "NaN"),
    ("0,0,0\n1,0.1,0\n2,0.2,0\n", "at least 6"),
    ("0,0,0\n1,0.1,0\n1,0.2,0\n2,.3,0\n3,.4,0\n4,.5,0\n", "strictly increase"),
])
def test_malformed_csv(tmp_path, text, match):
    with pytest.raises(ControllerError, match=match):
        load_trajectory(write(tmp_path, text))


def test_cusp_and_standstill(tmp_path, robot):
    t = np.arange(0, 20.01, 0.1)
    x = 0.02 * (t - 10) ** 2 / 10       # goes left, stops, comes back: a cusp at t = 10
    with pytest.raises(ControllerError, match="stops at t = 10"):
        build_reference(load_trajectory(write(tmp_path, csv_rows(t, x, 0 * t))), *robot)
    x = np.minimum(0.05 * t, 0.5)        # standstill after t = 10
    with pytest.raises(ControllerError, match="stops"):
        build_reference(load_trajectory(write(tmp_path, csv_rows(t, x, 0 * t), "s.csv")),
                        *robot)


def test_unreachable_speed(tmp_path, robot):
    t = np.arange(0, 10.01, 0.1)
    with pytest.raises(ControllerError, match="wheel speed .* above the limit"):
        build_reference(load_trajectory(write(tmp_path, csv_rows(t, 0.3 * t, 0 * t))), *robot)


def test_unknown_names_and_files(tmp_path):
    with pytest.raises(ControllerError, match="unknown trajectory 'spiral'"):
        load_trajectory("spiral")
    with pytest.raises(ControllerError, match="does not exist"):
        load_trajectory(tmp_path / "none.csv")
    bad = write(tmp_path, "name: x\npath: {type: zigzag}\ntf_s: 10\n", "bad.yaml")
    with pytest.raises(ControllerError, match="path type"):
        load_trajectory(bad)


def test_reference_at_matches_grid(robot):
    ref = build_reference(load_trajectory("curvilinear"), *robot)
    for i in [0, 17, 4000, 8749]:
        s, u, xd, ud = ref.at(ref.times_s[i])
        np.testing.assert_allclose(s, ref.states[i], atol=1e-12)
        np.testing.assert_allclose(xd, ref.xd[i], atol=1e-9)
        np.testing.assert_allclose(ud, ref.ud[i], atol=1e-9)


def test_custom_limits_and_geometry_are_used():
    tr = load_trajectory("circle")
    with pytest.raises(ControllerError, match="above the limit v1_max = 0.1 m/s"):
        build_reference(tr, Geometry(), Limits(v1_max_mps=0.1))


def test_curvilinear_closed_forms(robot):
    """tan(xd3) = (cos wt - 2 sin 2wt) / (2 cos 2wt - sin wt), the paper's (68)."""
    ref = build_reference(load_trajectory("curvilinear"), *robot)
    w = 2 * np.pi / 140
    t = ref.times_s
    num, den = np.cos(w * t) - 2 * np.sin(2 * w * t), 2 * np.cos(2 * w * t) - np.sin(w * t)
    ok = np.abs(den) > 0.1
    np.testing.assert_allclose(np.tan(ref.states[ok, 2]), num[ok] / den[ok], rtol=1e-9,
                               atol=1e-12)
    frame0 = ref.phi_rad == 0
    np.testing.assert_allclose(ref.xd[frame0, 3], (num / den)[frame0], rtol=1e-9)


@pytest.mark.parametrize("name", ["line", "circle", "curvilinear", "figure8.csv"])
def test_sample_equals_the_vectorised_reference(name, robot, numpy_ref):
    """Reference.sample (float math off the grid, a table on it) against desired_states +
    chained_desired at the same times: off-grid times, grid times, other frames, t > tf."""
    geom, limits = robot
    src = name if not name.endswith(".csv") else TRAJECTORY_DIR / name
    ref = build_reference(load_trajectory(src, geom), geom, limits)
    rng = np.random.default_rng(1)
    t = np.concatenate([rng.uniform(-0.5, ref.tf_s + 0.5, 300), ref.times_s[::7]])
    phi = ref.phi_rad[[ref.index(s) for s in np.clip(t, 0, ref.tf_s)]]
    for frames in (phi, phi - np.pi / 2 * (rng.random(t.size) < 0.3)):
        want = numpy_ref(ref, t, frames)
        got = [ref.sample(s, p) for s, p in zip(t, frames)]
        for k, w in enumerate(want):
            np.testing.assert_allclose([g[k] for g in got], w, rtol=1e-13, atol=1e-15)


def test_grid_table_is_the_scalar_evaluation_at_grid_times(robot):
    """On the grid, sample() returns a precomputed row: the scalar path's own values there
    (circle: the heading passes +-pi, so the unwrapped branch matters)."""
    ref = build_reference(load_trajectory("circle"), *robot)
    der = ref.extra["derivatives"]
    for i in range(0, ref.n_steps, 3):
        row = ref.sample(ref.times_s[i])
        assert row is ref.sample(ref.times_s[i], ref.phi_rad[i])      # a table lookup
        want = sample_at(der[:, :, i].reshape(8).tolist(), ref.states[i, 2], ref.phi_rad[i],
                         ref.geom)
        assert row == want                                              # bit for bit
    assert ref.sample(ref.times_s[5] + 1e-12) is not ref.sample(ref.times_s[5])  # off the grid


def test_sample_refuses_an_undefined_reference(robot):
    """Between grid samples a path may stop (no direction of travel): an error, not NaNs."""
    geom, limits = robot
    ref = build_reference(load_trajectory("line"), geom, limits)
    stopped = dataclasses.replace(ref.trajectory, path=LinePath((0.0, 0.0), (0.0, 0.0), 40.0))
    ref = dataclasses.replace(ref, trajectory=stopped)
    with pytest.raises(ControllerError, match="reference is undefined at t = 1.001 s"):
        ref.sample(1.001)


_SIMD_PROBE = """

x = np.random.default_rng(1).uniform(-10.0, 10.0, (2, 10000))
out = {"numpy arctan2": h(np.arctan2(x[0], x[1]))}
geom, limits = Geometry(), Limits()
for name in ("circle", TRAJECTORY_DIR / "s_curve.csv", TRAJECTORY_DIR / "figure8.csv"):
    traj = load_trajectory(name, geom)
    ref = build_reference(traj, geom, limits)
    K, _ = finite_horizon_lqr(*error_system(ref), traj.Q, traj.R, traj.tau_s)
    out[traj.name] = h(ref.xd, ref.ud, K)
print(json.dumps(out))
"""


@pytest.mark.slow
def test_same_bits_without_numpys_simd_loops(other_cpu, probe_prelude):
    """xd, ud and K of the circle and two CSV paths (lines and arcs; free-form) are the same
    whichever SIMD loops NumPy picks (here: those of a CPU without AVX-512 and AVX2)."""
    envs = {"native": {}, "no AVX2": {"NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL X86_V3"}}
    out = {k: json.loads(other_cpu(env, "-c", probe_prelude + _SIMD_PROBE)) for k, env in envs.items()}
    # the probe can tell the loops apart: NumPy's own arctan2 differs
    assert out["native"].pop("numpy arctan2") != out["no AVX2"].pop("numpy arctan2")
    assert out["native"] == out["no AVX2"]
