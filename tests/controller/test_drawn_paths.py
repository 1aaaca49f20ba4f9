"""Paths as users draw them: each is fitted and tracked in ``swerve sim``, or refused with one line.

Hypothesis draws line-and-arc sequences (radii from below the robot's tightest turn up, with and
without blends), smooth free-form curves (sums of sines, self-crossing), sampling intervals
and ±1 mm drawing noise, and writes them as CSV files. The fit's work is bounded by counting its
curve evaluations, never by a clock.
"""
from __future__ import annotations

import contextlib
import io
import json
import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, event, example, given, settings
from hypothesis import strategies as st

from swerve.core.errors import SwerveError
from swerve.controller.path_csv import read_csv_samples
from swerve.controller.path_fit import LM_ITERATIONS, LM_TRIALS, WINDOW_PARAMS, fit_samples
from swerve.controller.paths import draw_primitives, draw_sines
from swerve.tools.cli import main

#: Tracking bound in ``swerve sim`` (robot started on the path): largest distance from the
#: reference after tf/4, m.
TRACK_MAX_ERROR_M = 5e-3
#: Fit bound: largest distance of a noise-free sample from the fitted curve, m (plus the shift
#: of the sharpest blend, :func:`blend_shift_m`), and the largest arc overshoot of a noise-free
#: line-and-arc path.
FIT_MAX_DEVIATION_M = 3e-4
FIT_MAX_OVERSHOOT = 0.005
#: Drawing noise: each coordinate of a noisy sample is off by up to this, m; such a sample may
#: be up to five times this from the fitted curve (found: samples closer than their noise).
NOISE_M = 1e-3

#: The fit's bound holds where the samples resolve the turns: the direction of travel changes by
#: at most this between consecutive samples, rad (else 5 mm: a tip drawn with a few samples).
RESOLVED_TURN_RAD = 0.25

