"""pytest plugin ``swerve.testing``: the emulated Dynamixel bus and the emulated robot as fixtures.

Installed with swerve and registered through the ``pytest11`` entry point, so any project that
has swerve installed gets these fixtures without a conftest:

* ``emulated_bus``: the pty path of an emulated bus of X-series servos (in this process);
  configure it with ``@pytest.mark.emulated_bus(ids=[1, 2, 3], model="xh430-w210", ...)``.
* ``emulated_robot``: the whole emulated robot (eight servos and the body they move, in its own
  process) in lockstep: its time advances only when the test asks, so results do not depend on
  the machine's load. Configure with ``@pytest.mark.emulated_robot(config=..., faults=...)``.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Iterator

import pytest

from swerve.configs import shipped
from swerve.driver.bus import Bus
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.clock import DEFAULT_REPLY_LATENCY_S
from swerve.emulator.physics.params import load_config
from swerve.emulator.process import EmulatorProcess
from swerve.emulator.timing import Lockstep
from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepLoopClock

__all__ = ["EmulatedRobot", "emulated_bus", "emulated_robot"]


def pytest_configure(config) -> None:
    config.addinivalue_line(
        "markers", "emulated_bus(**kw): options of the emulated_bus fixture (ids, model, baud, physics, "
                   "faults, timing and other build_emulator keywords)")
    config.addinivalue_line(
        "markers", "emulated_robot(**kw): options of the emulated_robot fixture (config, faults, noise, "
                   "start_pose, rate_hz, reply_latency_s)")


def _marker_kwargs(request, name: str) -> dict:
    marker = request.node.get_closest_marker(name)
    return dict(marker.kwargs) if marker is not None else {}


@pytest.fixture
def emulated_bus(request) -> Iterator[str]:
    """Yield the pty path (``"/dev/pts/N"``) of an emulated bus, served by a thread of this process.

    Default: IDs 1-8, XH430-W210, 1 Mbps, a register-only bus (every instruction and error
    rule of the control table; Present* items stay put). Marker keywords are those of
    :func:`swerve.emulator.factory.build_emulator` plus ``physics`` (True: every servo
    runs its motor and firmware loops in ``timing``, default real time, as ``swerve emulate``). Open the path with ``swerve.driver.bus.Bus``, the dynamixel-sdk or any
    serial tool. The emulator object is ``request.node.emulator`` (faults, counters).
    """
    # the emulator in this process loads numba (the optional ``fast`` extra) and the physics:
    # only a session that asks for this fixture pays for it
    from swerve.emulator.factory import build_emulator

    kw = _marker_kwargs(request, "emulated_bus")
    physics = load_config(shipped("emulator.yaml")) if kw.pop("physics", False) else None
    kw.setdefault("ids", range(1, 9))
    with build_emulator(None, physics, **kw) as emu:
        request.node.emulator = emu
        yield emu.port


class EmulatedRobot:
    """The emulated robot in lockstep, as yielded by the ``emulated_robot`` fixture.

    ``port``: the pty to open with ``Bus(robot.port, 1_000_000)``; ``control_path``: its lockstep
    control socket; ``clock``: a :class:`swerve.tools.run.lockstep.LockstepLoopClock` (a clock for
    :class:`swerve.tools.run.ticker.Ticker` and the tracking loop). Open the bus with
    :meth:`open_bus`, or call :meth:`attach` with your own before you use it, so each time
    request first waits for the bytes it wrote.
    """

    def __init__(self, process, clock):
        self.process = process
        self.clock = clock
        self.port: str = process.port
        self.control_path: str = process.control_path

    def open_bus(self, **kwargs):
        """A :class:`swerve.driver.bus.Bus` on :attr:`port`, attached, with reply timeouts that
        ride out a loaded host (keywords go to ``Bus``; default 1 Mbps, XH430-W210)."""
        kwargs.setdefault("default_model", "xh430-w210")
        kwargs.setdefault("timeout_margin_s", LOCKSTEP_TIMEOUT_MARGIN_S)
        bus = Bus(self.port, kwargs.pop("baud", 1_000_000), **kwargs)
        self.attach(bus)
        return bus

    def attach(self, bus) -> None:
        """Count ``bus``'s written bytes (a :class:`swerve.driver.bus.Bus`, or anything with
        ``bytes_written``) in every time request; a ``Bus`` also tells the clock of each write,
        so a tracking loop asks for the time after a read while its reply is on the way."""
        if isinstance(bus, Bus):
            self.clock.attach(bus)
        else:
            self.clock.count_tx(lambda: bus.bytes_written)

    @property
    def time_s(self) -> float:
        """Robot time, s (bus exchanges included)."""
        return self.clock.now()

    @property
    def pose(self) -> tuple[float, float, float]:
        """True body pose ``(x_m, y_m, theta_rad)``, never through the bus."""
        return self.clock.pose()

    def advance(self, dt_s: float) -> float:
        """Let ``dt_s`` robot seconds pass (physics steps run); returns the new robot time."""
        if not (math.isfinite(dt_s) and dt_s >= 0):
            raise ValueError(f"advance needs a time >= 0 s, got {dt_s}")
        self.clock.sleep_until(self.clock.now() + dt_s)
        return self.clock.now()

    def fault(self, what: str, *args) -> None:
        """Inject a fault at this point of robot time: ``fault("vanish", 7)``, ``fault("restore", 7)``,
        ``fault("hwerror", 5, "overload")``."""
        self.clock.fault(what, *args)

    def counters(self) -> dict[str, int]:
        """The emulator's bus counters (``replies_dropped``, ``packets_received``, ...)."""
        return self.clock.counters()


@pytest.fixture
def emulated_robot(request) -> Iterator[EmulatedRobot]:
    """Yield an :class:`EmulatedRobot`: the robot (the robot file's eight servos and the body they
    move, 1 kHz physics) in its own process, in lockstep, at pose ``(0, 0, 0)``.

    Robot time stands still until the test (or a loop on ``robot.clock``) advances it; every bus
    exchange costs its wire time. Marker keywords: ``config`` (robot file; default: the
    shipped one), ``faults`` and ``noise`` (text specs; seeded with 0 unless they name a seed),
    ``start_pose``, ``rate_hz``, ``reply_latency_s``.
    """
    kw = _marker_kwargs(request, "emulated_robot")
    config = kw.pop("config", None)
    kw.setdefault("rate_hz", 1000.0)
    for key in ("faults", "noise"):
        if kw.get(key) and "seed=" not in kw[key]:
            kw[key] = f"{kw[key]},seed=0"
    kw.setdefault("noise", "seed=0")
    config = os.fspath(config) if isinstance(config, Path) else config
    timing = Lockstep(reply_latency_s=kw.pop("reply_latency_s", DEFAULT_REPLY_LATENCY_S))
    body = BodySettings(start_pose=tuple(kw.pop("start_pose", (0.0, 0.0, 0.0))))
    with EmulatorProcess(config, timing=timing, body=body, **kw) as process:
        with LockstepLoopClock(process.control_path) as clock:
            yield EmulatedRobot(process, clock)
