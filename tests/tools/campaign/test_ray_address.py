"""``--ray ADDRESS`` that nothing answers at: one line, exit 2, no results folder, no wait.

The address is a closed port on this machine's loopback (nothing is started), and malformed
addresses are refused before any connection is tried.
"""
from __future__ import annotations

import socket
import subprocess
import sys

import pytest

from swerve.core.errors import ConfigError
from swerve.tools.campaign.engines import check_reachable

pytest.importorskip("ray")


def _closed_port() -> int:
    with socket.socket() as s:                # a port the kernel just gave out and nobody listens on
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.parametrize("text", ["nonsense", "host:", ":6379", "host:0", "host:70000", "host:12a"])
def test_malformed_addresses_are_refused(text):
    with pytest.raises(ConfigError, match="expected auto or HOST:PORT"):
        check_reachable(text)


def test_an_unreachable_cluster_is_one_line_and_leaves_no_folder(tmp_path):
    out = tmp_path / "results"
    address = f"127.0.0.1:{_closed_port()}"
    proc = subprocess.run([sys.executable, "-m", "swerve.tools.cli", "campaign", "run", "smoke",
                           "--out", str(out), "--ray", address],
                          capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(lines) == 1 and address in lines[0] and "no Ray cluster answers" in lines[0], proc.stderr
    assert not out.exists()
