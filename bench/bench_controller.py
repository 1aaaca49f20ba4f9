"""Controller benchmarks (issue 5): Riccati synthesis, the paper's CG, gradient cost, tracking.

Run ``.venv/bin/python bench/bench_controller.py`` from the repository root. Results are
printed and written to the "## Controller (issue 5)" section of BENCHMARKS.md
(``--no-write`` to leave it alone; ``--cg-seconds`` caps each cold-start CG run).
``--per-cycle`` measures only the online loop's per-cycle CPU (tracking law, odometry, cycle
record, run-log write) and writes the "## Controller per-cycle cost" section instead.
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from controller.design import synthesize  # noqa: E402
from controller.kinematics import load_robot, rk4_step  # noqa: E402
from controller.ltv import cost, error_system, initial_error  # noqa: E402
from controller.odometry import Odometry  # noqa: E402
from controller.online import TrackingLoop  # noqa: E402
from controller.reference import TRAJECTORY_DIR, build_reference, load_trajectory  # noqa: E402
from controller.riccati import finite_horizon_lqr  # noqa: E402
from controller.simulate import metrics, simulate  # noqa: E402
from controller.synthesis import (conjugate_gradient,  # noqa: E402
                                  conjugate_gradient_continuation, cost_and_gradient,
                                  frozen_time_lqr_gains, initial_error_set)
from controller.tracking import TrackingLaw  # noqa: E402
from driver.wheelset import WheelState  # noqa: E402
from tools.logs import CycleRecord, RunLogWriter  # noqa: E402
from benchutil import cpu_model, write_section  # noqa: E402

SECTION = "## Controller (issue 5)"
SECTION_CYCLE = "## Controller per-cycle cost"
GEOM, LIMITS = load_robot()

#: Tracking cases: (label, trajectory, start state or None = the trajectory's own).
TRACK_CASES = [
    ("line (paper start)", "line", None),
    ("circle (paper start, on the path)", "circle", None),
    ("circle, start 0.1 m off, θ = 0.3 rad", "circle", [0.0, -0.1, 0.3, 0.0, 0.0]),
    ("curvilinear (paper start, 0.1 m off)", "curvilinear", None),
    ("line along +y (CSV), on the path", "line_y.csv", None),
    ("line along +y (CSV), start (0,0,0): facing +x", "line_y.csv", [0.0] * 5),
    ("line along −x (CSV), start 5 cm off, θ = 2.8", "line_neg_x.csv",
     [0.0, 0.05, 2.8, 0.0, 0.0]),
    ("figure-eight (CSV), on the path", "figure8.csv", None),
    ("figure-eight (CSV), start 5 cm off, θ = 0.5", "figure8.csv", [0.0, -0.05, 0.5, 0.0, 0.0]),
]


def problem(name):
    traj = load_trajectory(name, GEOM)
    ref = build_reference(traj, GEOM, LIMITS)
    Ad, Bd = error_system(ref)
    return traj, ref, Ad, Bd


def timed(fn, repeat=3):
    out, times = None, []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return out, statistics.median(times)


def bench_riccati():
    rows = []
    for name in ("line", "circle", "curvilinear"):
        traj, ref, Ad, Bd = problem(name)
        (_, t_sys) = timed(lambda: error_system(ref))
        (_, t_ric) = timed(lambda: finite_horizon_lqr(Ad, Bd, traj.Q, traj.R, traj.tau_s))
        rows.append((name, traj.n_steps, t_sys, t_ric))
    return rows


def bench_gradient():
    rows = []
    for name in ("line", "curvilinear"):
        traj, ref, Ad, Bd = problem(name)
        x0 = initial_error(ref, traj.start_state(GEOM))[:, None]
        K = np.zeros((traj.n_steps, 3, 5))
        _, t = timed(lambda: cost_and_gradient(K, Ad, Bd, traj.Q, traj.R, traj.tau_s, x0), 10)
        rows.append((name, traj.n_steps, t))
    return rows


CG_VARIANTS = [("K0 = 0, plain (the paper as printed)", False, "zero"),
               ("K0 = 0, block-Hessian preconditioned", True, "zero"),
               ("K0 = 0, horizon continuation, plain", False, "continuation"),
               ("K0 = 0, horizon continuation, preconditioned (default)", True, "continuation"),
               ("K0 = frozen-time LQR, preconditioned", True, "frozen-lqr")]


def bench_cg(cg_seconds, name="line", variants=CG_VARIANTS):
    traj, ref, Ad, Bd = problem(name)
    X0 = initial_error_set(initial_error(ref, traj.start_state(GEOM)))
    _, P = finite_horizon_lqr(Ad, Bd, traj.Q, traj.R, traj.tau_s)
    J_star = float(np.einsum("im,ij,jm->", X0, P[0], X0))
    rows = []
    for label, pre, init in variants:
        t0 = time.perf_counter()
        K0 = (frozen_time_lqr_gains(Ad, Bd, traj.Q, traj.R, traj.tau_s)
              if init == "frozen-lqr" else None)
        t_init = time.perf_counter() - t0
        opts = dict(precondition=pre, target_cost=1.01 * J_star, max_iter=100000,
                    max_seconds=cg_seconds)
        if init == "continuation":
            res = conjugate_gradient_continuation(Ad, Bd, traj.Q, traj.R, traj.tau_s, X0,
                                                  **opts)
        else:
            res = conjugate_gradient(Ad, Bd, traj.Q, traj.R, traj.tau_s, X0, K0=K0, **opts)
        h = np.array(res.history)
        at2 = h[h[:, 1] <= 2.0 - t_init][-1, 2] / J_star if np.any(h[:, 1] <= 2.0 - t_init) \
            else np.nan
        J0 = cost(Ad, Bd, np.zeros((traj.n_steps, 3, 5)) if K0 is None else K0, traj.Q, traj.R,
                  traj.tau_s, X0)
        msg = res.message.replace(f"time limit {cg_seconds - 0:g}", "time limit")
        if "time limit" in msg:
            msg = "time limit reached" + (" (continuation)" if "continuation" in msg else "")
        rows.append((label, res.cost / J_star, res.seconds + t_init, res.evaluations,
                     msg, at2, J0 / J_star))
    return J_star, rows


def bench_tracking():
    rows = []
    for label, name, x0 in TRACK_CASES:
        src = name if not name.endswith(".csv") else str(TRAJECTORY_DIR / name)
        traj = load_trajectory(src, GEOM)
        ref, gains = synthesize(traj, "riccati", GEOM, LIMITS)
        start = traj.start_state(GEOM) if x0 is None else np.array(x0, float)
        t0 = time.perf_counter()
        res = simulate(TrackingLaw(ref, gains, LIMITS), start)
        wall = time.perf_counter() - t0
        m = metrics(res, traj.Q, traj.R, traj.tau_s)
        rows.append((label, m, len(set(gains.phi_rad)), wall))
    return rows


#: The per-cycle pieces, in loop order (column titles of the per-cycle table).
CYCLE_PIECES = ("odometry", "law", "record", "log")


def _ideal_measurement(t_s, x, v1, wheel_rad, geom=GEOM):
    """What ideal wheels report at robot state ``x`` (5,) driving at ``v1`` m/s."""
    w = v1 / geom.wheel_radius_m
    d1, d2 = float(x[3]), float(x[4])
    return WheelState(t_s, (w,) * 4, (wheel_rad,) * 4, (d1, d2, d2, d1), (0.0,) * 4,
                      (0.1,) * 4, (0.0,) * 4)


def cycle_costs(name, log_dir):
    """Per-cycle CPU of the loop's own work on one trajectory, ideal wheels, Riccati gains.

    The cycle body of :meth:`controller.online.TrackingLoop.run` without the bus: odometry
    update, tracking law, the cycle record (state vector, steering integration, result row and
    the ``on_cycle`` dict) and the run-log write (``CycleRecord`` + ``RunLogWriter.write``).
    Returns ``{piece: per-cycle ns array}`` and the number of cycles.
    """
    traj = load_trajectory(name, GEOM)
    ref, gains = synthesize(traj, "riccati", GEOM, LIMITS)
    law = TrackingLaw(ref, gains, LIMITS)
    tau, r = traj.tau_s, GEOM.wheel_radius_m
    x = traj.start_state(GEOM)
    odo = Odometry(GEOM, x[:3])
    delta_cmd = x[3:5].copy()
    law.reset()
    ns = {p: [] for p in CYCLE_PIECES}
    rows, v1, wheel_rad = [], 0.0, 0.0
    clock = time.perf_counter_ns
    with RunLogWriter(Path(log_dir) / name, {"trajectory": name}) as writer:
        for k in range(int(1.5 * traj.n_steps)):
            t = k * tau
            meas = _ideal_measurement(t, x, v1, wheel_rad)
            c0 = clock()
            odo.update(tau, meas.drive_radps, meas.steer_rad, meas.drive_rad)
            c1 = clock()
            state = np.array([*odo.pose, *delta_cmd])
            v1, w1, w2 = law.command(t, state)
            c2 = clock()
            if law.last.get("finished"):
                break
            L = law.last
            delta_cmd = np.clip(delta_cmd + np.array([w1, w2]) * tau,
                                -LIMITS.steer_angle_max_rad, LIMITS.steer_angle_max_rad)
            steer = [delta_cmd[0], delta_cmd[1], delta_cmd[1], delta_cmd[0]]
            drive = [v1 / r] * 4
            truth = x[:3].copy()
            rows.append((t, state, truth, L["desired_state"], np.array([v1, w1, w2]), L["raw"],
                         L["s"], L["error"], L["u"] - L["ud"], 0))
            fields = TrackingLoop._cycle(k, t, tau, drive, steer, v1, w1, w2, meas, odo.pose,
                                         L["desired_state"], truth, 0)
            c3 = clock()
            writer.write(CycleRecord(sim_pose=truth, **fields))
            c4 = clock()
            for p, dt in zip(CYCLE_PIECES, (c1 - c0, c2 - c1, c3 - c2, c4 - c3)):
                ns[p].append(dt)
            # ideal actuators: wheel speed and steering reach their goals at once
            x[3:5] = delta_cmd
            x = rk4_step(x, [v1, 0.0, 0.0], tau, GEOM)
            wheel_rad += v1 / r * tau
    return {p: np.array(v) for p, v in ns.items()}, len(rows)


def bench_cycles(repeat=3):
    """Median (over cycles, then the best of ``repeat`` runs) and p99 per piece, microseconds."""
    out = []
    with tempfile.TemporaryDirectory() as d:
        for name in ("line", "circle", "curvilinear"):
            runs = []
            for j in range(repeat):
                costs, n = cycle_costs(name, Path(d) / str(j))
                runs.append(costs)
            med = {p: min(np.median(c[p]) for c in runs) / 1e3 for p in CYCLE_PIECES}
            p99 = {p: min(np.percentile(c[p], 99) for c in runs) / 1e3 for p in CYCLE_PIECES}
            out.append((name, n, med, p99))
    return out


def render_cycles(rows):
    out = [SECTION_CYCLE, "", machine(),
           "Command: `.venv/bin/python bench/bench_controller.py --per-cycle`. The loop body of "
           "`TrackingLoop.run` without the bus, on ideal wheels (Riccati gains, the paper's start "
           "states): µs per cycle, median over the run's cycles (best of 3 runs), p99 in "
           "brackets. *record*: state vector, steering integration, result row and the "
           "`on_cycle` dict; *log*: `CycleRecord` + `RunLogWriter.write` (flush every cycle).", "",
           "| trajectory | cycles | " + " | ".join(CYCLE_PIECES) + " | total (without log) |",
           "|---|---|" + "---|" * (len(CYCLE_PIECES) + 1)]
    for name, n, med, p99 in rows:
        cells = [f"{med[p]:.0f} ({p99[p]:.0f})" for p in CYCLE_PIECES]
        total = sum(med[p] for p in CYCLE_PIECES if p != "log")
        out.append(f"| {name} | {n} | " + " | ".join(cells) + f" | {total:.0f} |")
    return "\n".join(out) + "\n"


def machine():
    cpu = cpu_model()
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return (f"Date {datetime.date.today().isoformat()}, `nproc` = {os.cpu_count()}, CPU "
            f"\"{cpu}\", Python {platform.python_version()}, numpy {np.__version__}; "
            f"load average {load:.1f} at the start (shared machine).")


def _f(x):
    return "–" if not np.isfinite(x) else f"{x:.4f}"


def render(ric, grad, cg, cg_more, track, cg_seconds):
    J_star, cg_rows = cg
    out = [SECTION, "", machine(),
           "Command: `.venv/bin/python bench/bench_controller.py` (one run; medians of 3 "
           "(synthesis) or 10 (gradient) repetitions).", "",
           "Riccati synthesis (finite-horizon discrete recursion, exact J*):", "",
           "| trajectory | N | error system (A, B, frame switches) s | Riccati s |",
           "|---|---|---|---|"]
    out += [f"| {n} | {N} | {ts:.3f} | {tr:.3f} |" for n, N, ts, tr in ric]
    out += ["", "One cost + exact adjoint gradient evaluation (K = 0, one initial error):", "",
            "| trajectory | N | seconds |", "|---|---|---|"]
    out += [f"| {n} | {N} | {t * 1e3:.1f} ms |" for n, N, t in grad]
    out += ["", f"The paper's method (nonlinear CG, Dai–Yuan β, SciPy strong-Wolfe line search, "
            f"exact gradient) on the line case, N = 2500, target 1.01·J* (J* = {J_star:.4f}); "
            f"runs capped at {cg_seconds:g} s; times include computing K0:", "",
            "| start / variant | J(K0)/J* | J/J* reached | seconds | evaluations | J/J* at 2 s (– : still in a shorter stage or computing K0) | "
            "stopped because |", "|---|---|---|---|---|---|---|"]
    out += [f"| {lab} | {j0:.3g} | {r:.4f} | {s:.2f} | {e} | {_f(a2)} | {msg} |"
            for lab, r, s, e, msg, a2, j0 in cg_rows]
    for title, (J2, rows2) in cg_more:
        out += ["", f"Same target, {title} (J* = {J2:.4f}):", "",
                "| start / variant | J(K0)/J* | J/J* reached | seconds | evaluations | "
                "J/J* at 2 s | stopped because |", "|---|---|---|---|---|---|---|"]
        out += [f"| {lab} | {j0:.3g} | {r:.4f} | {s:.2f} | {e} | {_f(a2)} | {msg} |"
                for lab, r, s, e, msg, a2, j0 in rows2]
    out += ["", "Closed loop on the nonlinear model (1)–(5), Riccati gains, rotating chained "
            "frames, limits from configs/robot.yaml, errors over t ≥ tf/4:", "",
            "| case | frames | rms error m | max error m | final error m | max abs v1 m/s | "
            "max abs ω rad/s | saturated | ref. lag s | sim wall s |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    for lab, m, nf, wall in track:
        out.append(f"| {lab} | {nf} | {m['rms_position_error_m']:.2e} | "
                   f"{m['max_position_error_m']:.2e} | {m['final_position_error_m']:.2e} | "
                   f"{m['max_abs_v1_mps']:.3f} | {m['max_abs_steer_rate_radps']:.2f} | "
                   f"{100 * m['saturated_fraction']:.1f} % | {m['max_reference_lag_s']:.2f} | "
                   f"{wall:.1f} |")
    return "\n".join(out) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cg-seconds", type=float, default=60.0)
    ap.add_argument("--no-write", action="store_true")
    ap.add_argument("--per-cycle", action="store_true",
                    help="only the per-cycle cost of the online loop's own work")
    args = ap.parse_args()
    if args.per_cycle:
        text = render_cycles(bench_cycles())
        print(text)
        if not args.no_write:
            write_section(SECTION_CYCLE, text)
        return
    ric = bench_riccati()
    grad = bench_gradient()
    cg = bench_cg(args.cg_seconds)
    more = [("K0 = 0, horizon continuation, preconditioned (default)", True, "continuation"),
            ("K0 = frozen-time LQR, plain", False, "frozen-lqr"),
            ("K0 = frozen-time LQR, preconditioned", True, "frozen-lqr")]
    cg_more = [("circle (N = 3500, x~(0) = 0: five scaled unit initial errors)",
                bench_cg(args.cg_seconds, "circle", more)),
               ("curvilinear (N = 8750)", bench_cg(args.cg_seconds, "curvilinear", more))]
    track = bench_tracking()
    text = render(ric, grad, cg, cg_more, track, args.cg_seconds)
    print(text)
    if not args.no_write:
        write_section(SECTION, text)


if __name__ == "__main__":
    main()
