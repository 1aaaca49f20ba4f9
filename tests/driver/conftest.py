"""Driver test fixtures: one bus target that is the emulator's pty, or the real port
given with ``--port`` (then fault-injection tests are skipped)."""
from __future__ import annotations

from dataclasses import dataclass

import pytest

from .fake_servos import FakeServos


@dataclass
class Target:
    url: str
    baud: int
    emu: object | None  # emulator.Emulator, or None on hardware

    @property
    def margin_s(self) -> float:
        # a Python emulator on a loaded 2-core machine can stall for tens of ms
        return 0.3 if self.emu is not None else 0.005


@pytest.fixture
def target(hw_port, hw_baud):
    if hw_port:
        yield Target(hw_port, hw_baud, None)
        return
    build_emulator = pytest.importorskip("swerve.emulator.factory").build_emulator
    Frozen = pytest.importorskip("swerve.emulator.timing").Frozen
    with build_emulator(ids=range(1, 9), model="xh430-w210", baud=1_000_000, timing=Frozen()) as emu:
        yield Target(emu.port, 1_000_000, emu)


@pytest.fixture
def bus_url(target) -> str:
    """The emulator's pty path, or the real port with --port."""
    return target.url


@pytest.fixture
def emu(target):
    """The emulator (for fault injection and inspection); skips on hardware."""
    if target.emu is None:
        pytest.skip("needs the emulator (fault injection / inspection)")
    return target.emu


@pytest.fixture
def bus(target):
    from swerve.driver.bus import Bus

    with Bus(target.url, target.baud, timeout_margin_s=target.margin_s) as b:
        yield b


@pytest.fixture
def fake():
    """The scripted responder (wrong IDs, garbage, stray bytes the emulator cannot make)."""
    with FakeServos() as f:
        yield f