SETTINGS = settings(max_examples=12, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def write_csv(path, t, x, y):
    path.write_text("t,x,y\n" + "".join(f"{a:.6f},{b:.6f},{c:.6f}\n" for a, b, c in zip(t, x, y)))
    return path


def run_sim(csv):
    """``swerve sim --json`` on ``csv``: ``(exit status, JSON or None, stderr lines)``."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(["sim", "--trajectory", str(csv), "--json", "--quiet"])
    lines = err.getvalue().strip().splitlines()
    return status, (json.loads(out.getvalue()) if status in (0, 1) else None), lines


def evaluation_bound(fit) -> int:
    """Most curve evaluations the fit may make: per window (each moves the start by at least
    one parameter, at most half a window), LM iterations with their damping trials, three
    projections and the next start."""
    params = len(fit._layout.init)
    windows = 1 + max(params - WINDOW_PARAMS, 0) // max(WINDOW_PARAMS // 2, 1) + 1
    return windows * (LM_ITERATIONS * (1 + LM_TRIALS) + 4)


def blend_shift_m(segs, blend_m: float = 0.05) -> float:
    """How far the curvature blend moves a drawn path at its sharpest junction, m: a step of
    ``dk`` spread over ``blend_m`` shifts the curve by about ``dk blend_m^2 / 48``."""
    ks = [0.0 if seg[0] == "line" else math.copysign(1 / seg[1], seg[2]) for seg in segs]
    dk = max((abs(a - b) for a, b in zip(ks, ks[1:])), default=0.0)
    return dk * blend_m * blend_m / 48


def max_turn_rad(x, y) -> float:
    """Largest change of direction between consecutive chords of the samples, rad."""
    d = np.diff(np.column_stack([x, y]), axis=0)
    a = np.arctan2(d[:, 1], d[:, 0])
    return float(np.abs((np.diff(a) + np.pi) % (2 * np.pi) - np.pi).max(initial=0.0))


def reason(message: str) -> str:
    """The kind of a refusal: its message without file names and numbers."""
    text = message.split(".csv", 1)[-1]
    return re.sub(r"[-+]?[0-9][0-9.e+-]*", "#", text)[:70]


def check_outcome(tmp_path, t, x, y, noisy: bool, exact_geometry: bool, shift_m: float = 0.0):
    """Read and fit the samples as ``swerve sim`` does; refused -> one line; else the fit's
    bounds (``shift_m``: the blends' allowance, m), then ``swerve sim``."""
    csv = write_csv(tmp_path / "drawn.csv", t, x, y)
    try:
        fit = fit_samples(read_csv_samples(csv), source=str(csv))
    except SwerveError as exc:
        assert len(str(exc).splitlines()) == 1 and str(csv) in str(exc)
        status, _, err = run_sim(csv)
        assert status == 2 and len(err) == 1 and "Traceback" not in err[0]
        return "refused: " + reason(err[0])
    assert fit.report.evaluations <= evaluation_bound(fit)
    dev = fit.report.position_m
    if noisy or max_turn_rad(x, y) > RESOLVED_TURN_RAD:
        assert dev <= FIT_MAX_DEVIATION_M + shift_m + 5 * NOISE_M
    else:
        assert dev <= FIT_MAX_DEVIATION_M + shift_m
    if exact_geometry:
        assert fit.report.overshoot <= FIT_MAX_OVERSHOOT
    status, data, err = run_sim(csv)
    if status == 2:                      # refused by the robot's limits (speed, steering rate)
        assert len(err) == 1 and "Traceback" not in err[0]
        assert any(w in err[0] for w in ("steering rate", "wheel speed", "steering", "stops"))
        return "refused: " + reason(err[0])
    assert status == 0, err
    assert data["converged"] and data["max_position_error_m"] <= TRACK_MAX_ERROR_M
    return "tracked"


segment = st.one_of(
    st.tuples(st.just("line"), st.floats(0.02, 0.8)),
    st.tuples(st.just("arc"), st.floats(0.05, 2.0),
              st.floats(0.2, 3.0).flatmap(lambda a: st.sampled_from([a, -a]))))


@pytest.mark.slow
@SETTINGS
@given(segs=st.lists(segment, min_size=1, max_size=6), speed=st.floats(0.02, 0.1),
       dt=st.floats(0.01, 0.25), noise=st.booleans(), seed=st.integers(0, 2 ** 16),
       heading=st.floats(-math.pi, math.pi))
@example(segs=[("arc", 0.3, math.pi / 2), ("arc", 0.3, -math.pi / 2)], speed=0.05, dt=0.1,
         noise=False, seed=0, heading=0.0)                    # the direct S-curve, 5 mm samples
@example(segs=[("line", 0.2), ("arc", 0.25, math.pi), ("line", 0.4)], speed=0.05, dt=0.016,
         noise=False, seed=0, heading=0.0)                    # a half turn: its sign
@example(segs=[("line", 0.3), ("arc", 0.05, math.pi / 2), ("line", 0.3)], speed=0.1, dt=0.016,
         noise=False, seed=0, heading=1.0)                    # tighter than the steering allows
@example(segs=[("line", 0.8)], speed=0.02, dt=0.04389094774966303, noise=True, seed=141,
         heading=-1.7780144598384735)                         # noise larger than the spacing
@example(segs=[("arc", 1.375, 0.25)], speed=0.0625, dt=0.25, noise=True, seed=0,
         heading=0.0)                                         # sparse noisy samples
def test_line_and_arc_paths(tmp_path_factory, segs, speed, dt, noise, seed, heading):
    spacing = speed * dt
    s, x, y, _ = draw_primitives(segs, (0.0, 0.0, heading), spacing)
    if len(s) < 6:
        return
    if noise:
        rng = np.random.default_rng(seed)
        x = x + rng.uniform(-NOISE_M, NOISE_M, len(x))
        y = y + rng.uniform(-NOISE_M, NOISE_M, len(y))
    outcome = check_outcome(tmp_path_factory.mktemp("la"), s / speed, x, y, noise,
                            exact_geometry=not noise, shift_m=blend_shift_m(segs))
    event(outcome)
    comfortable = (not noise and speed <= 0.06 and spacing >= 2e-3
                   and all(seg[0] == "line" or seg[1] >= 0.3 for seg in segs))
    if comfortable:
        assert outcome == "tracked", outcome


@pytest.mark.slow
@SETTINGS
@given(ax=st.floats(0.1, 0.6), ay=st.floats(0.1, 0.6), ratio=st.sampled_from([1, 2, 3, 1.5]),
       phase=st.floats(0.0, math.pi), period=st.floats(40.0, 120.0), extra=st.floats(0.0, 0.1),
       laps=st.floats(0.3, 1.5), dt=st.floats(0.01, 0.25), noise=st.booleans(),
       seed=st.integers(0, 2 ** 16))
@example(ax=0.5, ay=0.3, ratio=2, phase=0.6, period=150.0, extra=0.0, laps=1.0, dt=0.016,
         noise=False, seed=0)                                 # a 150 s figure-eight, 9,375 samples
@example(ax=0.5, ay=0.5, ratio=1, phase=3.0, period=40.0, extra=0.0, laps=1.0, dt=0.25,
         noise=False, seed=0)                                 # tips drawn with few samples
def test_free_form_paths(tmp_path_factory, ax, ay, ratio, phase, period, extra, laps, dt, noise,
                         seed):
    w = 2 * math.pi / period
    t = np.arange(0.0, laps * period, dt)
    if len(t) < 6:
        return
    x, y = draw_sines(t, [(ax, w, 0.0), (extra, 3 * w, 1.0)], [(ay, ratio * w, phase)])
    if noise:
        rng = np.random.default_rng(seed)
        x = x + rng.uniform(-NOISE_M, NOISE_M, len(x))
        y = y + rng.uniform(-NOISE_M, NOISE_M, len(y))
    event(check_outcome(tmp_path_factory.mktemp("ff"), t, x, y, noise, exact_geometry=False))


@pytest.mark.parametrize("rows,match", [
    ([(i * 0.016, 1000 * i * 0.016, 0) for i in range(200)], "wheel speed .* above the limit"),
    ([(i * 0.1, 1e300, 0) for i in range(10)], "beyond the workspace"),
    ([(i * 0.1, 0.01 * i, 0) for i in range(5)] + [(0.3, 0.06, 0)], "strictly increase"),
    ([(0.0, 0, 0)] + [(1e4 + i, 0.01 * i, 0) for i in range(6)], "more than 3200 s"),
    ([(i * 0.016, 0.05 * math.sin(2.0 * i * 0.016), 0.05 * (1 - math.cos(2.0 * i * 0.016)))
      for i in range(100)], r"turns at .*centripetal acceleration"),   # r = 5 cm at 0.1 m/s
])
def test_bounds_are_checked_before_any_work(tmp_path, rows, match):
    csv = tmp_path / "bad.csv"
    csv.write_text("t,x,y\n" + "".join(f"{a!r},{b!r},{c!r}\n" for a, b, c in rows))
    status, _, err = run_sim(csv)
    assert status == 2 and len(err) == 1, err
    assert "bad.csv:" in err[0]
    assert re.search(match, err[0]), err[0]


def test_file_and_row_caps(tmp_path, monkeypatch):
    import swerve.controller.path_csv as path_csv

    big = tmp_path / "big.csv"
    with open(big, "wb") as fh:
        fh.truncate(2 * 1024 ** 3)             # sparse: the size is refused before reading
    status, _, err = run_sim(big)
    assert status == 2 and "more than the 25600000" in err[0]
    monkeypatch.setattr(path_csv, "MAX_ROWS", 50)
    many = write_csv(tmp_path / "many.csv", *(np.arange(60) * 0.1, np.arange(60) * 0.005,
                                              np.zeros(60)))
    status, _, err = run_sim(many)
    assert status == 2 and "many.csv:52: more than 50 sample rows" in err[0]
