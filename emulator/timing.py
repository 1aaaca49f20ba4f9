"""How simulated time runs on a built emulator: frozen, scaled wall time, or lockstep.

:func:`swerve.emulator.factory.build_emulator` takes one of these descriptions as ``timing`` and
calls its :meth:`~Timing.build` once, with the physics rate, for the clock
(:mod:`swerve.emulator.clock`) and, in lockstep, the control channel
(:mod:`swerve.emulator.lockstep_socket`). They are frozen values, so they travel to another
process (:class:`swerve.emulator.process.EmulatorProcess`) and build there.

* :class:`Frozen`: simulated time stands still; only ``emu.advance(dt_s)`` moves it.
* :class:`WallTime`: ``scale`` simulated seconds per wall second.
* :class:`Lockstep`: robot time advances only when a client asks through the control channel;
  every bus exchange costs its wire time.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Protocol

from swerve.driver.errors import ConfigError
from swerve.emulator.clock import (DEFAULT_REPLY_LATENCY_S, FrozenClock, LockstepPhysicsClock, PhysicsClock,
                                   WallPhysicsClock)
from swerve.emulator.lockstep_socket import BARRIER_TIMEOUT_S, ControlServer


class Timing(Protocol):
    """A description of how simulated time runs, which builds its clock."""

    def build(self, rate_hz: float) -> tuple[PhysicsClock, ControlServer | None]:
        """The clock stepping the physics at ``rate_hz`` steps per simulated second, and the
        lockstep control channel (``None`` unless the clock keeps robot time)."""


@dataclass(frozen=True)
class Frozen:
    """Simulated time stands still; the bus only answers (step with ``emu.advance(dt_s)``)."""

    def build(self, rate_hz: float) -> tuple[PhysicsClock, None]:
        return FrozenClock(rate_hz), None


@dataclass(frozen=True)
class WallTime:
    """``scale`` simulated seconds per wall second (:class:`~swerve.emulator.clock.WallPhysicsClock`)."""

    scale: float = 1.0

    def __post_init__(self):
        if not (math.isfinite(self.scale) and self.scale > 0):
            raise ConfigError(f"time scale must be a finite number > 0, got {self.scale}")

    def build(self, rate_hz: float) -> tuple[PhysicsClock, None]:
        return WallPhysicsClock(self.scale, rate_hz), None


@dataclass(frozen=True)
class Lockstep:
    """Robot time advances only when a client asks, through the control channel (a Unix socket at
    ``control_path``, a temporary one by default; ``emu.control.path``); every exchange is charged
    at its wire time plus ``reply_latency_s`` per answering servo
    (:class:`~swerve.emulator.clock.LockstepPhysicsClock`). ``barrier_timeout_s`` bounds the wait for
    the pty bytes a control request announces (:class:`~swerve.emulator.lockstep_socket.ControlServer`)."""

    control_path: str | os.PathLike | None = None
    reply_latency_s: float = DEFAULT_REPLY_LATENCY_S
    barrier_timeout_s: float = BARRIER_TIMEOUT_S

    def build(self, rate_hz: float) -> tuple[PhysicsClock, ControlServer]:
        clock = LockstepPhysicsClock(rate_hz, self.reply_latency_s)
        try:
            return clock, ControlServer(self.control_path, self.barrier_timeout_s)
        except OSError as exc:
            raise ConfigError(f"cannot open the lockstep control socket: {exc}") from None


def scaled(time_scale: float) -> Frozen | WallTime:
    """:class:`WallTime` at ``time_scale`` simulated s per wall s, or :class:`Frozen` for 0."""
    if not (math.isfinite(time_scale) and time_scale >= 0):
        raise ConfigError(f"time scale must be a finite number >= 0, got {time_scale}")
    return WallTime(time_scale) if time_scale > 0 else Frozen()


__all__ = ["Timing", "Frozen", "WallTime", "Lockstep", "scaled"]
