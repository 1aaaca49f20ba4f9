"""One scenario of a campaign: draw the robot, (calibrate it,) run it in lockstep, make its row.

The run is :func:`swerve.tools.run.orchestrate.run_tracking` with the request ``swerve run
--emulate --lockstep`` builds (pty, driver, emulator server), the drawn physics written as an
emulator config file; the calibration is ``swerve calibrate --emulate --yes --lockstep
--write`` on a copy of the robot file, parsed by that command's own parser. A scenario the
controller or the emulator refuses is a ``failed`` row with the reason, not an exception.
"""
from __future__ import annotations

import contextlib
import io
import math
import shutil
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from swerve.core.atomic import write_text
from swerve.core.errors import SwerveError
from swerve.controller.gain_schedule import synthesize
from swerve.controller.gains_io import save_gains
from swerve.controller.trajectory import load_trajectory
from swerve.driver.robot_config import load_robot_config
from swerve.tools.calibrate import write_robot_file
from swerve.tools.calibrate_emulated import calibrate_emulated
from swerve.tools.run.geometry import geometry_and_limits, locate_and_load
from swerve.tools.run.orchestrate import RunRequest, run_tracking

from .draw import Robot, draw_robot
from .spec import Campaign, Cell, dump_physics, profile_data, set_dotted

#: The run summary's keys kept in results.csv: the ones a lockstep run repeats bit for bit
#: (host-measured times and CPU are left out, so the table is the same on every machine).
METRICS = ("completed", "cycles", "failed_reads", "rms_position_error_m", "max_position_error_m",
           "final_position_error_m", "odometry_vs_true_max_m", "odometry_vs_true_final_m",
           "max_abs_v1_mps", "max_abs_steer_rate_radps", "cost", "max_reference_lag_s",
           "saturated_fraction", "duration_s", "loop_period_p99_ms", "overruns", "missed_slots",
           "bus_stray_replies", "bus_corrupt_frames", "emulator_replies_dropped", "recoveries",
           "abort_cause")
#: What calibration found, kept in results.csv when the campaign calibrates.
CALIBRATION = tuple(f"calibrated_center_pulse[{w}]" for w in range(4)) + ("calibrated_wheel_radius_m",)
#: Statuses of a row.
STATUSES = ("completed", "stopped", "failed")


@dataclass(frozen=True)
class Scenario:
    """Scenario ``index`` of a campaign: its grid ``cell`` and drawn ``robot``."""

    index: int
    cell: Cell
    robot: Robot


@dataclass(frozen=True)
class Outcome:
    """A finished scenario: its results.csv ``row`` (every value already text) and how long it
    took on its worker (``run_s``, wall s; host-measured, not in the table)."""

    index: int
    row: dict
    run_s: float

    @property
    def status(self) -> str:
        """``completed``, ``stopped`` or ``failed``."""
        return self.row["status"]


def scenario(campaign: Campaign, index: int) -> Scenario:
    """Scenario ``index``: a pure function of the campaign file, its seed and ``index``."""
    sample, cell = campaign.cell_of(index)
    return Scenario(index, cell, draw_robot(campaign, sample))


def text(value) -> str:
    """A table cell: floats by ``repr`` (shortest text that reads back bit for bit), None empty."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else repr(value)
    return " ".join(str(value).split())


def columns(campaign: Campaign) -> list[str]:
    """The header of results.csv."""
    head = ["index", "sample", "trajectory", "profile", "gains", "faults", "calibrate"]
    for p in campaign.parameters:
        head += p.columns
    tail = list(CALIBRATION) if any(c.calibrate for c in campaign.cells) else []
    return head + ["status", "reason"] + list(METRICS) + tail


def base_row(campaign: Campaign, sc: Scenario) -> dict:
    """The columns of a scenario's row known before it runs: its grid cell and drawn values."""
    c = sc.cell
    return dict(index=sc.index, sample=sc.robot.sample, trajectory=c.trajectory, profile=c.profile,
                gains=c.gains, faults=c.faults, calibrate=c.calibrate, **sc.robot.columns(campaign.parameters))


