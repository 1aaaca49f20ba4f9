"""``swerve demo``: the main job on the embedded default (the emulator), before and after calibration.

For each of the paper's three trajectories: synthesise the gain schedule, simulate the closed
loop on model (1)-(5), run the 62.5 Hz loop against the emulated robot in lockstep (robot time
owned by the emulator, so the runs are the same on every machine; ``--wall-clock`` runs it
time-scaled on the wall clock instead) with the robot file as it is. Then calibrate the emulated
robot as ``swerve calibrate --emulate --yes --lockstep`` does (steering zero, direction signs,
wheel radius, read from its true state), write the calibrated robot file to
``out/demo/robot-calibrated.yaml`` (the user's file is not touched) and run every trajectory
again with it, on the same emulated robot. Run logs, plots and a one-page summary with both
rows per trajectory and what calibration recovered go to ``out/demo/``.
"""
from __future__ import annotations

import argparse
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
from swerve.tools.argtypes import finite_float
from swerve.tools.cli import add_config_option


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
    parser.add_argument("--no-calibrate", action="store_true",
                        help="run with the robot file as it is only (no calibration and second run)")


def run(args: argparse.Namespace) -> int:
    from swerve.core.atomic import check_writable
    from swerve.core.errors import ConfigError
    from swerve.controller.trajectory import load_trajectory
    from swerve.tools.run.geometry import geometry_and_limits, locate_and_load

    if args.time_scale is not None and not args.time_scale > 0:
        raise ConfigError(f"--time-scale must be positive, got {args.time_scale}")
    lockstep = not args.wall_clock
    scale = args.time_scale if lockstep or args.time_scale else 5.0
    pace = ("in lockstep, " + (f"paced at {scale}x" if scale else "as fast as possible")
            if lockstep else f"on the wall clock at {scale}x")
    out = Path(args.out)
    choice, cfg = locate_and_load(args.config)
    print(f"config: {choice.describe()}", flush=True)
    geom, limits = geometry_and_limits(cfg)
    names = [n.strip() for n in args.trajectories.split(",") if n.strip()]
    if not names:
        raise ConfigError(f"--trajectories {args.trajectories!r} names no trajectory "
                          f"(e.g. {','.join(TRAJECTORIES)})")
    for name in names:          # every trajectory is valid before any output
        load_trajectory(name, geom, limits)
    check_writable(out / "summary.md")      # a read-only or full target is refused before the runs
    created = _missing_folder(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        return _demo(args, out, choice, cfg, geom, limits, names, lockstep, scale, pace)
    except BaseException:
        if created is not None:     # a failed demo leaves no new folder behind
            shutil.rmtree(created, ignore_errors=True)
        raise


def _missing_folder(path: Path) -> Path | None:
    """The outermost folder of ``path`` that does not exist yet (``None`` if ``path`` exists)."""
    missing = None
    for folder in (path, *path.parents):
        if folder.exists():
            break
        missing = folder
    return missing


def _demo(args, out, choice, cfg, geom, limits, names, lockstep, scale, pace) -> int:
    from swerve.tools.run.geometry import geometry_and_limits, locate_and_load

    t_start = time.monotonic()
    run = dict(lockstep=lockstep, scale=scale, pace=pace, emulator_config=args.emulator_config)
    rows = [_run_one(out, name, geom, limits, choice, "as is", **run) for name in names]
    calibration = None
    if not args.no_calibrate:
        calibration = _calibrate(out, cfg, choice.path, args.emulator_config)
        _, calibrated = locate_and_load(calibration.path)
        geom, limits = geometry_and_limits(calibrated)      # the gains are synthesised for it too
        rows += [_run_one(out, name, geom, limits, calibration.path, "calibrated", emulated_robot=choice.path, **run)
                 for name in names]
    summary = _write_summary(out, rows, pace, time.monotonic() - t_start, choice,
                             str(args.emulator_config), calibration)
    print(f"\nsummary: {summary}\nlogs:    {out / 'logs'}\nplots:   {out / 'plots'}\ngains:   {out / 'gains'}")
    return 0 if all(r.summary.get("completed") for r in rows) else 1


@dataclass(frozen=True)
class DemoRow:
    """One run of the demo: trajectory ``name``, the robot file's state (``"as is"`` or
    ``"calibrated"``), the simulated metrics, the run's summary dict, its figures, gains and log."""

    name: str
    robot: str
    sim: dict
    summary: dict
    figures: list
    gains_file: Path
    log_dir: Path


@dataclass(frozen=True)
class Calibration:
    """What the demo's calibration found (``values`` of :func:`swerve.tools.calibrate.run_steps`),
    the robot file's values before it, and the calibrated file written."""

    values: dict
    before: dict
    path: Path


def _run_one(out: Path, name: str, geom, limits, config, robot: str, *, lockstep: bool, scale, pace: str,
             emulator_config: str, emulated_robot=None) -> DemoRow:
    """Synthesise, simulate and run one trajectory with robot file ``config`` on the emulator."""
    from swerve.controller.gain_schedule import synthesize
    from swerve.controller.gains_io import save_gains
    from swerve.controller.trajectory import load_trajectory
    from swerve.controller.simulate import metrics, simulate
    from swerve.controller.tracking import TrackingLaw
    from swerve.tools.logs.bag import read_log
    from swerve.tools.logs.log_figures import plot_run
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    tag = f"[{name}, robot file {robot}]"
    print(f"{tag} synthesising gains (Riccati) ...", flush=True)
    traj = load_trajectory(name, geom, limits)
    ref, gains = synthesize(traj, "riccati", geom, limits)
    stem = Path(name).stem
    run_name = stem if robot == "as is" else f"{stem}-{robot}"
    gains_file = save_gains(out / "gains" / f"{run_name}.npz", gains)
    save_gains(out / "gains" / f"{run_name}.dat", gains)
    sim = metrics(simulate(TrackingLaw(ref, gains, limits), traj.start_state(geom)), traj.Q, traj.R, traj.tau_s)
    print(f"{tag} simulated: final error {sim['final_position_error_m'] * 1e3:.1f} mm; running on the emulator "
          f"{pace} ({traj.tf_s:.0f} s of robot time) ...", flush=True)
    log_dir = out / "logs" / run_name
    if log_dir.exists():
        shutil.rmtree(log_dir)
    res = run_tracking(RunRequest(trajectory=name, gains=gains_file, config=config, emulate=True,
                                  lockstep=lockstep, time_scale=scale, log=log_dir,
                                  emulator_config=emulator_config, emulated_robot=emulated_robot))
    figs = plot_run(read_log(log_dir), out / "plots" / run_name)
    s = res.summary.to_dict()
    state = "completed" if s.get("completed") else f"STOPPED: {s.get('abort_message', '?')}"
    print(f"{tag} {state}; rms error {s.get('rms_position_error_m', float('nan')) * 1e3:.1f} mm, final "
          f"{s.get('final_position_error_m', float('nan')) * 1e3:.1f} mm, overruns {s.get('overruns')}, "
          f"real-time factor {s.get('real_time_factor', float('nan')):.1f}", flush=True)
    return DemoRow(name, robot, sim, s, figs, gains_file, log_dir)


def _calibrate(out: Path, cfg, robot_path: Path, emulator_config: str) -> Calibration:
    """Calibrate the emulated robot (built from ``robot_path`` and ``emulator_config``) in lockstep,
    as ``swerve calibrate --emulate --yes --lockstep`` does; write ``out/robot-calibrated.yaml``."""
    from swerve.core.atomic import write_text
    from swerve.tools.calibrate import calibrate_emulated, update_robot_text

    print("[calibration] steering zero, direction signs and wheel radius on the emulated robot ...", flush=True)
    values = calibrate_emulated(cfg, robot_path, emulator_config=emulator_config, lockstep=True,
                                log=lambda msg: print(f"[calibration] {msg}", flush=True))
    keys = {k: v for k, v in values.items() if k != "radius_facts"}
    path = out / "robot-calibrated.yaml"
    write_text(path, update_robot_text(Path(robot_path).read_text(), where=str(path), **keys))
    before = dict(center_pulse=[w.center_pulse for w in cfg.wheels],
                  drive_direction=[w.drive_direction for w in cfg.wheels],
                  steer_direction=[w.steer_direction for w in cfg.wheels], wheel_radius_m=cfg.wheel_radius_m)
    print(f"[calibration] wrote {path}", flush=True)
    return Calibration(values, before, path)


def _fmt(v, scale=1e3, digits=1) -> str:
    try:
        return f"{float(v) * scale:.{digits}f}"
    except (TypeError, ValueError):
        return "-"


def _write_summary(out: Path, rows: list[DemoRow], pace: str, wall_s: float, choice, physics: str = "ideal",
                   calibration: Calibration | None = None) -> Path:
    from swerve.core.atomic import write_text

    lines = ["# swerve demo", "",
             f"Generated {time.strftime('%Y-%m-%d %H:%M')} by `swerve demo`: gains by finite-horizon Riccati, "
             f"closed loop simulated on model (1)-(5) and run at 62.5 Hz against the emulated robot "
             f"(Table 1 motors, firmware loops, robot body) {pace}; "
             f"{wall_s:.0f} s wall in all.", "",
             f"Robot file: `{choice.path}` ({choice.source}); emulator physics: `{physics}`."
             + ("" if calibration is None else
                f" Each trajectory runs with the robot file as it is, then with the file calibrated on the "
                f"emulated robot (`{calibration.path}`), on the same emulated robot."), "",
             "Errors in mm (rms and max over t >= tf/4); emulator errors use the emulator's true pose.", "",
             "| trajectory | robot file | sim rms | sim max | sim final | emu rms | emu max | emu final "
             "| odometry vs true max | loop p50 / p99 ms | overruns | status |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        sim, s = r.sim, r.summary
        status = "completed" if s.get("completed") else f"stopped: {s.get('abort_cause')}"
        lines.append(
            f"| {r.name} | {r.robot} | {_fmt(sim['rms_position_error_m'])} | {_fmt(sim['max_position_error_m'])} | "
            f"{_fmt(sim['final_position_error_m'])} | {_fmt(s.get('rms_position_error_m'))} | "
            f"{_fmt(s.get('max_position_error_m'))} | {_fmt(s.get('final_position_error_m'))} | "
            f"{_fmt(s.get('odometry_vs_true_max_m'))} | {_fmt(s.get('loop_period_p50_ms'), 1, 2)} / "
            f"{_fmt(s.get('loop_period_p99_ms'), 1, 2)} | {s.get('overruns', '-')} | {status} |")
    if calibration is not None:
        lines += ["", "## What calibration recovered", "", calibration_table(calibration, rows)]
    for r in rows:
        lines += ["", f"## {r.name} (robot file {r.robot})", "", f"Gains: `{r.gains_file}`; log: `{r.log_dir}` "
                  f"(ROS 2 bag, MCAP: open with Foxglove or `swerve export-csv`).", ""]
        lines += [f"![{f.stem}]({f.relative_to(out)})" for f in r.figures]
    path = out / "summary.md"
    write_text(path, "\n".join(lines) + "\n")
    return path


def calibration_table(calibration: Calibration, rows: list[DemoRow]) -> str:
    """Markdown: the values calibration found against the robot file's, and each trajectory's
    emulator rms error before and after."""
    v, b = calibration.values, calibration.before
    lines = ["| item | robot file | calibrated |", "|---|---|---|"]
    for key, label in (("center_pulse", "steering centres, pulse"), ("steer_direction", "steering directions"),
                       ("drive_direction", "drive directions")):
        if key in v:
            lines.append(f"| {label} | {b[key]} | {list(v[key])} |")
    if "wheel_radius_m" in v:
        lines.append(f"| wheel radius, mm | {b['wheel_radius_m'] * 1e3:.3f} | {v['wheel_radius_m'] * 1e3:.3f} |")
    by = {(r.name, r.robot): r.summary for r in rows}
    lines += ["", "| trajectory | emu rms as is, mm | emu rms calibrated, mm | recovered, mm |", "|---|---|---|---|"]
    for name in dict.fromkeys(r.name for r in rows):
        before = by.get((name, "as is"), {}).get("rms_position_error_m")
        after = by.get((name, "calibrated"), {}).get("rms_position_error_m")
        gained = before - after if before is not None and after is not None else None
        lines.append(f"| {name} | {_fmt(before)} | {_fmt(after)} | {_fmt(gained)} |")
    return "\n".join(lines)
