"""The full stack over a real pty against the emulated robot.

Each test runs the 62.5 Hz loop through the project's driver against the emulator in its own
process. All but the process-level tests run in lockstep (the ``emulated_robot`` fixture of the
``swerve.testing`` plugin): the emulator owns robot time, each bus exchange costs its wire time,
and the run is the same on an idle or a loaded machine, so the error bounds are tight absolute
bounds on the emulated robot's errors (servo lag, encoder quantisation, odometry), measured at
a few mm. One tracking test stays on the wall clock (time-scaled, ``SWERVE_TEST_TIME_SCALE``,
default 2, where a whole run met every deadline on this 2-core machine) with the wall-clock allowance of 2x the ideal simulation + 3 cm, and skips (saying so)
when the host cannot run the emulator or the controller at that scale. A controller killed
mid-run is tested in lockstep (the test takes over robot time after the kill) and, as two
processes of the command line, on the wall clock; Ctrl-C and the other stop signals are tested
in ``tests/tools/test_signals.py``. Under a time scale the run stretches the Bus Watchdog
and the failed-read limit to their wall-clock length (``swerve.tools.run.orchestrate.
wall_clock_guards``); the wall-clock tests' copy of ``configs/robot.yaml`` also raises the
watchdog from 0.1 s to 0.25 s, so one scheduling hiccup of a loaded CI machine is not taken for
a dead controller.
"""
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import load_robot_config
from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepLoopClock
from swerve.tools.run.orchestrate import RunRequest, run_tracking, wall_clock_guards

#: Time scale of the wall-clock tests (see BENCHMARKS.md for the limit).
SCALE = float(os.environ.get("SWERVE_TEST_TIME_SCALE", "2"))
#: Wall clock: tracking allowance above the ideal simulation, m (servo lag, quantisation, latency).
ALLOWANCE_M = 0.03
#: Wall clock: odometry vs true pose over a whole run, m.
ODOMETRY_BOUND_M = 0.03
#: Lockstep: bounds on the emulated robot's position errors (rms, max, final), m. Measured on
#: this emulator: line 2.6 / 10.8 / 1.8 mm, circle 3.2 / 5.0 / 3.7 mm (the same on every machine;
#: the bounds leave 1-2 mm for changes to the physics model).
LOCKSTEP_BOUNDS_M = {"line": (0.004, 0.0125, 0.0035), "circle": (0.0045, 0.0065, 0.005)}
#: Lockstep: odometry vs true pose over a whole run, m (measured 1.7 mm line, 3.8 mm circle).
LOCKSTEP_ODOMETRY_BOUND_M = 0.005
#: Lockstep: slack on the bus's reply deadlines, wall s. The emulator is the bus's reply gate, so
#: a reply late on the wall clock is still waited for and the run's outcome does not depend on
#: this; it only sets how long a reply the emulator dropped on purpose keeps the loop waiting.
LOCKSTEP_MARGIN_S = 0.001

pytestmark = pytest.mark.slow

#: Bus Watchdog of the wall-clock test config, s (robot time at 1x; the run stretches it by SCALE).
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


def lockstep_run(robot, trajectory: str, **kw):
    """``run_tracking`` in lockstep against the ``emulated_robot`` fixture's emulator."""
    return run_tracking(RunRequest(trajectory=trajectory, port=robot.port, control=robot.control_path,
                                   lockstep=True, time_scale=None, **kw))


def _check_log(log_dir: Path, cycles: int) -> None:
    from swerve.tools.logs.bag import read_log
    log = read_log(log_dir)
    assert log.clean and len(log) == cycles
    assert np.all(np.isfinite(log.true_pose)) and np.all(np.isfinite(log.est_pose))


