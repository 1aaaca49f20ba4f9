"""Two programs on one port: the second is refused with one line naming the port.

A first process opens a pty through :class:`swerve.driver.transport.Transport` (which takes the
port's exclusive lock) and holds it; every command that opens a serial port then runs on the
same pty in a second process and must exit 2 with a one-line error naming the port, without
writing a byte to the bus.
"""
from __future__ import annotations

import os
import select
import subprocess
import sys

import pytest

from swerve.driver.errors import PortInUseError
from swerve.driver.transport import Transport

HOLDER = """
import sys
from swerve.driver.transport import Transport
t = Transport(sys.argv[1], 1_000_000)
print("locked", flush=True)
sys.stdin.read()
t.close()
"""

#: Every command that opens a serial port, with the arguments that point it at ``{port}``.
COMMANDS = {
    "scan": ["scan", "--port", "{port}", "--ids", "1-2"],
    "doctor": ["doctor", "--port", "{port}"],
    "run": ["run", "--trajectory", "line", "--port", "{port}"],
    "calibrate": ["calibrate", "--port", "{port}", "--yes"],
    "tune": ["tune", "--port", "{port}", "--id", "1", "--mode", "drive"],
}


@pytest.fixture
def held_pty():
    """A pty whose slave is opened and locked by another process; yields ``(path, master_fd)``."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, path], stdin=subprocess.PIPE,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        yield path, master
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
        os.close(master)
        os.close(slave)


def _drain(fd: int) -> bytes:
    out = b""
    while select.select([fd], [], [], 0)[0]:
        try:
            chunk = os.read(fd, 4096)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    return out


def test_transport_second_open_in_process_is_refused(held_pty):
    path, _ = held_pty
    with pytest.raises(PortInUseError, match=f"serial port {path} is in use by another program") as err:
        Transport(path, 1_000_000)
    assert err.value.port == path


def test_lock_is_released_on_close():
    master, slave = os.openpty()
    path = os.ttyname(slave)
    try:
        first = Transport(path, 1_000_000)
        first.close()
        second = Transport(path, 1_000_000)
        second.close()
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("command", sorted(COMMANDS), ids=sorted(COMMANDS))
def test_second_program_on_a_held_port_gets_one_line(held_pty, command, tmp_path):
    path, master = held_pty
    argv = [a.format(port=path) for a in COMMANDS[command]]
    env = {k: v for k, v in os.environ.items() if k != "SWERVE_CONFIG"}
    proc = subprocess.run([sys.executable, "-m", "swerve.tools.cli", *argv], capture_output=True,
                          text=True, timeout=120, cwd=tmp_path, env=env)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1, proc.stderr
    assert path in lines[0] and "in use by another program" in lines[0]
    assert _drain(master) == b"", "the refused program wrote to the bus"
    assert not any(tmp_path.iterdir()), "the refused program left files behind"
