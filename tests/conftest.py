"""Shared test options and fixtures.

``--port PORT`` runs the hardware-capable tests against a real bus (U2D2) instead of the
emulator; ``--baud`` sets its baud rate. Without ``--port`` those tests use the emulator on a pty.
"""
import pytest


def pytest_addoption(parser):
    parser.addoption("--port", default=None, help="real Dynamixel bus (e.g. /dev/ttyUSB0); default: emulator")
    parser.addoption("--baud", default=1_000_000, type=int, help="baud rate for --port")


@pytest.fixture(scope="session")
def hw_port(request):
    """The real port given with --port, or None."""
    return request.config.getoption("--port")


@pytest.fixture(scope="session")
def hw_baud(request):
    return request.config.getoption("--baud")
