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
import pickle
import shutil
import sys
import time
import traceback
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from tqdm import tqdm

from swerve.configs import ConfigChoice
from swerve.controller.gain_schedule import synthesize
from swerve.controller.gains_io import save_gains
from swerve.controller.riccati_cache import RiccatiCache, user_cache_dir
from swerve.controller.simulate import metrics, simulate
from swerve.controller.tracking import TrackingLaw
from swerve.controller.trajectory import load_trajectory
from swerve.core.atomic import check_writable, write_text
from swerve.core.errors import ConfigError, SwerveError
from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP
from swerve.tools.argtypes import finite_float, int_range
from swerve.tools.calibrate import update_robot_text
from swerve.tools.calibrate_emulated import calibrate_emulated
from swerve.tools.campaign.engines import Engine, PoolEngine, run_queue
from swerve.tools.cli import add_config_option
from swerve.tools.logs.bag import read_log
from swerve.tools.logs.log_figures import plot_run
from swerve.tools.run.geometry import geometry_and_limits, locate_and_load
from swerve.tools.run.orchestrate import RunRequest, run_tracking


TRAJECTORIES = ("line", "circle", "curvilinear")
KEYS = ("rms_position_error_m", "max_position_error_m", "final_position_error_m", "max_abs_v1_mps",
        "max_abs_steer_rate_radps")
#: Where the demo writes the calibrated robot file, in its output folder.
CALIBRATED_FILE = "robot-calibrated.yaml"


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
        values = run_tasks(plan.tasks, PoolEngine(plan, min(workers, len(plan.tasks))))
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


@dataclass(frozen=True)
class Task:
    """One job of the demo: the ``calibration``, or a ``run`` of trajectory ``name`` with the
    robot file ``robot`` (``"as is"``, or ``"calibrated"``: the file the calibration wrote),
    ``robot_s`` seconds of robot time long (what a run costs grows with it)."""

    kind: str
    name: str = ""
    robot: str = ""
    robot_s: float = 0.0


def tasks(robot_s: dict[str, float], *, calibrate: bool) -> tuple[Task, ...]:
    """The demo's tasks in the order their messages are printed: each trajectory of ``robot_s``
    (name -> its robot time, s) with the robot file as it is, then the calibration and each
    trajectory with the calibrated file."""
    first = [Task("run", n, "as is", s) for n, s in robot_s.items()]
    if not calibrate:
        return tuple(first)
    return (*first, Task("calibration"), *(Task("run", n, "calibrated", s) for n, s in robot_s.items()))


def longest_first(tasks: tuple[Task, ...], indices) -> list[int]:
    """``indices`` of ``tasks``, the longest run (robot time) first; ties keep their order."""
    return sorted(indices, key=lambda i: -tasks[i].robot_s)


@dataclass(frozen=True)
class TaskDone:
    """What a task left: the ``lines`` it printed, and its ``value`` (a :class:`DemoRow` or the
    :class:`Calibration`) or the ``error`` it raised (with the worker's ``trace``)."""

    lines: tuple[str, ...]
    value: DemoRow | Calibration | None = None
    error: Exception | None = None
    trace: str = ""


class WorkerTraceback(Exception):
    """The traceback of an error raised in a worker process, as text (the cause of the re-raised error)."""


@dataclass(frozen=True)
class DemoPlan:
    """Everything a worker process needs to run the demo's task ``index`` (picklable):
    ``plan(index)`` runs ``tasks[index]`` and returns its :class:`TaskDone`, never raising an
    :class:`Exception` (a stop signal still ends it through its clean-up)."""

    out: Path
    choice: ConfigChoice
    tasks: tuple[Task, ...]
    emulator_config: str
    lockstep: bool
    scale: float | None
    pace: str

    def __call__(self, index: int) -> TaskDone:
        lines: list[str] = []
        task = self.tasks[index]
        try:
            if task.kind == "calibration":
                value = _calibrate(self.out, self.choice.path, self.emulator_config, lines.append)
            else:
                value = self.run(task, lines.append)
            return TaskDone(tuple(lines), value)
        except Exception as exc:  # noqa: BLE001 - carried to the main process, which raises it
            return TaskDone(tuple(lines), error=_picklable(exc), trace=traceback.format_exc())

    def run(self, task: Task, say: Callable[[str], None]) -> DemoRow:
        """The run ``task``, with the robot file as it is or the calibrated one (on the robot as it is)."""
        if task.robot == "as is":
            choice, emulated = self.choice, None
        else:
            choice, emulated = self.out / CALIBRATED_FILE, self.choice.path
        _, cfg = locate_and_load(choice)
        geom, limits = geometry_and_limits(cfg)     # the calibrated file's gains are synthesised for it
        return _run_one(self.out, task.name, geom, limits, choice, task.robot, say, lockstep=self.lockstep,
                        scale=self.scale, pace=self.pace, emulator_config=self.emulator_config,
                        emulated_robot=emulated)