def physics_file(campaign: Campaign, sc: Scenario, folder: Path) -> Path:
    """The scenario's emulator config: its profile with the drawn values set; written to ``folder``."""
    data = profile_data(campaign.resolve(sc.cell.profile))
    for key, value in sc.robot.values.items():
        set_dotted(data, key, list(value) if isinstance(value, tuple) else value)
    return write_text(folder / "physics.yaml", dump_physics(data), fsync=False)


def _gains(campaign: Campaign, cell: Cell, config: Path, folder: Path) -> str | None:
    """The gain schedule file of ``cell`` (None: the run synthesises Riccati gains itself)."""
    if cell.gains == "riccati":
        return None
    if cell.gains != "paper":
        return campaign.resolve(cell.gains)
    _, cfg = locate_and_load(config)
    geom, limits = geometry_and_limits(cfg)
    _, gains = synthesize(load_trajectory(campaign.resolve(cell.trajectory), geom, limits), "paper", geom, limits)
    return str(save_gains(folder / "gains.npz", gains))


def calibrate(campaign: Campaign, physics: Path, folder: Path, out: io.StringIO) -> Path:
    """What ``swerve calibrate --emulate --yes --lockstep --write`` does, on a copy of the
    campaign's robot file, with the emulated robot built from the original and ``physics``;
    returns the calibrated copy. Progress lines go to ``out``."""
    robot = Path(shutil.copyfile(campaign.robot, folder / "robot.yaml"))
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        values = calibrate_emulated(load_robot_config(robot), campaign.robot, emulator_config=physics,
                                    lockstep=True, distance_m=campaign.calibration_distance_m,
                                    log=lambda msg: print(msg, file=out))
    values.pop("radius_facts", None)
    write_robot_file(robot, **values)
    return robot


def run_scenario(campaign: Campaign, index: int, log: Path | None = None) -> Outcome:
    """Run scenario ``index`` and return its :class:`Outcome` (a refused or broken scenario is a
    ``failed`` row; a stop signal propagates)."""
    t0 = time.monotonic()
    sc = scenario(campaign, index)
    cell = sc.cell
    row = base_row(campaign, sc)
    stage = "setup"
    with tempfile.TemporaryDirectory(prefix=f"swerve-scenario-{index}-") as tmp:
        folder = Path(tmp)
        try:
            physics = physics_file(campaign, sc, folder)
            config = campaign.robot
            if cell.calibrate:
                stage = "calibration"
                config = calibrate(campaign, physics, folder, io.StringIO())
                row.update(_calibration(config))
            stage = "gains"
            gains = _gains(campaign, cell, config, folder)
            stage = "run"
            faults = f"{cell.faults},seed={sc.robot.fault_seed}" if cell.faults and "seed=" not in cell.faults \
                else (cell.faults or None)
            result = run_tracking(RunRequest(
                trajectory=campaign.resolve(cell.trajectory), gains=gains, config=config, emulated_robot=campaign.robot,
                emulate=True, lockstep=True, time_scale=None, log=log, faults=faults,
                emulator_config=physics))
        except SwerveError as exc:
            row.update(status="failed", reason=f"{stage}: {exc}")
        except Exception as exc:  # noqa: BLE001 - a bug in one scenario is its row, the campaign goes on
            row.update(status="failed", reason=f"{stage}: {type(exc).__name__}: {exc}")
        else:
            s = result.summary.to_dict()
            row.update({k: s.get(k) for k in METRICS})
            if s.get("completed"):
                row.update(status="completed", reason="")
            else:
                row.update(status="stopped", reason=s.get("abort_message") or s.get("abort_cause") or "")
    return Outcome(index, {k: text(v) for k, v in row.items()}, time.monotonic() - t0)


def _calibration(robot: Path) -> dict:
    cfg = load_robot_config(robot)
    out = {f"calibrated_center_pulse[{w}]": wc.center_pulse for w, wc in enumerate(cfg.wheels)}
    out["calibrated_wheel_radius_m"] = cfg.wheel_radius_m
    return out


__all__ = ["CALIBRATION", "METRICS", "Outcome", "STATUSES", "Scenario", "base_row", "columns", "run_scenario", "scenario",
           "text"]
