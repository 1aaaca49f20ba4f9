"""The emulator's true state as a JSON status file (``swerve emulate --status-file``).

:func:`status` is the document, :class:`StatusFile` an observer of the emulator
(``emu.observers``) that rewrites it atomically at most ``hz`` times a wall second,
:func:`read_status` reads it back (another process may be writing it).
"""
from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path

import numpy as np

from swerve.core.atomic import write_text
from swerve.driver.errors import ConfigError
from swerve.emulator.server import Emulator

log = logging.getLogger(__name__)


def status(emu: Emulator) -> dict:
    """The status-file document of a robot emulator (call under ``emu.lock``).

    ``{"t_s", "pose": [x_m, y_m, theta_rad], "twist": [vx_mps, vy_mps, omega_radps] (body
    frame), "wheels": [{"name", "speed_mps", "steer_rad", "slip_mps"} x 4], "slip_rms_mps",
    "clock": ClockStats.as_dict()}``. Wheel speeds and angles are the true shaft states in
    the wheel frame (direction signs and steering centre applied).
    """
    physics = emu.world.physics
    body = physics.body
    speeds, steer = physics.wheel_state()
    slip = np.asarray(body.residual_mps, float)
    return {
        "t_s": emu.sim_time_s,
        "pose": list(body.pose),
        "twist": [float(v) for v in body.twist],
        "wheels": [{"name": w.name, "speed_mps": float(v), "steer_rad": float(d), "slip_mps": float(s)}
                   for w, v, d, s in zip(physics.geometry.wheels, speeds, steer, slip)],
        "slip_rms_mps": float(np.sqrt(np.mean(slip ** 2))) if slip.size else 0.0,
        "clock": emu.clock_stats.as_dict(),
    }


class StatusFile:
    """Observer writing :func:`status` to ``path`` atomically (temp file + ``os.replace``), at most
    ``hz`` times per wall second, and every time while the emulator is not serving (at start and
    close)."""

    def __init__(self, path: str | os.PathLike, hz: float = 20.0):
        if not hz > 0:
            raise ConfigError(f"status_hz must be > 0, got {hz:g}")
        self.path = Path(path)
        self.period_s = 1.0 / hz
        self._next_t = 0.0

    def __call__(self, emu: Emulator) -> None:
        now = time.monotonic()
        if now >= self._next_t or not emu.running:
            self._next_t = now + self.period_s
            self.write(emu)

    def write(self, emu: Emulator, strict: bool = False) -> None:
        """Write the file now; a failure raises with ``strict`` (at start), else is logged."""
        try:
            write_text(self.path, json.dumps(status(emu)) + "\n", fsync=False, mkdir=False)
        except OSError as exc:
            if strict:
                raise
            log.warning("status file: %s", exc)


def read_status(path: str | os.PathLike) -> dict:
    """Read a status file written by :class:`StatusFile` (another process may be writing it)."""
    return json.loads(Path(path).read_text())
