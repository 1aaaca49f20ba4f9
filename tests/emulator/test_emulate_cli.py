"""``swerve emulate`` as a subprocess: PORT line, SDK ping through the link, clean SIGTERM exit."""
from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.core.options import parse_ids
from swerve.tools.commands.emulate import format_ids, parse_port_line

from .conftest import TIMEOUT, SdkClient, answered

ROOT = Path(__file__).resolve().parents[2]


def _start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "emulate", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


@pytest.mark.slow
def test_emulate_serves_sdk_and_exits_cleanly(tmp_path):
    link = tmp_path / "dxl"
    proc = _start("--config", "configs/robot.yaml", "--ids", "1-3", "--link", str(link))
    try:
        line = proc.stdout.readline()
        first = line.split()
        assert first[0] == "PORT" and first[1].startswith("/dev/pts/")
        assert parse_port_line(line) == (first[1], 1_000_000, [1, 2, 3])
        assert proc.stdout.readline().split() == ["LINK", str(link)]
        assert link.resolve() == Path(first[1])
        sdk = SdkClient(str(link))
        try:       # a process just started may answer after the SDK's packet timeout on a loaded host
            assert [answered(sdk.ping, i) for i in (1, 2, 3)] == [(1010, 0)] * 3
            assert sdk.ping(4) == TIMEOUT
        finally:
            sdk.close()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
        assert not link.exists() and not link.is_symlink()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_sigint_exits_zero():
    proc = _start("--ids", "1")
    try:
        assert proc.stdout.readline().startswith("PORT /dev/pts/")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=20) == 0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@pytest.mark.parametrize("args, message", [
    (["--ids", "1-x"], "--ids"),
    (["--baud", "12345"], "baud"),
    (["--model", "xh999"], "unknown servo model"),
    (["--faults", "drop=7"], "drop_rate"),
], ids=["ids", "baud", "model", "faults"])
def test_bad_arguments_exit_2_with_one_line(args, message):
    proc = _start(*args)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2
    assert out == "" and len(err.strip().splitlines()) == 1 and message in err


def test_port_line_round_trips_ids():
    for ids in ([1], [1, 2, 3, 5], [2, 4, 5, 6, 9]):
        assert parse_ids(format_ids(ids), max_id=252) == ids
    assert parse_port_line("PORT /dev/pts/3 BAUD 57600 IDS 1-2,7\n") == ("/dev/pts/3", 57600, [1, 2, 7])
    with pytest.raises(ValueError):
        parse_port_line("PORT /dev/pts/3")


#: Generous: the emulator is a child process on a loaded machine; a timeout only ends a failing test.
DEADLINE_S = 30.0


def _spin(port: str, baud: int, id_: int, done):
    """Operating Mode 1 (velocity), torque on, Goal Velocity 100 through the driver's Bus; then
    ``(Realtime Tick ms, Present Velocity)`` samples until ``done(samples)`` (or the deadline)."""
    import time

    with Bus(port, baud, timeout_margin_s=1.0, retries=3) as bus:
        bus.write(id_, Reg.TORQUE_ENABLE, 0)
        bus.write(id_, Reg.OPERATING_MODE, 1)
        bus.write(id_, Reg.BUS_WATCHDOG, 0)
        bus.write(id_, Reg.TORQUE_ENABLE, 1)
        bus.write(id_, Reg.GOAL_VELOCITY, 100)
        samples = []
        deadline = time.monotonic() + DEADLINE_S
        while not (samples and done(samples)) and time.monotonic() < deadline:
            samples.append((bus.read(id_, Reg.REALTIME_TICK), bus.read(id_, Reg.PRESENT_VELOCITY)))
            time.sleep(0.01)
        return samples


def _elapsed_ms(samples) -> int:
    return (samples[-1][0] - samples[0][0]) % 32768     # Realtime Tick wraps at 32767 ms


def test_plain_emulate_servos_move_under_goal_velocity():
    """``swerve emulate --ids 1-2`` without flags: the servo's motor and velocity loop run."""
    proc = _start("--ids", "1-2")
    try:
        port, baud, ids = parse_port_line(proc.stdout.readline())
        assert ids == [1, 2]
        samples = _spin(port, baud, 2, lambda s: s[-1][1] >= 90)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
    assert samples[-1][1] >= 90                        # Goal Velocity 100 reached (90 %)


def test_frozen_emulate_servos_stay_put():
    """``--frozen``: a register-only bus; its clock ticks (Realtime Tick, watchdog) but Present
    Velocity stays 0 through 0.5 s of emulated time."""
    proc = _start("--ids", "1-2", "--frozen")
    try:
        port, baud, _ = parse_port_line(proc.stdout.readline())
        samples = _spin(port, baud, 2, lambda s: _elapsed_ms(s) >= 500)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
    assert _elapsed_ms(samples) >= 500
    assert {v for _, v in samples} == {0}


@pytest.mark.parametrize("model, number", [("xl330-m288", 1200), ("xm540-w270", 1120)])
def test_a_model_without_motor_data_is_served_register_only_with_a_notice(model, number):
    proc = _start("--model", model, "--ids", "1-2")
    try:
        port, baud, ids = parse_port_line(proc.stdout.readline())
        notice = proc.stderr.readline()
        with Bus(port, baud, timeout_margin_s=1.0) as bus:     # a wall bound: the emulator shares the CPU
            found = bus.ping(2)
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=20)
    assert proc.returncode == 0 and ids == [1, 2]
    assert notice.startswith(f"{model.upper()}: no motor data") and "control table only" in notice
    assert (found.model_number, found.model) == (number, model.upper())


def test_a_model_without_motor_data_refuses_the_robot_body(tmp_path):
    status = tmp_path / "status.json"
    proc = _start("--model", "xl430-w250", "--status-file", str(status))
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 2 and out == "" and not status.exists()
    assert len(err.strip().splitlines()) == 1 and "XL430-W250 has no motor data" in err
