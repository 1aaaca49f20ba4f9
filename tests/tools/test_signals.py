"""SIGTERM, SIGHUP and SIGINT stop a command the way Ctrl-C does: wheels to zero, torque off, log closed.

The end-to-end tests run the real ``swerve`` command in subprocesses: ``swerve emulate
--physics`` serves the robot, ``swerve run --port`` drives it, the test signals the run, then
reads Torque Enable of all eight servos back through its own :class:`~swerve.driver.bus.Bus`.
Waits are hang guards only; no verdict depends on how fast the machine is.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import load_robot_config
from swerve.tools.signals import Interrupted, safe_stop, signals_as_interrupt

ROOT = Path(__file__).resolve().parents[2]
CLI = [sys.executable, "-m", "swerve.tools.cli"]
#: Robot seconds per wall second for the end-to-end runs.
SCALE = "1"


# --- the mechanism, in this process --------------------------------------------------------------

@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_raises_interrupted_with_its_exit_code(sig):
    with pytest.raises(Interrupted) as info:
        with signals_as_interrupt():
            os.kill(os.getpid(), sig)
            for _ in range(1000):          # the handler runs between bytecodes of the main thread
                time.sleep(0.001)
    assert info.value.signum == sig and info.value.exit_code == 128 + sig
    assert isinstance(info.value, KeyboardInterrupt)


def test_a_second_signal_does_not_interrupt_the_clean_up():
    done = []
    with pytest.raises(Interrupted) as info:
        with signals_as_interrupt():
            try:
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(1000):
                    time.sleep(0.001)
            finally:
                os.kill(os.getpid(), signal.SIGINT)     # a second Ctrl-C during the safe stop
                for _ in range(50):
                    time.sleep(0.001)
                done.append("torque off")
    assert info.value.signum == signal.SIGTERM and done == ["torque off"]


def test_a_first_signal_during_a_safe_stop_waits_for_its_end():
    steps = []
    with pytest.raises(Interrupted):
        with signals_as_interrupt():
            with safe_stop():
                os.kill(os.getpid(), signal.SIGTERM)
                for _ in range(50):
                    time.sleep(0.001)
                steps.append("torque off")
            steps.append("after")                         # not reached: the held signal is raised
    assert steps == ["torque off"]


# --- end to end ----------------------------------------------------------------------------------

@pytest.fixture
def robot_file(tmp_path) -> Path:
    """The shipped robot with a 1 s Bus Watchdog and 50 missed replies allowed (the test is about
    signals: a loaded machine's hiccups must not end the run first)."""
    import yaml

    doc = yaml.safe_load((ROOT / "configs" / "robot.yaml").read_text())
    doc["safety"]["bus_watchdog_s"] = 1.0
    doc["safety"]["max_consecutive_timeouts"] = 50
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(doc))
    return path


@pytest.fixture
def emulator(robot_file):
    """``(port, process)`` of a ``swerve emulate --physics`` serving the robot file."""
    proc = subprocess.Popen([*CLI, "emulate", "--physics", "--config", str(robot_file), "--time-scale", SCALE,
                             "--clock-hz", "1000"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        words = proc.stdout.readline().split()
        assert words and words[0] == "PORT", proc.stderr.read()
        yield words[1], proc
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


def _torque_enable(port: str, robot_file: Path) -> dict[int, int]:
    cfg = load_robot_config(robot_file)
    ids = [*cfg.drive_ids, *cfg.steer_ids]
    with Bus(port, cfg.link.baud, retries=3, timeout_margin_s=0.5) as bus:
        return {i: bus.read(i, Reg.TORQUE_ENABLE) for i in ids}


def _start_run(port: str, robot_file: Path, log: Path) -> subprocess.Popen:
    proc = subprocess.Popen([*CLI, "run", "--trajectory", "line", "--port", port, "--config", str(robot_file),
                             "--time-scale", SCALE, "--timeout-margin-ms", "50", "--log", str(log)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    first = proc.stdout.readline()
    assert first.startswith("config:"), proc.stderr.read()
    deadline = time.monotonic() + 60                # hang guard: wait for the loop to be logging
    mcap = log / f"{log.name}.mcap"
    while time.monotonic() < deadline and proc.poll() is None and not mcap.exists():
        time.sleep(0.05)
    time.sleep(3.0)                                 # into the loop (the line takes 40 s at 1x)
    assert proc.poll() is None, proc.stderr.read()
    return proc


@pytest.mark.slow
@pytest.mark.parametrize("sigs", [(signal.SIGINT,), (signal.SIGTERM,), (signal.SIGHUP,),
                                  (signal.SIGTERM, signal.SIGINT)],
                         ids=["SIGINT", "SIGTERM", "SIGHUP", "SIGTERM-then-SIGINT"])
def test_a_signal_stops_swerve_run_with_the_torque_off_and_the_log_closed(sigs, emulator, robot_file, tmp_path):
    port, _ = emulator
    log = tmp_path / "log"
    run = _start_run(port, robot_file, log)
    try:
        for s in sigs:
            run.send_signal(s)
            time.sleep(0.02)
        rc = run.wait(timeout=60)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    err = run.stderr.read().strip().splitlines()
    assert rc == 128 + sigs[0], err
    assert err[-1] == f"swerve run: stopped by {signal.Signals(sigs[0]).name}"
    assert not any("Traceback" in line for line in err)
    assert set(_torque_enable(port, robot_file).values()) == {0}
    out = subprocess.run([*CLI, "export-csv", str(log), "--out", str(tmp_path / "run.csv")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stderr == ""                           # closed cleanly: no recovery note
    rows = (tmp_path / "run.csv").read_text().splitlines()
    assert len(rows) > 10


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_swerve_emulate_exits_cleanly_on_each_stop_signal(sig):
    proc = subprocess.Popen([*CLI, "emulate", "--frozen", "--ids", "1"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("PORT ")
        proc.send_signal(sig)
        assert proc.wait(timeout=30) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert "Traceback" not in proc.stderr.read()