@pytest.mark.parametrize("name", ["line", "circle"])
def test_tracks_paper_trajectory_in_lockstep(name, tmp_path, emulated_robot):
    res = lockstep_run(emulated_robot, name, log=tmp_path / "log")
    s = res.summary.to_dict()
    print({k: s[k] for k in ("rms_position_error_m", "max_position_error_m", "final_position_error_m",
                             "odometry_vs_true_max_m", "real_time_factor")})
    assert res.aborted is None, s.get("abort_message")
    assert s["completed"] and s["error_source"] == "true_pose" and s["clock"] == "lockstep"
    rms, worst, final = LOCKSTEP_BOUNDS_M[name]
    assert s["rms_position_error_m"] <= rms
    assert s["max_position_error_m"] <= worst
    assert s["final_position_error_m"] <= final
    assert s["odometry_vs_true_max_m"] <= LOCKSTEP_ODOMETRY_BOUND_M
    assert s["max_abs_v1_mps"] <= 0.13 + 1e-9
    # robot time: every cycle fits its 16 ms slot (about 3 ms of bus time per cycle)
    assert s["overruns"] == 0 and s["missed_slots"] == 0
    assert s["loop_period_p50_ms"] == pytest.approx(16.0, abs=1e-9)
    assert s["loop_period_max_ms"] == pytest.approx(16.0, abs=1e-9)
    _check_log(tmp_path / "log", s["cycles"])


@pytest.mark.wallclock
def test_tracks_the_line_on_the_wall_clock(tmp_path, config):
    """The loop on the wall clock, time-scaled, against the emulator in its own process: the
    same tracking bounds as the simulation allows. Whether the host keeps up is not the code's
    doing, so this runs only when asked (``pytest -m wallclock``); the lockstep tests assert
    the tracking on robot time in every run."""
    sim = sim_summary("line")
    res = run_tracking(RunRequest(trajectory="line", emulate=True, time_scale=SCALE, log=tmp_path / "log",
                                  config=config))
    s = res.summary.to_dict()
    lost_s, achieved = s.get("emulator_lost_sim_s") or 0.0, s.get("emulator_achieved_time_scale") or 0.0
    if lost_s > 0 or achieved < 0.9 * SCALE:
        pytest.skip(f"the host could not run the emulator at {SCALE}x (achieved {achieved:.2f}x, lost "
                    f"{lost_s:.2f} s of robot time): a wall-clock run then measures the host, not the code "
                    f"(the lockstep tests do)")
    late = s["overruns"] + s["missed_slots"]
    if late > 0.02 * s["cycles"]:
        pytest.skip(f"the host could not run the controller at {SCALE}x ({s['overruns']} overruns, "
                    f"{s['missed_slots']} missed slots in {s['cycles']} cycles): a wall-clock run then "
                    f"measures the host, not the code (the lockstep tests do)")
    if s.get("abort_cause") == "diverged":
        pytest.skip(f"the wall-clock loop fell behind its reference ({s.get('abort_message')}): on a loaded "
                    f"host a wall-clock run measures the host, not the code (the lockstep tests assert the "
                    f"same tracking on robot time)")
    assert res.aborted is None, s.get("abort_message")
    assert s["completed"] and s["error_source"] == "true_pose" and s["clock"] == "wall"
    for key in ("final_position_error_m", "rms_position_error_m", "max_position_error_m"):
        assert s[key] <= 2 * sim[key] + ALLOWANCE_M, (key, s[key], sim[key])
    assert s["odometry_vs_true_max_m"] <= ODOMETRY_BOUND_M
    assert s["max_abs_v1_mps"] <= 0.13 + 1e-9
    for key in ("loop_period_p50_ms", "loop_period_p99_ms", "overruns", "missed_slots"):
        assert key in s
    assert s["loop_period_p50_ms"] == pytest.approx(16.0 / SCALE, rel=0.2)
    _check_log(tmp_path / "log", s["cycles"])


@pytest.mark.emulated_robot(faults="drop=0.02,seed=3")
def test_two_percent_dropped_replies_completes_with_drops_counted(emulated_robot):
    res = lockstep_run(emulated_robot, "line", log=None, timeout_margin_s=LOCKSTEP_MARGIN_S)
    s = res.summary.to_dict()
    assert res.aborted is None, s.get("abort_message")
    assert s["emulator_replies_dropped"] > 0 and s["failed_reads"] > 0
    assert s["final_position_error_m"] <= LOCKSTEP_BOUNDS_M["line"][2] + 0.005


