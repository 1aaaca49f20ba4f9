"""``swerve emulate`` as a subprocess: PORT line, SDK ping through the link, clean SIGTERM exit."""
from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _start(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "emulate", *args], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def test_emulate_serves_sdk_and_exits_cleanly(tmp_path):
    import dynamixel_sdk as sdk

    link = tmp_path / "dxl"
    proc = _start("--config", "configs/robot.yaml", "--ids", "1-3", "--link", str(link))
    try:
        first = proc.stdout.readline().split()
        assert first[0] == "PORT" and first[1].startswith("/dev/pts/")
        assert proc.stdout.readline().split() == ["LINK", str(link)]
        assert link.resolve() == Path(first[1])
        port, ph = sdk.PortHandler(str(link)), sdk.PacketHandler(2.0)
        assert port.openPort() and port.setBaudRate(1_000_000)
        try:
            for i in (1, 2, 3):
                model, result, err = ph.ping(port, i)
                assert (model, result, err) == (1010, sdk.COMM_SUCCESS, 0)
            assert ph.ping(port, 4)[1] == sdk.COMM_RX_TIMEOUT
        finally:
            port.closePort()
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
