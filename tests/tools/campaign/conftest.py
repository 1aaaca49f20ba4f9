"""Fixtures of the campaign tests: a tiny campaign file and ``swerve campaign run`` in a subprocess."""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from swerve.configs import shipped

#: A campaign of two short scenarios on one robot: one that completes, and one whose steering
#: servo reports an overload at start (the run refuses it: a ``failed`` row).
TINY = """\
name: tiny
seed: 7
samples: 1
trajectories: [{traj}]
profiles: [realistic]
faults: ["", "hwerror=3:overload"]
parameters:
  tolerances.wheel_radius_scale: {{dist: normal, mean: 1.0, std: 0.01, min: 0.97, max: 1.03, wheels: each}}
  contact.friction_coefficient: {{dist: choice, values: [0.6, 0.8]}}
"""


@pytest.fixture(scope="session")
def tiny_file(tmp_path_factory) -> Path:
    """The path of the tiny campaign file (a short line, two scenarios)."""
    path = tmp_path_factory.mktemp("tiny") / "tiny.yaml"
    path.write_text(TINY.format(traj=shipped("campaigns/trajectories/line-6s.yaml")))
    return path


def campaign_cmd(*args: str) -> list[str]:
    """The argv of ``swerve campaign ARGS`` run by this interpreter."""
    return [sys.executable, "-m", "swerve.tools.cli", "campaign", *args]


def run_campaign(*args: str, timeout: float = 400, check: bool = True) -> subprocess.CompletedProcess:
    """``swerve campaign ARGS`` in a subprocess; asserts exit 0 unless ``check`` is False."""
    proc = subprocess.run(campaign_cmd(*args), capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "PYTHONHASHSEED": "0"})
    if check:
        assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


@pytest.fixture(scope="session")
def tiny_pool(tiny_file, tmp_path_factory) -> bytes:
    """results.csv of the tiny campaign on the process pool with one worker."""
    out = tmp_path_factory.mktemp("tiny-pool") / "out"
    run_campaign("run", str(tiny_file), "--out", str(out), "--workers", "1", "--no-plots")
    return (out / "results.csv").read_bytes()


@pytest.fixture(scope="session")
def smoke_pool(tmp_path_factory) -> Path:
    """The results folder of the shipped smoke campaign on the process pool (two workers)."""
    out = tmp_path_factory.mktemp("smoke-pool") / "out"
    run_campaign("run", "smoke", "--out", str(out), "--workers", "2")
    return out
