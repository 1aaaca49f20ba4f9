"""``--emulator-config`` takes a profile name or a file, on every command that starts an emulator."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import HardwareError, Reg
from swerve.tools.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("argv", [
    ["run", "--emulate", "--trajectory", "line", "--no-log", "--emulator-config", "realstic"],
    ["emulate", "--emulator-config", "realstic"],
    ["demo", "--emulator-config", "realstic", "--trajectories", "line"],
], ids=["run", "emulate", "demo"])
def test_unknown_profile_is_a_one_line_error(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].endswith("emulator config 'realstic': no such file and not a profile (ideal, realistic)")


def test_emulator_config_without_emulate_is_refused(capsys):
    assert main(["run", "--trajectory", "line", "--no-log", "--emulator-config", "realistic"]) == 2
    assert "--emulator-config needs --emulate" in capsys.readouterr().err


@pytest.mark.parametrize("profile, alert", [("ideal", 0), ("realistic", HardwareError.INPUT_VOLTAGE)])
def test_emulate_serves_the_named_profile(profile, alert):
    """``swerve emulate --emulator-config NAME``: only the realistic world has a battery that
    sags (11.95 V idle) and a firmware that flags it against a 12.0 V Min Voltage Limit."""
    proc = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "emulate", "--physics",
                             "--emulator-config", profile, "--time-scale", "1"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        port = proc.stdout.readline().split()[1]
        with Bus(port, 1_000_000, timeout_margin_s=1.0) as bus:
            bus.write(1, Reg.MIN_VOLTAGE_LIMIT, 120)
            deadline = time.monotonic() + 10.0
            while bus.hardware_error(1) != alert and time.monotonic() < deadline:
                time.sleep(0.05)
            time.sleep(0.2)                        # ideal: still nothing after a few physics steps
            assert bus.hardware_error(1) == alert
    finally:
        proc.terminate()
        proc.wait(timeout=30)
