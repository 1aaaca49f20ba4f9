"""``swerve demo``: the main job on the embedded default (the emulator).

For each of the paper's three trajectories: synthesise the gain schedule, simulate the closed
loop on model (1)-(5), run the 62.5 Hz loop against the emulated robot in lockstep (robot time
owned by the emulator, so the runs are the same on every machine; ``--wall-clock`` runs it
time-scaled on the wall clock instead), write the run log, plots and a one-page summary to
``out/demo/``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
from swerve.tools.argtypes import finite_float
from swerve.tools.cli import add_config_option

NAME = "demo"
HELP = "synthesise gains, run the paper's three trajectories on the emulator, write logs, plots, summary"

TRAJECTORIES = ("line", "circle", "curvilinear")
KEYS = ("rms_position_error_m", "max_position_error_m", "final_position_error_m", "max_abs_v1_mps",
        "max_abs_steer_rate_radps")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_config_option(parser)
    parser.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    parser.add_argument("--wall-clock", action="store_true",
                        help="run on the wall clock (time-scaled) instead of in lockstep")
    parser.add_argument("--time-scale", type=finite_float(0.0, 1000.0, lo_open=True), default=None,
                        help="robot seconds per wall second (lockstep: pacing, default as fast as "
                             "possible; --wall-clock: default 5, BENCHMARKS.md has the loop timing per "
                             "scale on a 2-core machine)")
    parser.add_argument("--trajectories", default=",".join(TRAJECTORIES),
                        help="comma-separated trajectory names or files (default: the paper's three)")
    parser.add_argument("--emulator-config", default="realistic",
                        help=EMULATOR_CONFIG_HELP + "; default realistic")


def run(args: argparse.Namespace) -> int:
    from swerve.controller.design import synthesize
    from swerve.controller.gains_io import save_gains
    from swerve.controller.trajectory import load_trajectory
    from swerve.controller.simulate import metrics, simulate
    from swerve.controller.tracking import TrackingLaw
    from swerve.tools.logs.bag import read_log
    from swerve.tools.logs.plots import plot_run
    from swerve.tools.run.orchestrate import RunRequest, run_tracking
    from swerve.tools.run.robot import geometry_and_limits, locate_and_load

    from swerve.configs.errors import ConfigError

    if args.time_scale is not None and not args.time_scale > 0:
        raise ConfigError(f"--time-scale must be positive, got {args.time_scale}")
    lockstep = not args.wall_clock
    scale = args.time_scale if lockstep or args.time_scale else 5.0
    pace = ("in lockstep, " + (f"paced at {scale}x" if scale else "as fast as possible")
            if lockstep else f"on the wall clock at {scale}x")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    choice, cfg = locate_and_load(args.config)
    print(f"config: {choice.describe()}", flush=True)
    geom, limits = geometry_and_limits(cfg)
    names = [n.strip() for n in args.trajectories.split(",") if n.strip()]
    rows, t_start = [], time.monotonic()
    for name in names:
        print(f"[{name}] synthesising gains (Riccati) ...", flush=True)
        traj = load_trajectory(name, geom, limits)
        ref, gains = synthesize(traj, "riccati", geom, limits)
        stem = Path(name).stem
        gains_file = save_gains(out / "gains" / f"{stem}.npz", gains)
        save_gains(out / "gains" / f"{stem}.dat", gains)
        sim = metrics(simulate(TrackingLaw(ref, gains, limits), traj.start_state(geom)),
                      traj.Q, traj.R, traj.tau_s)
        print(f"[{name}] simulated: final error {sim['final_position_error_m'] * 1e3:.1f} mm; "
              f"running on the emulator {pace} ({traj.tf_s:.0f} s of robot time) ...",
              flush=True)
        log_dir = out / "logs" / stem
        if log_dir.exists():
            import shutil
            shutil.rmtree(log_dir)
        res = run_tracking(RunRequest(trajectory=name, gains=gains_file, config=choice,
                                      emulate=True, lockstep=lockstep, time_scale=scale, log=log_dir,
                                      emulator_config=args.emulator_config))
        figs = plot_run(read_log(log_dir), out / "plots" / stem)
        s = res.summary.to_dict()
        state = "completed" if s.get("completed") else f"STOPPED: {s.get('abort_message', '?')}"
        print(f"[{name}] {state}; final error {s.get('final_position_error_m', float('nan')) * 1e3:.1f} mm, "
              f"overruns {s.get('overruns')}, real-time factor {s.get('real_time_factor', float('nan')):.1f}",
              flush=True)
        rows.append((name, sim, s, figs, gains_file, log_dir))
    summary = _write_summary(out, rows, pace, time.monotonic() - t_start, choice,
                             str(args.emulator_config))
    print(f"\nsummary: {summary}\nlogs:    {out / 'logs'}\nplots:   {out / 'plots'}\ngains:   {out / 'gains'}")
    return 0 if all(r[2].get("completed") for r in rows) else 1


def _fmt(v, scale=1e3, digits=1) -> str:
    try:
        return f"{float(v) * scale:.{digits}f}"
    except (TypeError, ValueError):
        return "-"


def _write_summary(out: Path, rows, pace: str, wall_s: float, choice, physics: str = "ideal") -> Path:
    from swerve.configs.atomic import write_text

    lines = ["# swerve demo", "",
             f"Generated {time.strftime('%Y-%m-%d %H:%M')} by `swerve demo`: gains by finite-horizon Riccati, "
             f"closed loop simulated on model (1)-(5) and run at 62.5 Hz against the emulated robot "
             f"(Table 1 motors, firmware loops, robot body) {pace}; "
             f"{wall_s:.0f} s wall in all.", "",
             f"Robot file: `{choice.path}` ({choice.source}); emulator physics: `{physics}`.", "",
             "Errors in mm (rms and max over t >= tf/4); emulator errors use the emulator's true pose.", "",
             "| trajectory | sim rms | sim max | sim final | emu rms | emu max | emu final | odometry vs true max "
             "| loop p50 / p99 ms | overruns | status |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, sim, s, figs, gains_file, log_dir in rows:
        status = "completed" if s.get("completed") else f"stopped: {s.get('abort_cause')}"
        lines.append(
            f"| {name} | {_fmt(sim['rms_position_error_m'])} | {_fmt(sim['max_position_error_m'])} | "
            f"{_fmt(sim['final_position_error_m'])} | {_fmt(s.get('rms_position_error_m'))} | "
            f"{_fmt(s.get('max_position_error_m'))} | {_fmt(s.get('final_position_error_m'))} | "
            f"{_fmt(s.get('odometry_vs_true_max_m'))} | {_fmt(s.get('loop_period_p50_ms'), 1, 2)} / "
            f"{_fmt(s.get('loop_period_p99_ms'), 1, 2)} | {s.get('overruns', '-')} | {status} |")
    for name, sim, s, figs, gains_file, log_dir in rows:
        lines += ["", f"## {name}", "", f"Gains: `{gains_file}`; log: `{log_dir}` "
                  f"(ROS 2 bag, MCAP: open with Foxglove or `swerve export-csv`).", ""]
        lines += [f"![{f.stem}]({f.relative_to(out)})" for f in figs]
    path = out / "summary.md"
    write_text(path, "\n".join(lines) + "\n")
    return path

