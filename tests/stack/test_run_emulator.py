"""The full stack over a real pty against the emulated robot (issue 6).

Each test runs the 62.5 Hz loop through the project's driver against the emulator in its own
process, time-scaled. Error bounds are absolute allowances on top of the ideal-model simulation
(``swerve sim``), whose errors are ~0 mm on these paths: the emulated robot has servo lag,
encoder quantisation and bus latency that model (1)-(5) does not (see README, "Full stack").

Time scale: ``SWERVE_TEST_TIME_SCALE`` (default 5, as the issue asks); BENCHMARKS.md has the
largest scale at which every deadline is met on the reference machine. Overruns on a loaded
machine are counted in the summary, not failures. Under a time scale the run stretches the Bus
Watchdog and the failed-read limit to their wall-clock length (``swerve.tools.run.orchestrate.
wall_clock_guards``); the tests' copy of ``configs/robot.yaml`` also raises the watchdog from
0.1 s to 0.25 s, so one scheduling hiccup of a loaded CI machine is not taken for a dead
controller.
"""
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from swerve.driver.robot_config import load_robot_config
from swerve.tools.run.orchestrate import RunRequest, run_tracking, wall_clock_guards

#: Time scale of the stack tests (the issue asks for >= 5; see BENCHMARKS.md for the limit).
SCALE = float(os.environ.get("SWERVE_TEST_TIME_SCALE", "5"))
#: Tracking allowance above the ideal simulation, m (servo lag, quantisation, latency).
ALLOWANCE_M = 0.03
#: Odometry vs true pose over a whole run, m (stated bound, README).
ODOMETRY_BOUND_M = 0.03

pytestmark = pytest.mark.slow

#: Bus Watchdog of the test config, s (robot time at 1x; the run stretches it by SCALE).
WATCHDOG_S = 0.25


@pytest.fixture(scope="module")
def config(tmp_path_factory) -> Path:
    import yaml

    doc = yaml.safe_load(Path("configs/robot.yaml").read_text())
    doc["safety"]["bus_watchdog_s"] = WATCHDOG_S
    path = tmp_path_factory.mktemp("cfg") / "robot.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


def sim_summary(name: str) -> dict:
    out = subprocess.run([sys.executable, "-m", "swerve.tools.cli", "sim", "--trajectory", name, "--json"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


@pytest.mark.parametrize("name", ["line", "circle"])
def test_tracks_paper_trajectory_on_the_emulator(name, tmp_path, config):
    sim = sim_summary(name)
    res = run_tracking(RunRequest(trajectory=name, emulate=True, time_scale=SCALE, log=tmp_path / "log",
                                  config=config))
    s = res.summary.to_dict()
    assert res.aborted is None, s.get("abort_message")
    assert s["completed"] and s["error_source"] == "true_pose"
    for key in ("final_position_error_m", "rms_position_error_m", "max_position_error_m"):
        assert s[key] <= 2 * sim[key] + ALLOWANCE_M, (key, s[key], sim[key])
    assert s["odometry_vs_true_max_m"] <= ODOMETRY_BOUND_M
    assert s["max_abs_v1_mps"] <= 0.13 + 1e-9
    for key in ("loop_period_p50_ms", "loop_period_p99_ms", "overruns", "missed_slots"):
        assert key in s
    assert s["loop_period_p50_ms"] == pytest.approx(16.0 / SCALE, rel=0.2)

    from swerve.tools.logs.bag import read_log
    log = read_log(tmp_path / "log")
    assert log.clean and len(log) == s["cycles"]
    assert np.all(np.isfinite(log.true_pose)) and np.all(np.isfinite(log.est_pose))


def test_two_percent_dropped_replies_completes_with_drops_counted(config):
    res = run_tracking(RunRequest(trajectory="line", emulate=True, time_scale=SCALE,
                                  faults="drop=0.02,seed=3", log=None, config=config))
    s = res.summary.to_dict()
    assert res.aborted is None, s.get("abort_message")
    assert s["emulator_replies_dropped"] > 0 and s["failed_reads"] > 0
    assert s["final_position_error_m"] <= ALLOWANCE_M + 0.02


def test_vanishing_servo_stops_cleanly_naming_it(tmp_path, monkeypatch, config):
    """A steering servo disappears mid-run: the loop stops, naming servo 7."""
    import swerve.emulator.process as proc

    started = {}
    real_start = proc.EmulatorProcess.start

    def start(self):
        started["emu"] = self
        return real_start(self)

    monkeypatch.setattr(proc.EmulatorProcess, "start", start)

    from swerve.tools.run import loop as online

    real_read = online.TrackingLoop._read

    def read(self):
        if getattr(self, "_n", 0) == 100:
            started["emu"].fault("vanish", 7)
        self._n = getattr(self, "_n", 0) + 1
        return real_read(self)

    monkeypatch.setattr(online.TrackingLoop, "_read", read)
    res = run_tracking(RunRequest(trajectory="line", emulate=True, time_scale=SCALE, log=tmp_path / "log",
                                  config=config))
    assert res.aborted is not None and res.aborted.cause == "no reply"
    assert 7 in res.aborted.ids and "servo ID" in str(res.aborted) and "7" in str(res.aborted)
    from swerve.tools.logs.bag import read_log
    assert len(read_log(tmp_path / "log")) == res.summary.cycles


def _start_emulator(tmp_path: Path, config: Path):
    status = tmp_path / "status.json"
    emu = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "emulate", "--config", str(config),
                            "--physics", "--clock-hz", "1000", "--time-scale", str(SCALE),
                            "--status-file", str(status)],
                           stdout=subprocess.PIPE, text=True)
    from swerve.tools.commands.emulate import parse_port_line

    port, _baud, _ids = parse_port_line(emu.stdout.readline())
    return emu, port, status


