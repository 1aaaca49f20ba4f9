"""Calibration on the emulated robot: ``swerve calibrate --emulate`` and the demo's and
campaigns' calibration step.

The emulated robot is built from a robot file whose steering centres, direction signs and wheel
radius (and the physics profile's tolerances) are the truth calibration must find; the
:class:`EmulatorOperator` answers the procedures' questions of :mod:`swerve.tools.calibrate`
from the emulator's true state, as a person looks at the robot.
"""
from __future__ import annotations

import contextlib
import math
from pathlib import Path
from typing import Callable, Sequence

from swerve.driver.bus import Bus
from swerve.driver.errors import ConfigError, SwerveError
from swerve.driver.robot_config import RobotConfig
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.factory import robot_emulator
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.status_file import status
from swerve.emulator.timing import Lockstep, scaled
from swerve.tools.calibrate import RADIUS_SPEED_MPS, STEPS, Jogger, Session, run_steps
from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepLoopClock

#: Physics rate of the emulated robot while calibrating, Hz.
EMULATOR_RATE_HZ = 1000.0


@contextlib.contextmanager
def emulated_bus(robot_path: str | Path, cfg: RobotConfig, *, emulator_config: str | Path | None = None,
                 lockstep: bool = True, time_scale: float = 1.0, margin_s: float | None = None):
    """The emulated robot built from ``robot_path`` (its steering centres, direction signs and
    wheel radius, plus the physics of ``emulator_config``: a profile name or file, default
    ideal, are the truth calibration must find), and a bus to it at ``cfg``'s baud.

    Yields ``(bus, clock, emu)``: ``clock`` the lockstep clock (``lockstep``), else None.
    """
    if margin_s is None:
        margin_s = LOCKSTEP_TIMEOUT_MARGIN_S if lockstep else 0.05
    with contextlib.ExitStack() as stack:
        emu = stack.enter_context(robot_emulator(robot_path, resolve_emulator_config(emulator_config or "ideal"),
                                                 body=BodySettings(), rate_hz=EMULATOR_RATE_HZ,
                                                 timing=Lockstep() if lockstep else scaled(time_scale)))
        clock = stack.enter_context(LockstepLoopClock(emu.control.path)) if lockstep else None
        bus = stack.enter_context(Bus(emu.port, cfg.link.baud, default_model=cfg.model, retries=1,
                                      timeout_margin_s=margin_s))
        if clock is not None:           # connected before anything was written to the pty
            clock.attach(bus)
        yield bus, clock, emu


def emulator_operator(emu, clock, cfg: RobotConfig, settle: Callable[[float], None]) -> "EmulatorOperator":
    """The :class:`EmulatorOperator` of a running emulated robot (what ``--yes`` answers with)."""
    def true_state() -> dict:
        if clock is not None:
            clock.pose()        # answered once the emulator has run the physics up to robot time
        with emu.lock:
            return status(emu)

    return EmulatorOperator(true_state, rad_per_pulse=cfg.table["present_position"].scale, settle=settle)


def calibrate_emulated(cfg: RobotConfig, robot_path: str | Path, *, emulator_config: str | Path | None = None,
                       steps: Sequence[str] = STEPS, lockstep: bool = True, time_scale: float = 1.0,
                       distance_m: float = 1.0, speed_mps: float = RADIUS_SPEED_MPS,
                       margin_s: float | None = None, log: Callable[[str], None] = print) -> dict:
    """``swerve calibrate --emulate --yes``: calibrate ``cfg`` on the emulated robot of
    ``robot_path`` and ``emulator_config`` (:func:`emulated_bus`), the answers read from its
    true state (:class:`EmulatorOperator`). Returns the values of :func:`run_steps`."""
    with emulated_bus(robot_path, cfg, emulator_config=emulator_config, lockstep=lockstep,
                      time_scale=time_scale, margin_s=margin_s) as (bus, clock, emu):
        with Session(bus, cfg, time_scale=time_scale, log=log, clock=clock) as session:
            op = emulator_operator(emu, clock, cfg, session.sleep)
            return run_steps(session, op, steps, jog=True, distance_m=distance_m, speed_mps=speed_mps)


class EmulatorOperator:
    """``--yes`` on the emulator: looks at the emulated robot's true state (``status()`` of a
    :class:`~swerve.emulator.server.Emulator`), as a person looks at the robot."""

    def __init__(self, status: Callable[[], dict], *, rad_per_pulse: float, settle: Callable[[float], None]):
        self.status = status
        self.rad_per_pulse = rad_per_pulse
        self.settle = settle
        self._seen: dict[tuple[str, int], float] = {}
        self._start_pose: list[float] | None = None

    def wait_straight(self) -> None:
        raise ConfigError("the emulated wheels cannot be turned by hand: calibrate the steering "
                          "zero on the emulator with --jog")

    def _angle(self, k: int) -> float:
        return float(self.status()["wheels"][k]["steer_rad"])

    def jog_straight(self, jog: Jogger) -> None:
        for k in range(len(jog.goals)):
            before = self._angle(k)
            probe = 16
            jog.jog(k, probe)
            jog.settle()
            slope = (self._angle(k) - before) / probe          # rad per pulse, sign unknown before
            if abs(slope) < 0.5 * self.rad_per_pulse:
                raise SwerveError(f"steering wheel {k} did not move when jogged")
            for _ in range(6):
                angle = self._angle(k)
                step = -round(angle / slope)
                if step == 0:
                    break
                jog.jog(k, step)
                jog.settle()

    def observe(self, kind: str, wheel: int) -> None:
        w = self.status()["wheels"][wheel]
        self._seen[(kind, wheel)] = float(w["speed_mps"] if kind == "drive" else w["steer_rad"])

    def confirm(self, kind: str, wheel: int, name: str) -> bool:
        return self._seen[(kind, wheel)] > 0

    def drive_starts(self) -> None:
        self._start_pose = list(self.status()["pose"])

    def measured_distance_m(self, commanded_m: float) -> float:
        if self._start_pose is None:
            raise SwerveError("the emulator operator did not see the start of the drive")
        x0, y0, _ = self._start_pose
        x1, y1, _ = self.status()["pose"]
        return math.hypot(x1 - x0, y1 - y0)
