"""``swerve calibrate`` against an emulated robot whose truth differs from its robot file.

The emulator is built from a "true" robot file (steering centres off by up to 30 pulses, wheel
radius 34.5 mm instead of 33 mm, one drive sign flipped); calibration starts from the shipped
file and must find the truth from what the operator sees (``--yes`` on the emulator).
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import DEFAULT_PATH, load_robot_config
from swerve.tools import calibrate as cal
from swerve.tools.cli import main

TRUE_CENTERS = [2078, 2020, 2061, 2035]
TRUE_RADIUS_M = 0.0345


def _robot_copy(tmp_path: Path, name: str, watchdog_s: float = 0.25, **values) -> Path:
    path = tmp_path / name
    # As in the stack tests, the guards against a dead host ride out a loaded CI machine's stalls.
    text = (DEFAULT_PATH.read_text().replace("bus_watchdog_s: 0.1 ", f"bus_watchdog_s: {watchdog_s}")
            .replace("max_consecutive_timeouts: 3", "max_consecutive_timeouts: 10"))
    path.write_text(cal.update_robot_text(text, **values) if values else text)
    return path


def test_update_keeps_every_other_byte_and_validates():
    text = DEFAULT_PATH.read_text()
    new = cal.update_robot_text(text, center_pulse=[2000, 2001, 2002, 2003], wheel_radius_m=0.0341,
                                drive_direction=[1, -1, -1, -1], steer_direction=[1, 1, -1, 1])
    changed = [(a, b) for a, b in zip(text.splitlines(), new.splitlines()) if a != b]
    assert len(changed) == 4 and len(new.splitlines()) == len(text.splitlines())
    assert "  wheel_radius_m: 0.0341   # not given in the paper" in new
    assert "  center_pulse: [2000, 2001, 2002, 2003]  # Present Position" in new
    doc = yaml.safe_load(new)
    assert doc["drive"]["direction"] == [1, -1, -1, -1] and doc["steering"]["direction"] == [1, 1, -1, 1]
    with pytest.raises(ConfigError, match="center_pulse"):
        cal.update_robot_text(text, center_pulse=[5000, 0, 0, 0])


def test_write_is_atomic_and_refuses_bad_values(tmp_path):
    path = _robot_copy(tmp_path, "robot.yaml")
    before = path.read_text()
    with pytest.raises(ConfigError):
        cal.write_robot_file(path, wheel_radius_m=-1.0)
    assert path.read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["robot.yaml"]
    cal.write_robot_file(path, wheel_radius_m=0.034)
    assert load_robot_config(path).wheel_radius_m == 0.034


def test_write_refuses_the_shipped_robot_file(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("SWERVE_CONFIG", raising=False)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))          # no user robot file either
    assert main(["calibrate", "--emulate", "--yes", "--write"]) == 2
    assert "will not edit the shipped robot file" in capsys.readouterr().err


@pytest.mark.slow
def test_calibration_finds_the_truth_and_improves_tracking(tmp_path, capsys):
    truth = _robot_copy(tmp_path, "truth.yaml", center_pulse=TRUE_CENTERS, wheel_radius_m=TRUE_RADIUS_M)
    work = _robot_copy(tmp_path, "robot.yaml", drive_direction=[1, 1, 1, -1])   # rear_right sign wrong
    assert main(["calibrate", "--emulate", "--emulated-robot", str(truth), "--config", str(work),
                 "--yes", "--write", "--lockstep", "--distance", "0.5"]) == 0
    err = capsys.readouterr().err
    assert "rear_right: drive direction -1 (flipped)" in err
    got = load_robot_config(work)
    assert [w.drive_direction for w in got.wheels] == [1, 1, -1, -1]
    assert [w.steer_direction for w in got.wheels] == [1, 1, 1, 1]
    for c, t in zip((w.center_pulse for w in got.wheels), TRUE_CENTERS):
        assert abs(c - t) <= 2
    assert got.wheel_radius_m == pytest.approx(TRUE_RADIUS_M, rel=0.005)
    print(f"calibrated centres {[w.center_pulse for w in got.wheels]} (truth {TRUE_CENTERS}), "
          f"radius {got.wheel_radius_m * 1e3:.3f} mm (truth {TRUE_RADIUS_M * 1e3:.1f} mm)")

    # Track the circle on the true robot with the shipped file, then with the calibrated one, in
    # lockstep: robot time is the emulator's, so both runs give the same numbers on any machine.
    from swerve.tools.run.orchestrate import RunRequest, run_tracking

    before = _robot_copy(tmp_path, "before.yaml")
    results = {name: run_tracking(RunRequest(trajectory="circle", config=cfg, emulate=True, lockstep=True,
                                             time_scale=None, emulated_robot=truth))
               for name, cfg in (("before", before), ("after", work))}
    errors = {name: (r.summary.tracking.rms_position_error_m, r.summary.tracking.max_position_error_m)
              for name, r in results.items()}
    print(f"circle vs true pose, rms/max m: before {errors['before']} "
          f"(completed: {results['before'].summary.completed}), after {errors['after']}; wall s: "
          f"{[round(r.summary.wall_time_s, 1) for r in results.values()]}")
    after = results["after"]
    assert after.aborted is None, after.summary.abort_message   # before may stop: it cannot follow
    assert all(r.summary.clock == "lockstep" for r in results.values())
    assert all(r.summary.tracking.error_source == "true_pose" for r in results.values())
    assert errors["after"][0] < 0.5 * errors["before"][0]
    assert errors["after"][1] < errors["before"][1]
    # lockstep makes calibration and both runs repeatable (measured: before 274.6 / 339.5 mm
    # rms / max, after 6.39 / 8.88 mm); the bounds leave room for round-off across platforms
    assert errors["after"][0] < 0.0066 and errors["after"][1] < 0.0092
    assert errors["before"][0] > 0.25


def test_lockstep_needs_the_emulator(capsys):
    assert main(["calibrate", "--lockstep", "--yes"]) == 2
    assert "--lockstep needs --emulate" in capsys.readouterr().err