def _wait_for(predicate, timeout_s: float):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.05)
    return False


def _status(status: Path) -> dict | None:
    try:
        return json.loads(status.read_text())
    except (OSError, ValueError):
        return None


def _max_wheel_speed(doc: dict | None) -> float:
    return max(abs(w["speed_mps"]) for w in doc["wheels"]) if doc else float("nan")


def test_killed_controller_lets_the_watchdog_stop_the_wheels(tmp_path, config):
    emu, port, status = _start_emulator(tmp_path, config)
    try:
        ctl = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "run", "--trajectory", "line", "--config", str(config),
                                "--port", port, "--time-scale", str(SCALE), "--timeout-margin-ms", "50",
                                "--no-log"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        assert _wait_for(lambda: _max_wheel_speed(_status(status)) > 0.02, 120), "robot never moved"
        ctl.kill()                                   # SIGKILL: no cleanup in the controller at all
        ctl.wait(timeout=30)
        killed_sim_s = _status(status)["t_s"]       # robot time, at most one status period late
        stopped = []

        def wheels_stopped() -> bool:
            doc = _status(status)
            if doc is not None and _max_wheel_speed(doc) < 0.005:
                stopped.append(doc["t_s"])
            return bool(stopped)

        assert _wait_for(wheels_stopped, 30), _status(status)
        # in robot time: the (stretched) Bus Watchdog, the servos' deceleration, one status period
        watchdog = wall_clock_guards(load_robot_config(config), SCALE).bus_watchdog_s
        assert stopped[0] - killed_sim_s < watchdog + 1.0, (stopped[0], killed_sim_s, watchdog)
    finally:
        emu.send_signal(signal.SIGTERM)
        emu.wait(timeout=30)


def test_ctrl_c_turns_torque_off_and_keeps_the_log(tmp_path, config):
    from swerve.driver.bus import Bus
    from swerve.driver.control_table import Reg
    from swerve.tools.logs.bag import read_log

    emu, port, status = _start_emulator(tmp_path, config)
    log = tmp_path / "log"
    try:
        ctl = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "run", "--trajectory", "circle", "--config", str(config),
                                "--port", port, "--time-scale", str(SCALE), "--timeout-margin-ms", "50",
                                "--log", str(log)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert _wait_for(lambda: _max_wheel_speed(_status(status)) > 0.02, 120), "robot never moved"
        time.sleep(1.0)                              # let the run log a few dozen cycles
        ctl.send_signal(signal.SIGINT)
        out, err = ctl.communicate(timeout=60)
        assert ctl.returncode == 130, err
        with Bus(port, 1_000_000, timeout_margin_s=0.3) as bus:
            torque = bus.sync_read(list(range(1, 9)), Reg.TORQUE_ENABLE)
        assert all(v[Reg.TORQUE_ENABLE] == 0 for v in torque.values())
        run_log = read_log(log)
        assert run_log.clean and len(run_log) > 10
    finally:
        emu.send_signal(signal.SIGTERM)
        emu.wait(timeout=30)