def test_vanishing_servo_stops_cleanly_naming_it(tmp_path, monkeypatch, emulated_robot):
    """A steering servo disappears mid-run: the loop stops, naming servo 7."""
    from swerve.tools.run import loop as online

    real_read = online.TrackingLoop._read

    def read(self):
        if getattr(self, "_n", 0) == 100:
            emulated_robot.fault("vanish", 7)
        self._n = getattr(self, "_n", 0) + 1
        return real_read(self)

    monkeypatch.setattr(online.TrackingLoop, "_read", read)
    res = lockstep_run(emulated_robot, "line", log=tmp_path / "log", timeout_margin_s=LOCKSTEP_MARGIN_S)
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


#: A controller run in its own process against the ``emulated_robot`` fixture's emulator (the
#: same ``run_tracking`` as ``swerve run``), so the test can SIGKILL it.
_CONTROLLER = ("import sys\n"
               "from swerve.tools.run.orchestrate import RunRequest, run_tracking\n"
               "run_tracking(RunRequest(trajectory='line', port=sys.argv[1], control=sys.argv[2], lockstep=True,\n"
               "                        time_scale=None, log=None))\n")


def _robot_time_s(control_path: str) -> float:
    """Robot time asked on a connection of its own (``robot.clock`` keeps the last time it saw,
    since it assumes it is the only client moving time)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
        s.settimeout(60)
        s.connect(control_path)
        s.sendall(b"now 0\n")
        return float(s.makefile("rb").readline().split()[1])


def test_killed_controller_lets_the_watchdog_stop_the_robot_in_lockstep(emulated_robot):
    """A controller killed mid-run (SIGKILL: no clean-up at all) stops sending; in robot time,
    the robot file's Bus Watchdog then stops the wheels. Robot time stands still from the kill
    until the test advances it, so the bound is exact robot time on any host."""
    control = emulated_robot.control_path
    ctl = subprocess.Popen([sys.executable, "-c", _CONTROLLER, emulated_robot.port, control],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        assert _wait_for(lambda: ctl.poll() is not None or _robot_time_s(control) > 3.0, 300), "never got going"
        assert ctl.poll() is None, ctl.stderr.read()     # the line takes 40 s of robot time
    finally:
        ctl.kill()
        ctl.wait(timeout=30)
    watchdog = load_robot_config("configs/robot.yaml").bus_watchdog_s
    with LockstepLoopClock(control) as clock, Bus(emulated_robot.port, 1_000_000, default_model="xh430-w210",
                                                  timeout_margin_s=LOCKSTEP_TIMEOUT_MARGIN_S) as bus:
        clock.attach(bus)
        killed_s, moved = clock.now(), np.hypot(*clock.pose()[:2])
        assert moved > 0.05, moved                       # it was driving when killed
        clock.sleep_until(killed_s + watchdog + 1.0)     # the Bus Watchdog, the servos' deceleration
        before = np.array(clock.pose())
        clock.sleep_until(clock.now() + 0.5)
        drift = np.hypot(*(np.array(clock.pose()) - before)[:2])
        assert drift < 1e-3, drift                       # driving on, it would cover ~5 cm
        assert all(bus.read(i, Reg.BUS_WATCHDOG) == -1 for i in range(1, 9))    # tripped: reads -1


@pytest.mark.wallclock
def test_killed_controller_lets_the_watchdog_stop_the_wheels(tmp_path, config):
    """The same with ``swerve emulate`` and ``swerve run`` as processes, on the wall clock: the run
    only pauses a lockstep robot it does not own through ``--emulate``, so this one is time-scaled
    and its robot-time bound rides on the status file's wall-clock period (``pytest -m wallclock``)."""
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
