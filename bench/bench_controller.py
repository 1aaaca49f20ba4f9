"""Controller benchmarks: Riccati synthesis, the paper's CG, gradient cost, tracking.

Run ``.venv/bin/python bench/bench_controller.py`` from the repository root. Results are
printed and written to the "## Controller" section of BENCHMARKS.md
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

from swerve.controller.gain_schedule import synthesize  # noqa: E402
from swerve.controller.kinematics import rk4_step  # noqa: E402
from swerve.controller.ltv import cost, error_system, initial_error  # noqa: E402
from swerve.controller.odometry import Odometry  # noqa: E402
from swerve.controller.reference import build_reference  # noqa: E402
from swerve.controller.trajectory import TRAJECTORY_DIR, load_trajectory  # noqa: E402
from swerve.controller.riccati import finite_horizon_lqr  # noqa: E402
from swerve.controller.simulate import metrics, simulate  # noqa: E402
from swerve.controller.synthesis import (conjugate_gradient,  # noqa: E402
                                  conjugate_gradient_continuation, cost_and_gradient,
                                  frozen_time_lqr_gains, initial_error_set)
from swerve.controller.tracking import TrackingLaw  # noqa: E402
from swerve.driver.wheelset import WheelState  # noqa: E402
from swerve.tools.logs import CycleRecord, RunLogWriter  # noqa: E402
from swerve.tools.run.loop import TrackingLoop  # noqa: E402
from swerve.tools.run.geometry import load_robot  # noqa: E402
from swerve.tools.run.ticker import ForegroundClock  # noqa: E402
from benchutil import cpu_model, write_section  # noqa: E402

SECTION = "## Controller"
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


#: Per-cycle cases: (label, trajectory, start state or None = the trajectory's own).
CYCLE_CASES = [("line", "line", None), ("circle", "circle", None),
               ("circle, start 0.1 m off, θ = 0.3 rad", "circle", [0.0, -0.1, 0.3, 0.0, 0.0]),
               ("curvilinear", "curvilinear", None)]
#: The per-cycle pieces (column titles of the per-cycle table).
CYCLE_PIECES = ("odometry", "law", "loop", "log")


class _Timer:
    """Accumulates the wall time of the calls it wraps, per loop cycle (ns)."""

    def __init__(self):
        self.ns = 0

    def wrap(self, fn):
        def timed(*args, **kwargs):
            t0 = time.perf_counter_ns()
            try:
                return fn(*args, **kwargs)
            finally:
                self.ns += time.perf_counter_ns() - t0
        return timed


class _IdealWheels(ForegroundClock):
    """Wheels that reach their goals at once, on a simulated clock (no bus, no sleeping).

    Each ``read_state`` starts a cycle: it records the time since the previous one and the time
    the pieces' timers accumulated meanwhile, the wheels' own work excluded.
    """

    def __init__(self, state, timers):
        self.x = np.asarray(state, float).copy()
        self.t = 0.0                     # simulated robot time, s
        self.t_read = 0.0
        self.timers = timers
        self.v1 = self.wheel_rad = 0.0
        self.cycles, self._t0, self._own = [], None, 0

    def now(self):
        return self.t

    def sleep_until(self, t):
        self.t = max(self.t, t)

    def read_state(self):
        now = time.perf_counter_ns()
        if self._t0 is not None:
            pieces = {name: tm.ns for name, tm in self.timers.items()}
            self.cycles.append((now - self._t0 - self._own, pieces))
        for tm in self.timers.values():
            tm.ns = 0
        self._t0, self._own = now, 0
        dt = self.t - self.t_read            # advance the ideal robot to the read time
        if dt > 0:
            self.x = rk4_step(self.x, [self.v1, 0.0, 0.0], dt, GEOM)
            self.wheel_rad += self.v1 / GEOM.wheel_radius_m * dt
        self.t_read = self.t
        w, d1, d2 = self.v1 / GEOM.wheel_radius_m, float(self.x[3]), float(self.x[4])
        st = WheelState(self.t, (w,) * 4, (self.wheel_rad,) * 4, (d1, d2, d2, d1), (0.0,) * 4,
                        (0.1,) * 4, (0.0,) * 4)
        self._own += time.perf_counter_ns() - now
        return st

    def write_goals(self, drive, steer):
        t0 = time.perf_counter_ns()
        self.v1 = float(np.mean(drive)) * GEOM.wheel_radius_m
        self.x[3], self.x[4] = steer[0], steer[1]
        self._own += time.perf_counter_ns() - t0

    def stop(self):
        self.v1 = 0.0


def cycle_costs(traj_name, x0, log_dir):
    """Per-cycle CPU of :meth:`swerve.tools.run.loop.TrackingLoop.run`'s own work, ideal wheels.

    Runs the real loop (Riccati gains, a run log as ``swerve run --log`` writes it) and splits
    each cycle into odometry (``Odometry.update``), law (``TrackingLaw.step``: inputs and
    steering goals), log (``CycleRecord`` + ``RunLogWriter.write``) and loop (everything else
    the loop does: state vector, result row, ``on_cycle`` dict, ticker). Returns
    ``({piece: ns array}, fraction of cycles whose reference time was on the grid)``.
    """
    import swerve.tools.run.loop as online

    traj = load_trajectory(traj_name, GEOM)
    ref, gains = synthesize(traj, "riccati", GEOM, LIMITS)
    law = TrackingLaw(ref, gains, LIMITS)
    start = traj.start_state(GEOM) if x0 is None else np.array(x0, float)
    timers = {p: _Timer() for p in ("odometry", "law", "log")}
    wheels = _IdealWheels(start, timers)
    timed_step, on_grid = timers["law"].wrap(law.step), []

    def step(t_s, state):
        out = timed_step(t_s, state)
        if not out.finished:                 # is the reference time a grid time?
            s = out.reference_time_s
            on_grid.append(s == ref.times_s[ref.index(s)])
        return out
    law.step = step

    class TimedOdometry(Odometry):
        update = timers["odometry"].wrap(Odometry.update)

    with RunLogWriter(Path(log_dir) / traj.name, {"trajectory": traj.name}) as writer:
        def on_cycle(fields):
            writer.write(CycleRecord(sim_pose=fields["true_pose"], **fields))

        loop = TrackingLoop(wheels, law, GEOM, clock=wheels,
                            true_pose=lambda: wheels.x[:3], on_cycle=timers["log"].wrap(on_cycle))
        saved, online.Odometry = online.Odometry, TimedOdometry
        try:
            loop.run(start)
        finally:
            online.Odometry = saved
    total = np.array([c[0] for c in wheels.cycles])
    ns = {p: np.array([c[1][p] for c in wheels.cycles]) for p in timers}
    ns["loop"] = total - sum(ns.values())
    return ns, float(np.mean(on_grid))


def bench_cycles(repeat=3):
    """Median (over cycles, then the best of ``repeat`` runs) and p99 per piece, microseconds."""
    out = []
    with tempfile.TemporaryDirectory() as d:
        for label, name, x0 in CYCLE_CASES:
            runs = [cycle_costs(name, x0, Path(d) / f"{label}-{j}") for j in range(repeat)]
            med = {p: min(np.median(c[p]) for c, _ in runs) / 1e3 for p in CYCLE_PIECES}
            p99 = {p: min(np.percentile(c[p], 99) for c, _ in runs) / 1e3 for p in CYCLE_PIECES}
            out.append((label, len(runs[0][0]["law"]), runs[0][1], med, p99))
    return out


def render_cycles(rows):
    out = [SECTION_CYCLE, "", machine(),
           "Command: `.venv/bin/python bench/bench_controller.py --per-cycle`. "
           "`TrackingLoop.run` on ideal wheels and a simulated clock (no bus; Riccati gains; run "
           "log written as by `swerve run --log`): µs per cycle, median over the run's cycles "
           "(best of 3 runs), p99 in brackets. *odometry*: `Odometry.update`; *law*: "
           "`TrackingLaw.step` (inputs and steering goals); *loop*: the rest of the loop's work "
           "(state vector, result row, `on_cycle` dict, ticker); *log*: `CycleRecord` + "
           "`RunLogWriter.write` (flush every cycle). *on grid*: share of cycles whose reference "
           "time is a grid time (the governor slows the reference clock off the grid).", "",
           "| case | cycles | on grid | " + " | ".join(CYCLE_PIECES) + " | total without log |",
           "|---|---|---|" + "---|" * (len(CYCLE_PIECES) + 1)]
    for label, n, grid, med, p99 in rows:
        cells = [f"{med[p]:.0f} ({p99[p]:.0f})" for p in CYCLE_PIECES]
        total = sum(med[p] for p in CYCLE_PIECES if p != "log")
        out.append(f"| {label} | {n} | {100 * grid:.0f} % | " + " | ".join(cells)
                   + f" | {total:.0f} |")
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
