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

The runs and the calibration are independent lockstep runs, so they go to a pool of worker
processes (``--workers``, default one per CPU; one on the wall clock, where runs would compete
for the CPU in real time): the calibration starts first, the calibrated runs once it has
written its file, and among the runs ready to start the longest (in robot time) goes first, so
no worker is left with a long run while the others are idle. Each task's messages are printed
in the order a one-by-one demo prints them, so the output, the files and every number are the
same for any number of workers.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from collections import deque
from pathlib import Path

from tqdm import tqdm

from swerve.controller.trajectory import load_trajectory
from swerve.core.atomic import check_writable, write_text
from swerve.core.errors import ConfigError, SwerveError
from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
from swerve.tools.argtypes import finite_float, int_range
from swerve.tools.campaign.pool import Engine, ModuleJob, PoolEngine, run_queue
from swerve.tools.cli import add_config_option
from swerve.tools.demo.plan import Calibration, DemoPlan, DemoRow, Task, TaskDone, longest_first, tasks
from swerve.tools.run.geometry import geometry_and_limits, locate_and_load

TRAJECTORIES = ("line", "circle", "curvilinear")
#: The module whose ``run_job`` runs a task in a pool worker (imported there only).
TASK_MODULE = "swerve.tools.demo.runs"


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
    parser.add_argument("--workers", type=int_range(1, 256), default=None,
                        help="runs at a time, each in its own process (default: one per CPU in lockstep, "
                             "1 with --wall-clock); the results do not depend on it")


def run(args: argparse.Namespace) -> int:
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
    robot_s = {name: load_trajectory(name, geom, limits).tf_s for name in names}   # valid before any output
    check_writable(out / "summary.md")      # a read-only or full target is refused before the runs
    workers = args.workers or (len(os.sched_getaffinity(0)) if lockstep else 1)
    plan = DemoPlan(out, choice, tasks(robot_s, calibrate=not args.no_calibrate), str(args.emulator_config),
                    lockstep, scale, pace)
    created = _missing_folder(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        t_start = time.monotonic()
        values = run_tasks(plan.tasks, PoolEngine(ModuleJob(TASK_MODULE, plan), min(workers, len(plan.tasks))))
        rows = [v for v in values if isinstance(v, DemoRow)]
        calibration = next((v for v in values if isinstance(v, Calibration)), None)
        summary = _write_summary(out, rows, pace, time.monotonic() - t_start, choice,
                                 str(args.emulator_config), calibration)
    except BaseException:
        if created is not None:     # a failed demo leaves no new folder behind (every worker has exited)
            shutil.rmtree(created, ignore_errors=True)
        raise
    print(f"\nsummary: {summary}\nlogs:    {out / 'logs'}\nplots:   {out / 'plots'}\ngains:   {out / 'gains'}")
    return 0 if all(r.summary.get("completed") for r in rows) else 1


def _missing_folder(path: Path) -> Path | None:
    """The outermost folder of ``path`` that does not exist yet (``None`` if ``path`` exists)."""
    missing = None
    for folder in (path, *path.parents):
        if folder.exists():
            break
        missing = folder
    return missing


class WorkerTraceback(Exception):
    """The traceback of an error raised in a worker process, as text (the cause of the re-raised error)."""


def run_tasks(tasks: tuple[Task, ...], engine: Engine) -> list[DemoRow | Calibration]:
    """Run ``tasks`` on ``engine`` (its jobs return :class:`TaskDone`), ``engine.slots`` at a
    time, and close it; print each task's messages in the order of ``tasks``. Returns each
    task's value, in that order.

    The calibration is submitted first: the calibrated runs wait for it. Of the runs ready to
    start, the longest goes first (:func:`longest_first`). The error of a task is raised as soon
    as it arrives, after its messages; on any exception (a stop signal too) the engine is closed
    (every worker has exited) when this returns.
    """
    order = range(len(tasks))
    todo = deque([i for i in order if tasks[i].kind == "calibration"]
                 + longest_first(tasks, [i for i in order if tasks[i].robot == "as is"]))
    held = [i for i in order if tasks[i].robot == "calibrated"]
    done: dict[int, TaskDone] = {}
    shown = 0
    bar = tqdm(total=len(tasks), unit="task", desc=f"demo ({engine.slots} at a time)", disable=None,
               dynamic_ncols=True, leave=False)
    try:
        for finished in run_queue(engine, todo):
            task, result = tasks[finished.index], finished.outcome
            if result is None:
                raise SwerveError(f"the worker process of the demo's {_what(task)} went away ({finished.lost})")
            if result.error is not None:
                _show(result.lines)
                raise result.error from WorkerTraceback(result.trace)
            done[finished.index] = result
            bar.update(1)
            if task.kind == "calibration":
                ready = longest_first(tasks, [*todo, *held])
                todo.clear()
                todo.extend(ready)
            while shown in done:
                _show(done[shown].lines)
                shown += 1
    finally:
        bar.close()
        engine.close()
    return [done[i].value for i in order]


def _show(lines: tuple[str, ...]) -> None:
    """Print a task's messages above the progress bar."""
    for line in lines:
        tqdm.write(line)
    sys.stdout.flush()


def _what(task: Task) -> str:
    return "calibration" if task.kind == "calibration" else f"run of {task.name} (robot file {task.robot})"


def _fmt(v, scale=1e3, digits=1) -> str:
    try:
        return f"{float(v) * scale:.{digits}f}"
    except (TypeError, ValueError):
        return "-"


def _write_summary(out: Path, rows: list[DemoRow], pace: str, wall_s: float, choice, physics: str = "ideal",
                   calibration: Calibration | None = None) -> Path:
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
