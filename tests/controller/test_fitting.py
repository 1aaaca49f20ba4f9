"""Fitted trajectory files keep the drawn geometry; start state and reverse driving in files."""
import math

import numpy as np
import pytest

from swerve.controller.errors import ControllerError
from swerve.controller.path_csv import read_csv_samples
from swerve.controller.path_fit import FittedPath
from swerve.controller.paths import draw_primitives
from swerve.controller.reference import build_reference
from swerve.controller.trajectory import TRAJECTORY_DIR, load_trajectory

S_CURVE = [("line", 0.3), ("arc", 0.3, math.pi / 2), ("arc", 0.3, -math.pi / 2), ("line", 0.3)]
SQUARE = [s for _ in range(4) for s in (("line", 0.6), ("arc", 0.2, math.pi / 2))]


def fitted(segments, start=(0.0, 0.0, 0.0), speed=0.05):
    s, x, y, kappa = draw_primitives(segments, start, 0.01)
    return FittedPath(s / speed, np.round(x, 6), np.round(y, 6)), s, kappa


def test_shipped_drawn_files_are_the_primitives():
    s, x, y, _ = draw_primitives(S_CURVE)
    smp = read_csv_samples(TRAJECTORY_DIR / "s_curve.csv")
    np.testing.assert_allclose(smp.x_m, x, atol=1e-6)
    np.testing.assert_allclose(smp.y_m, y, atol=1e-6)


@pytest.mark.parametrize("segments", [S_CURVE, SQUARE], ids=["s-curve", "square"])
def test_straight_parts_have_zero_curvature(segments):
    fit, s, kappa = fitted(segments)
    c = fit.curve
    # every straight stretch, away from the blends (blend_m / 2 either side of a junction)
    edges = np.cumsum([seg[1] if seg[0] == "line" else abs(seg[1] * seg[2])
                       for seg in segments])
    starts = np.concatenate([[0.0], edges[:-1]])
    for (kind, *_), a, b in zip(segments, starts, edges):
        if kind != "line":
            continue
        lo = a + (0.03 if a > 0 else 0.0)
        hi = b - (0.03 if b < edges[-1] else 0.0)
        ss = np.linspace(lo, hi, 500)
        assert np.abs(c.curvature(ss)).max() <= 1e-12
    # and the reference built on it steers straight on the drawn straight start
    t = np.linspace(0.0, 0.25 / 0.05, 200)
    der = fit.derivatives(t)
    v, a = der[1], der[2]
    assert np.abs(v[0] * a[1] - v[1] * a[0]).max() <= 1e-12


@pytest.mark.parametrize("segments,radius", [(S_CURVE, 0.3), (SQUARE, 0.2)],
                         ids=["s-curve", "square"])
def test_corner_curvature_overshoot_at_most_5_percent(segments, radius):
    fit, s, _ = fitted(segments)
    ss = np.linspace(0.0, fit.curve.length_m, 20001)
    peak = np.abs(fit.curve.curvature(ss)).max()
    assert peak <= 1.05 / radius
    assert peak >= 0.95 / radius                    # and the arcs keep their drawn curvature
    assert fit.report.overshoot <= 0.05
    assert fit.report.position_m <= 5e-4             # samples within 0.5 mm of the curve
    # the former quintic smoothing spline of x(t), y(t) overshot by 16-36 % here


def test_fit_report_in_sim_json(capsys):
    import json

    from swerve.tools.cli import main

    assert main(["sim", "--trajectory", str(TRAJECTORY_DIR / "square.csv"), "--json",
                 "--quiet"]) == 0
    data = json.loads(capsys.readouterr().out)
    for k in ("fit_max_position_deviation_m", "fit_max_heading_deviation_rad",
              "fit_max_curvature_deviation_1pm", "fit_curvature_overshoot"):
        assert 0 <= data[k] < 0.05, k
    assert data["fit_runs"] == {"lines": 4, "arcs": 4, "free": 0}
    assert data["max_position_error_m"] < 1e-3


def test_start_line_and_reverse_driving(robot):
    geom, limits = robot
    traj = load_trajectory(TRAJECTORY_DIR / "s_curve_offset.csv", geom)
    np.testing.assert_allclose(traj.start_state(geom), [0, -0.2, 0, 0, 0])
    rev = load_trajectory(TRAJECTORY_DIR / "reverse_arc.csv", geom)
    assert rev.direction == -1
    ref = build_reference(rev, geom, limits)
    assert np.all(ref.inputs[:, 0] < 0)                   # v1 < 0
    v = ref.extra["derivatives"][1]
    travel = np.arctan2(v[1], v[0])
    np.testing.assert_allclose(np.cos(ref.states[:, 2] - travel), -1.0, atol=1e-9)


def test_reverse_path_is_tracked(robot):
    from swerve.controller.gain_schedule import synthesize
    from swerve.controller.simulate import metrics, simulate
    from swerve.controller.tracking import TrackingLaw

    geom, limits = robot
    traj = load_trajectory(TRAJECTORY_DIR / "reverse_arc.csv", geom)
    ref, gains = synthesize(traj, "riccati", geom, limits)
    res = simulate(TrackingLaw(ref, gains, limits), traj.start_state(geom) + [0, 0.02, 0.1, 0, 0])
    m = metrics(res, traj.Q, traj.R, traj.tau_s)
    assert m["max_position_error_m"] < 5e-3 and m["final_position_error_m"] < 1e-4
    assert np.mean(res.inputs[:, 0] < 0) > 0.95             # it drives backwards


def write(tmp_path, text, name="p.csv"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("text,match", [
    ("# start = 0, 0\nt,x,y\n" + "".join(f"{i},{0.01 * i},0\n" for i in range(8)),
     "3 or 5 numbers"),
    ("t,x,y,reverse\n" + "".join(f"{i},{0.01 * i},0,{int(i > 4)}\n" for i in range(8)),
     "direction changes"),
    ("t,x,y,reverse\n" + "".join(f"{i},{0.01 * i},0,2\n" for i in range(8)), "0 or 1"),
])
def test_bad_start_and_direction_lines(tmp_path, text, match):
    with pytest.raises(ControllerError, match=match):
        load_trajectory(write(tmp_path, text))
