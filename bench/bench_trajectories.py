"""Drawn trajectories: how well the reference fit keeps the drawn geometry, and how Riccati and
the paper's CG gains track them in simulation.

Run ``.venv/bin/python bench/bench_trajectories.py`` from the repository root.
``--write-csv`` regenerates the drawn CSV files in ``configs/trajectories/`` from their line and
arc primitives (:data:`DRAWN`). ``--fit-only`` measures only the fit, comparing the shipped
method (:class:`controller.paths.FittedPath`) with the former quintic smoothing spline of x(t),
y(t) (``scipy.interpolate.UnivariateSpline``, k = 5, s = n (1e-4 m)^2). ``--no-write`` leaves
BENCHMARKS.md alone.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from swerve.controller.paths import FittedPath, draw_primitives  # noqa: E402
from benchutil import write_section  # noqa: E402

SECTION = "## Drawn trajectories"
TRAJ_DIR = ROOT / "configs" / "trajectories"
SPEED_MPS = 0.05
SPACING_M = 0.01

#: name -> (segments, start pose of the first sample, reverse, '# start' line or None, note)
DRAWN = {
    "s_curve": ([("line", 0.3), ("arc", 0.3, math.pi / 2), ("arc", 0.3, -math.pi / 2),
                 ("line", 0.3)], (0, 0, 0), False, None, "S-curve, 0.3 m arcs"),
    "s_curve_tight": ([("line", 0.2), ("arc", 0.2, math.pi / 2), ("arc", 0.2, -math.pi / 2),
                       ("line", 0.2)], (0, 0, 0), False, None, "S-curve, 0.2 m arcs"),
    "square": ([s for _ in range(4) for s in (("line", 0.6), ("arc", 0.2, math.pi / 2))],
               (-0.3, -0.5, 0), False, None, "1 m square, 0.2 m corners"),
    "lane_change": ([("line", 0.4), ("arc", 0.5, 0.5), ("arc", 0.5, -0.5), ("line", 0.4)],
                    (0, 0, 0), False, None, "lane change, 0.5 m arcs, 0.24 m offset"),
    "reverse_arc": ([("line", 0.3), ("arc", 0.4, math.pi / 2), ("line", 0.3)],
                    (0, 0, math.pi), True, "0, 0, 0, 0, 0",
                    "driven in reverse: line, 0.4 m arc, line (travel -x then -y)"),
    "s_curve_offset": ([("line", 0.3), ("arc", 0.3, math.pi / 2), ("arc", 0.3, -math.pi / 2),
                        ("line", 0.3)], (0, 0, 0), False, "0, -0.2, 0, 0, 0",
                       "S-curve, robot starts 0.2 m to the right of it"),
}


def write_csv(name: str) -> Path:
    """Sample ``DRAWN[name]`` and write ``configs/trajectories/NAME.csv``."""
    segs, start, rev, start_line, note = DRAWN[name]
    s, x, y, _ = draw_primitives(segs, start, SPACING_M)
    t = s / SPEED_MPS
    head = [f"# {note}; drawn from {segs!r} at {SPEED_MPS} m/s, a sample every "
            f"{SPACING_M} m (bench/bench_trajectories.py --write-csv)"]
    if start_line:
        head.append(f"# start = {start_line}")
    head.append("t,x,y,reverse" if rev else "t,x,y")
    rows = [f"{a:.6f},{b:.6f},{c:.6f}" + (",1" if rev else "") for a, b, c in zip(t, x, y)]
    out = TRAJ_DIR / f"{name}.csv"
    out.write_text("\n".join(head + rows) + "\n")
    return out


def drawn_curvature(name: str, s_query):
    """Drawn curvature (1/m) at arc lengths ``s_query`` and the junctions' arc lengths."""
    segs = DRAWN[name][0]
    bounds, ks, s0 = [], [], 0.0
    for seg in segs:
        length = seg[1] if seg[0] == "line" else abs(seg[1] * seg[2])
        ks.append(0.0 if seg[0] == "line" else math.copysign(1 / seg[1], seg[2]))
        s0 += length
        bounds.append(s0)
    idx = np.minimum(np.searchsorted(bounds, s_query), len(ks) - 1)
    return np.array(ks)[idx], np.array(bounds[:-1])


def legacy_spline_curvature(t, x, y, tq):
    """Curvature of the former fit (quintic smoothing splines of x(t), y(t))."""
    from scipy.interpolate import UnivariateSpline

    s = len(t) * 1e-4 ** 2
    sx, sy = UnivariateSpline(t, x, k=5, s=s), UnivariateSpline(t, y, k=5, s=s)
    vx, vy, ax, ay = sx(tq, 1), sy(tq, 1), sx(tq, 2), sy(tq, 2)
    return (vx * ay - vy * ax) / (vx * vx + vy * vy) ** 1.5


def fit_metrics(name: str, blend_m: float = 0.03) -> dict:
    """Curvature on straight parts, overshoot at arcs, deviation from the drawn samples."""
    segs, start, rev, _, _ = DRAWN[name]
    s, x, y, _ = draw_primitives(segs, start, SPACING_M)
    x, y = np.round(x, 6), np.round(y, 6)
    t = s / SPEED_MPS
    fit = FittedPath(t, x, y, blend_m=blend_m, direction=-1 if rev else 1)
    tq = np.linspace(0, t[-1], 20001)
    sq = tq * SPEED_MPS
    k_drawn, junc = drawn_curvature(name, sq)
    away = np.all(np.abs(sq[:, None] - junc[None, :]) > blend_m / 2 + SPACING_M, axis=1)
    out = {}
    for label, kappa in (("fitted", fit.curve.curvature(fit._s_of_t(tq))),
                         ("legacy spline", legacy_spline_curvature(t, x, y, tq))):
        straight = away & (k_drawn == 0)
        over = 0.0
        for kd in set(k_drawn[k_drawn != 0]):
            sel = np.sign(kappa) == np.sign(kd)
            over = max(over, float(np.abs(kappa[sel]).max() / abs(kd) - 1))
        out[label] = dict(
            max_abs_curvature_on_straight_1pm=float(np.abs(kappa[straight]).max()),
            max_curvature_overshoot=over,
            max_curvature_error_away_from_junctions_1pm=float(
                np.abs(kappa - k_drawn)[away].max()))
    out["fitted"].update({k: v for k, v in fit.report.as_dict().items()})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--write-csv", action="store_true")
    ap.add_argument("--fit-only", action="store_true")
    ap.add_argument("--no-write", action="store_true")
    args = ap.parse_args()
    if args.write_csv:
        for name in DRAWN:
            print("wrote", write_csv(name))
    fits = {name: fit_metrics(name) for name in DRAWN}
    print(json.dumps(fits, indent=1))
    if args.fit_only:
        return 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
