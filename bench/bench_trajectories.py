"""Drawn trajectories: how well the reference fit keeps the drawn geometry, and how Riccati and
the paper's CG gains track them in simulation.

Run ``.venv/bin/python bench/bench_trajectories.py`` from the repository root.
``--write-csv`` regenerates the drawn CSV files in ``configs/trajectories/`` from their line and
arc primitives (:data:`DRAWN`). ``--fit-only`` measures only the fit, comparing the shipped
method (:class:`controller.path_fit.FittedPath`) with the former quintic smoothing spline of x(t),
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

from swerve.controller.path_fit import FittedPath  # noqa: E402
from swerve.controller.paths import draw_primitives  # noqa: E402
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


def fit_metrics(name: str, blend_m: float = 0.05) -> dict:
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


def run_case(traj, method: str, start=None) -> dict:
    """Synthesise (no gain check, so that failures show as numbers), simulate from ``start``
    (default the trajectory's), and return the metrics plus the requested (unclipped) peaks."""
    import time

    from swerve.controller.gain_schedule import synthesize
    from swerve.controller.kinematics import load_robot
    from swerve.controller.simulate import metrics, simulate
    from swerve.controller.tracking import TrackingLaw

    geom, limits = load_robot()
    start = traj.start_state(geom) if start is None else np.asarray(start, float)
    t0 = time.perf_counter()
    ref, gains = synthesize(traj, method, geom, limits, check=False, start=start)
    t_syn = time.perf_counter() - t0
    res = simulate(TrackingLaw(ref, gains, limits), start)
    m = metrics(res, traj.Q, traj.R, traj.tau_s)
    m.update(requested_max_abs_v1_mps=float(np.abs(res.raw_inputs[:, 0]).max()),
             requested_max_abs_steer_rate_radps=float(np.abs(res.raw_inputs[:, 1:]).max()),
             synthesis_s=t_syn, J_ratio=gains.cost / gains.meta["J_star"]
             if gains.meta.get("J_star") else 1.0)
    return m


def r_sign_table() -> str:
    """Both readings of R's lost exponent signs on the paper's three cases, Riccati gains."""
    import dataclasses

    from swerve.controller.trajectory import load_trajectory

    readings = [("line", None, (1e-4, 1e-2, 1e-2), (1e4, 1e2, 1e2)),
                ("circle", None, (1e-2, 1e-6, 1e-6), (1e2, 1e6, 1e6)),
                ("circle", (0.0, -0.1, 0.3, 0.0, 0.0), (1e-2, 1e-6, 1e-6), (1e2, 1e6, 1e6)),
                ("curvilinear", None, (1.0, 1.0, 1.0), (1.0, 1.0, 1.0))]
    rows = ["| case | R reading | R diag | requested max \\|v1\\| m/s | requested max \\|ω\\| "
            "rad/s | saturated steps | rms / max error m (t ≥ tf/4) | final error m |",
            "|---|---|---|---|---|---|---|---|"]
    for name, start, neg, pos in readings:
        base = load_trajectory(name)
        case = name if start is None else f"{name}, start {start[:3]}"
        for label, diag in (("negative exponents", neg), ("positive exponents", pos)):
            if name == "curvilinear" and label.startswith("positive"):
                continue
            traj = dataclasses.replace(base, R=np.diag(diag))
            m = run_case(traj, "riccati", start)
            rows.append(
                f"| {case} | {label if name != 'curvilinear' else 'exponents 0 (no sign)'} | "
                f"{', '.join(f'{v:g}' for v in diag)} | {m['requested_max_abs_v1_mps']:.3f} | "
                f"{m['requested_max_abs_steer_rate_radps']:.2f} | "
                f"{100 * m['saturated_fraction']:.1f} % | {m['rms_position_error_m']:.2g} / "
                f"{m['max_position_error_m']:.2g} | {m['final_position_error_m']:.2g} |")
            print(rows[-1], flush=True)
    return "\n".join(rows)


#: Rows of the tracking table: (label, trajectory name or CSV file, start or None).
TRACK_CASES = [
    ("line (paper)", "line", None),
    ("circle (paper, on the path)", "circle", None),
    ("circle, start 0.1 m off, θ = 0.3", "circle", (0.0, -0.1, 0.3, 0.0, 0.0)),
    ("curvilinear (paper, 0.1 m off)", "curvilinear", None),
    ("S-curve 0.3 m (drawn)", "s_curve.csv", None),
    ("S-curve 0.2 m (drawn)", "s_curve_tight.csv", None),
    ("square 1 m, 0.2 m corners (drawn)", "square.csv", None),
    ("lane change (drawn)", "lane_change.csv", None),
    ("reverse: line, arc, line (drawn)", "reverse_arc.csv", None),
    ("S-curve, start 0.2 m off (drawn)", "s_curve_offset.csv", None),
    ("square, start 5 cm off, θ = 0.3", "square.csv", (-0.3, -0.55, 0.3, 0.0, 0.0)),
]


def tracking_table() -> str:
    """Fit error, and Riccati versus default CG gains in simulation, for :data:`TRACK_CASES`."""
    import time

    from swerve.controller.gain_schedule import GainCheckError, check_gains, synthesize
    from swerve.controller.kinematics import load_robot
    from swerve.controller.trajectory import load_trajectory
    from swerve.controller.simulate import metrics, simulate
    from swerve.controller.tracking import TrackingLaw

    geom, limits = load_robot()
    rows = ["| case | fit: curvature dev. 1/m / arc overshoot / position dev. m | Riccati rms / "
            "max m | Riccati sat. | CG rms / max m | CG sat. | CG J/J*, s | CG check |",
            "|---|---|---|---|---|---|---|---|"]
    for label, name, start in TRACK_CASES:
        traj = load_trajectory(TRAJ_DIR / name if name.endswith(".csv") else name, geom)
        x0 = traj.start_state(geom) if start is None else np.asarray(start, float)
        rep = getattr(traj.path, "report", None)
        fit = ("analytic path" if rep is None else
               f"{rep.curvature_1pm:.1e} / {100 * rep.overshoot:.2f} % / {rep.position_m:.1e}")
        ref, g_r = synthesize(traj, "riccati", geom, limits, start=x0)
        t0 = time.perf_counter()
        ref_p, g_p = synthesize(traj, "paper", geom, limits, check=False, start=x0)
        t_cg = time.perf_counter() - t0
        out = []
        for g in (g_r, g_p):
            m = metrics(simulate(TrackingLaw(ref, g, limits), x0), traj.Q, traj.R, traj.tau_s)
            out.append(m)
        try:
            check_gains(ref_p, g_p, g_r.K, limits, x0)
            verdict = "pass"
        except GainCheckError as exc:
            verdict = f"fails: {exc.check} at {exc.t_s:.1f} s"
        (mr, mp) = out
        rows.append(f"| {label} | {fit} | {mr['rms_position_error_m']:.1e} / "
                    f"{mr['max_position_error_m']:.1e} | {100 * mr['saturated_fraction']:.1f} % "
                    f"| {mp['rms_position_error_m']:.1e} / {mp['max_position_error_m']:.1e} | "
                    f"{100 * mp['saturated_fraction']:.1f} % | "
                    f"{g_p.cost / g_p.meta['J_star']:.4f}, {t_cg:.1f} | {verdict} |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--write-csv", action="store_true")
    ap.add_argument("--fit-only", action="store_true")
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--r-signs", action="store_true", help="only the R-sign comparison")
    args = ap.parse_args()
    if args.write_csv:
        for name in DRAWN:
            print("wrote", write_csv(name))
    if args.r_signs:
        print(r_sign_table())
        return 0
    fits = {name: fit_metrics(name) for name in DRAWN}
    print(json.dumps(fits, indent=1))
    fit_rows = ["| path | method | max \\|κ\\| on straight parts 1/m | arc overshoot | max "
                "\\|κ − κ drawn\\| away from junctions 1/m |", "|---|---|---|---|---|"]
    for name, res in fits.items():
        for method, m in res.items():
            fit_rows.append(f"| {name} | {method} | {m['max_abs_curvature_on_straight_1pm']:.2g} "
                            f"| {100 * m['max_curvature_overshoot']:.2f} % | "
                            f"{m['max_curvature_error_away_from_junctions_1pm']:.2g} |")
    text = "\n".join(fit_rows)
    print(text)
    if not args.fit_only:
        text += "\n\n" + tracking_table() + "\n\n" + r_sign_table()
    if not args.no_write:
        write_section(SECTION, f"{SECTION}\n\n`python bench/bench_trajectories.py`\n\n{text}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