def _picklable(exc: Exception) -> Exception:
    """``exc`` if it crosses a process boundary intact, else a :class:`RuntimeError` naming it."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any failure to pickle or rebuild
        return RuntimeError(f"{type(exc).__name__}: {exc}")


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


def _run_one(out: Path, name: str, geom, limits, config, robot: str, say: Callable[[str], None], *,
             lockstep: bool, scale, pace: str, emulator_config: str, emulated_robot=None) -> DemoRow:
    """Synthesise, simulate and run one trajectory with robot file ``config`` on the emulator;
    ``say`` prints a message."""
    tag = f"[{name}, robot file {robot}]"
    say(f"{tag} synthesising gains (Riccati) ...")
    traj = load_trajectory(name, geom, limits)
    # as `swerve run` does: a Riccati solution of an input already seen comes from the user's cache, bit for bit
    ref, gains = synthesize(traj, "riccati", geom, limits, lqr=RiccatiCache(user_cache_dir()).solve)
    stem = Path(name).stem
    run_name = stem if robot == "as is" else f"{stem}-{robot}"
    gains_file = save_gains(out / "gains" / f"{run_name}.npz", gains)
    save_gains(out / "gains" / f"{run_name}.dat", gains)
    sim = metrics(simulate(TrackingLaw(ref, gains, limits), traj.start_state(geom)), traj.Q, traj.R, traj.tau_s)
    say(f"{tag} simulated: final error {sim['final_position_error_m'] * 1e3:.1f} mm; running on the emulator "
        f"{pace} ({traj.tf_s:.0f} s of robot time) ...")
    log_dir = out / "logs" / run_name
    if log_dir.exists():
        shutil.rmtree(log_dir)
    res = run_tracking(RunRequest(trajectory=name, gains=gains_file, config=config, emulate=True,
                                  lockstep=lockstep, time_scale=scale, log=log_dir,
                                  emulator_config=emulator_config, emulated_robot=emulated_robot))
    figs = plot_run(read_log(log_dir), out / "plots" / run_name)
    s = res.summary.to_dict()
    state = "completed" if s.get("completed") else f"STOPPED: {s.get('abort_message', '?')}"
    say(f"{tag} {state}; rms error {s.get('rms_position_error_m', float('nan')) * 1e3:.1f} mm, final "
        f"{s.get('final_position_error_m', float('nan')) * 1e3:.1f} mm, overruns {s.get('overruns')}, "
        f"real-time factor {s.get('real_time_factor', float('nan')):.1f}")
    return DemoRow(name, robot, sim, s, figs, gains_file, log_dir)


def _calibrate(out: Path, robot_path: Path, emulator_config: str, say: Callable[[str], None]) -> Calibration:
    """Calibrate the emulated robot (built from ``robot_path`` and ``emulator_config``) in lockstep,
    as ``swerve calibrate --emulate --yes --lockstep`` does; write ``out/robot-calibrated.yaml``."""
    _, cfg = locate_and_load(robot_path)
    say("[calibration] steering zero, direction signs and wheel radius on the emulated robot ...")
    values = calibrate_emulated(cfg, robot_path, emulator_config=emulator_config, lockstep=True,
                                log=lambda msg: say(f"[calibration] {msg}"))
    keys = {k: v for k, v in values.items() if k != "radius_facts"}
    path = out / CALIBRATED_FILE
    write_text(path, update_robot_text(Path(robot_path).read_text(), where=str(path), **keys))
    before = dict(center_pulse=[w.center_pulse for w in cfg.wheels],
                  drive_direction=[w.drive_direction for w in cfg.wheels],
                  steer_direction=[w.steer_direction for w in cfg.wheels], wheel_radius_m=cfg.wheel_radius_m)
    say(f"[calibration] wrote {path}")
    return Calibration(values, before, path)


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
