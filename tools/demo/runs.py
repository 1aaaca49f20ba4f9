"""What a pool worker does for one of the demo's tasks: synthesise, simulate, run on the emulator
and draw one trajectory, or calibrate the emulated robot. :func:`run_job` is the pool's job
(:class:`swerve.tools.campaign.pool.ModuleJob`); the worker imports this module once and runs
every task it is given with it."""
from __future__ import annotations

import pickle
import shutil
import traceback
from collections.abc import Callable
from pathlib import Path

from swerve.controller.gain_schedule import synthesize
from swerve.controller.gains_io import save_gains
from swerve.controller.riccati_cache import RiccatiCache
from swerve.core.user_cache import user_cache_dir
from swerve.controller.simulate import metrics, simulate
from swerve.controller.tracking import TrackingLaw
from swerve.controller.trajectory import load_trajectory
from swerve.core.atomic import write_text
from swerve.tools.calibrate import update_robot_text
from swerve.tools.calibrate_emulated import calibrate_emulated
from swerve.tools.logs.bag import read_log
from swerve.tools.logs.log_figures import plot_run
from swerve.tools.run.geometry import geometry_and_limits, locate_and_load
from swerve.tools.run.orchestrate import RunRequest, run_tracking

from .plan import CALIBRATED_FILE, Calibration, DemoPlan, DemoRow, Task, TaskDone


def run_job(plan: DemoPlan, index: int) -> TaskDone:
    """Run ``plan.tasks[index]`` and return its :class:`TaskDone`, never raising an
    :class:`Exception` (a stop signal still ends it through its clean-up)."""
    lines: list[str] = []
    task = plan.tasks[index]
    try:
        if task.kind == "calibration":
            value = _calibrate(plan.out, plan.choice.path, plan.emulator_config, lines.append)
        else:
            value = _run_task(plan, task, lines.append)
        return TaskDone(tuple(lines), value)
    except Exception as exc:  # noqa: BLE001 - carried to the main process, which raises it
        return TaskDone(tuple(lines), error=_picklable(exc), trace=traceback.format_exc())


def _run_task(plan: DemoPlan, task: Task, say: Callable[[str], None]) -> DemoRow:
    """The run ``task``, with the robot file as it is or the calibrated one (on the robot as it is)."""
    if task.robot == "as is":
        choice, emulated = plan.choice, None
    else:
        choice, emulated = plan.out / CALIBRATED_FILE, plan.choice.path
    _, cfg = locate_and_load(choice)
    geom, limits = geometry_and_limits(cfg)     # the calibrated file's gains are synthesised for it
    return _run_one(plan.out, task.name, geom, limits, choice, task.robot, say, lockstep=plan.lockstep,
                    scale=plan.scale, pace=plan.pace, emulator_config=plan.emulator_config,
                    emulated_robot=emulated)


def _picklable(exc: Exception) -> Exception:
    """``exc`` if it crosses a process boundary intact, else a :class:`RuntimeError` naming it."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any failure to pickle or rebuild
        return RuntimeError(f"{type(exc).__name__}: {exc}")


def _run_one(out: Path, name: str, geom, limits, config, robot: str, say: Callable[[str], None], *,
             lockstep: bool, scale, pace: str, emulator_config: str, emulated_robot=None) -> DemoRow:
    """Synthesise, simulate and run one trajectory with robot file ``config`` on the emulator
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


__all__ = ["run_job"]
