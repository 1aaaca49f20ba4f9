"""Shared test options and fixtures.

``--port PORT`` runs the hardware-capable tests against a real bus (U2D2) instead of the
emulator; ``--baud`` sets its baud rate. Without ``--port`` those tests use the emulator on a pty.
"""
import os
import platform
import shutil
import subprocess
import sys
import tempfile

import pytest


def pytest_configure(config):
    """Every test (and every command it starts) writes its caches into a fresh folder, never the
    user's ``~/.cache/swerve``: a verdict must not depend on what an earlier run left there."""
    config.swerve_cache_home = os.environ["XDG_CACHE_HOME"] = tempfile.mkdtemp(prefix="swerve-test-cache-")


def pytest_unconfigure(config):
    shutil.rmtree(config.swerve_cache_home, ignore_errors=True)


def pytest_addoption(parser):
    parser.addoption("--port", default=None, help="real Dynamixel bus (e.g. /dev/ttyUSB0); default: emulator")
    parser.addoption("--baud", default=1_000_000, type=int, help="baud rate for --port")


def pytest_collection_modifyitems(items):
    """Tests marked ``slow`` run first (in their collected order, as the rest): with ``-n`` the
    workers start the long tests early and finish together, instead of one worker running a
    long test alone at the end. The order is the same in every worker, as pytest-xdist needs."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)


@pytest.fixture(scope="session")
def hw_port(request):
    """The real port given with --port, or None."""
    return request.config.getoption("--port")


@pytest.fixture(scope="session")
def hw_baud(request):
    return request.config.getoption("--baud")


def _cpu_flags() -> set[str]:
    """The CPU's feature flags from ``/proc/cpuinfo`` (empty where there is none)."""
    try:
        with open("/proc/cpuinfo") as f:
            return next((set(line.split(":", 1)[1].split()) for line in f if line.startswith("flags")), set())
    except OSError:
        return set()


@pytest.fixture(scope="session")
def other_cpu():
    """``run(env, *args) -> stdout``: ``python *args`` in a subprocess whose environment adds ``env``,
    to make NumPy take another CPU's code paths: ``OPENBLAS_CORETYPE=Nehalem`` (kernels without FMA) or
    ``Haswell`` (with FMA), ``NPY_DISABLE_CPU_FEATURES`` (NumPy's own SIMD loops). Skips the test unless
    the CPU is x86-64 with AVX2 and FMA, which both kernels need."""
    if platform.machine() != "x86_64" or not {"avx2", "fma"} <= _cpu_flags():
        pytest.skip("imitates other x86-64 CPUs (the Haswell kernels need AVX2 and FMA)")

    def run(env: dict[str, str], *args: str) -> str:
        return subprocess.run([sys.executable, *args], env={**os.environ, **env}, capture_output=True,
                              text=True, check=True, timeout=600).stdout

    return run
