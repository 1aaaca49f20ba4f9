"""``swerve demo``'s calibration story: a run with the robot file as it is, calibration of the
emulated robot, a run with the calibrated file on the same emulated robot, and the summary."""
from __future__ import annotations

from pathlib import Path

import pytest

from swerve.configs import shipped
from swerve.driver.robot_config import load_robot_config
from swerve.tools.cli import main
from swerve.tools.commands.demo import calibration_table
from swerve.tools.demo.plan import Calibration, DemoRow


def _row(name: str, robot: str, rms_m: float) -> DemoRow:
    return DemoRow(name, robot, {}, {"rms_position_error_m": rms_m, "completed": True}, [], Path("g"), Path("l"))


def test_calibration_table_shows_the_values_found_and_what_each_run_recovered():
    cal = Calibration(values={"center_pulse": [2055, 2031, 2065, 2047], "drive_direction": [1, 1, -1, -1],
                              "steer_direction": [1, 1, 1, 1], "wheel_radius_m": 0.033058},
                      before={"center_pulse": [2048] * 4, "drive_direction": [1, 1, -1, -1],
                              "steer_direction": [1, 1, 1, 1], "wheel_radius_m": 0.033},
                      path=Path("robot-calibrated.yaml"))
    rows = [_row("line", "as is", 0.0369), _row("circle", "as is", 0.2017),
            _row("line", "calibrated", 0.0232), _row("circle", "calibrated", 0.0791)]
    text = calibration_table(cal, rows)
    assert "| steering centres, pulse | [2048, 2048, 2048, 2048] | [2055, 2031, 2065, 2047] |" in text
    assert "| wheel radius, mm | 33.000 | 33.058 |" in text
    assert "| line | 36.9 | 23.2 | 13.7 |" in text
    assert "| circle | 201.7 | 79.1 | 122.6 |" in text


@pytest.mark.slow
def test_demo_runs_before_and_after_calibrating_the_realistic_robot(tmp_path, capsys):
    out = tmp_path / "demo"
    assert main(["demo", "--trajectories", "line", "--out", str(out)]) == 0
    summary = (out / "summary.md").read_text()
    cells = [[c.strip() for c in line.split("|")[1:-1]] for line in summary.splitlines()
             if line.startswith("| line |")]
    rows = {c[1]: c for c in cells if len(c) == 12}                    # the run table's rows
    assert set(rows) == {"as is", "calibrated"}
    rms = {k: float(c[5]) for k, c in rows.items()}                      # emu rms, mm
    assert rms["calibrated"] < rms["as is"]
    # lockstep: the numbers of a demo that runs its tasks one by one, whatever ran in parallel
    assert rms == {"as is": 36.9, "calibrated": 23.2}
    assert "## What calibration recovered" in summary
    calibrated = load_robot_config(out / "robot-calibrated.yaml")
    shipped_cfg = load_robot_config(shipped("robot.yaml"))
    assert [w.center_pulse for w in calibrated.wheels] != [w.center_pulse for w in shipped_cfg.wheels]
    assert calibrated.wheel_radius_m != shipped_cfg.wheel_radius_m
    assert (out / "logs" / "line").is_dir() and (out / "logs" / "line-calibrated").is_dir()
    assert (out / "gains" / "line-calibrated.npz").is_file()
