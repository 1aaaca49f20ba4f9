"""The robot's four wheel modules: four drive servos (velocity mode) and four steering
servos (position mode) on one :class:`~driver.bus.Bus`, configured from ``robot.yaml``.

::

    cfg = load_robot_config()
    with Bus(cfg.link.port, cfg.link.baud) as bus, WheelSet(bus, cfg) as wheels:
        wheels.configure()          # torque off, modes, gains, watchdog, return delay
        wheels.enable()
        wheels.write_goals([v1] * 4, [d1, d2, d2, d1])   # rad/s, rad: one Bulk Write
        state = wheels.read_state()                      # one Sync Read of 126..135
    # leaving the block writes zero speeds and torque off, also on Ctrl-C or an exception

All values are SI in the wheel frame: direction signs and steering zero (``center_pulse``)
are applied here and nowhere else. Out-of-range goals raise :class:`OutOfRangeError`
before anything is sent.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from typing import Sequence

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import ConfigError, DxlError, OutOfRangeError, SwerveError, TransportError
from swerve.driver.robot_config import RobotConfig

log = logging.getLogger(__name__)

#: Relative slack on the configured speed/angle limits (float round-off from the controller).
_LIMIT_TOL = 1e-9
#: The goal items' names as plain strings: an enum member hashes in Python, a str in C, and the
#: Bulk Write of every cycle looks them up a dozen times.
_GOAL_VELOCITY, _GOAL_POSITION = str(Reg.GOAL_VELOCITY), str(Reg.GOAL_POSITION)


@dataclass(frozen=True)
class WheelState:
    """One snapshot of the four wheel modules, in wheel order of the config.

    ``t_s``: :func:`time.monotonic` when the reply was complete; ``drive_radps``: wheel
    speeds; ``drive_rad``: wheel rotation angles (multi-turn while in velocity mode);
    ``steer_rad``: steering angles (0 = straight, + = counter-clockwise);
    ``steer_radps``: steering rates; ``drive_current_a`` / ``steer_current_a``: motor
    currents (signs as the servo reports them times the direction sign).
    """

    t_s: float
    drive_radps: tuple[float, float, float, float]
    drive_rad: tuple[float, float, float, float]
    steer_rad: tuple[float, float, float, float]
    steer_radps: tuple[float, float, float, float]
    drive_current_a: tuple[float, float, float, float]
    steer_current_a: tuple[float, float, float, float]


class WheelSet:
    """Four drive and four steering servos of ``config`` on ``bus``.

    ``fast``: read state with Fast Sync Read (firmware >= 45) instead of Sync Read.
    Use as a context manager: on exit (normal, exception, KeyboardInterrupt) it writes
    zero wheel speeds and torque off to all eight servos, tolerating a dead bus.
    """

    def __init__(self, bus: Bus, config: RobotConfig, *, fast: bool = False):
        self.bus = bus
        self.config = config
        self.fast = fast
        self.table = config.table
        self.drive_ids = config.drive_ids
        self.steer_ids = config.steer_ids
        self.ids = self.drive_ids + self.steer_ids
        for i in self.ids:  # the model is known: no Ping needed before the first access
            bus.set_model(i, self.table)
        self._vel = self.table[Reg.GOAL_VELOCITY]
        self._pos = self.table[Reg.GOAL_POSITION]
        self._vmax = config.drive_max_radps * (1 + _LIMIT_TOL)
        self._dmax = config.steer_angle_max_rad * (1 + _LIMIT_TOL)
        self._goal_plan = None       # the Bulk Write of the goals, planned at the first one
        # plain strings, as _GOAL_VELOCITY
        self._first, self._last = str(Reg.PRESENT_CURRENT), str(Reg.PRESENT_POSITION)
        self._names: tuple[str, ...] | None = None     # the read's register names, and
        self._at: tuple[int, int, int] = (0, 0, 0)     # where current, velocity, position are in them
        # per wheel, the SI factor of each present value with the direction sign in it (the
        # sign is +-1, so sign * (raw * scale) == raw * (sign * scale) exactly)
        cur, vel, pos = (self.table[r].to_si(1) for r in
                         (Reg.PRESENT_CURRENT, Reg.PRESENT_VELOCITY, Reg.PRESENT_POSITION))
        self._si = tuple((w.drive_direction * vel, w.drive_direction * pos, w.drive_direction * cur,
                          w.center_pulse, w.steer_direction * pos, w.steer_direction * vel,
                          w.steer_direction * cur) for w in config.wheels)

    # --- setup -------------------------------------------------------------------------------

    def configure(self) -> None:
        """Check all eight servos answer with the configured model, then (torque off) set
        Return Delay Time, operating modes, gains, profiles and the Bus Watchdog."""
        cfg, bus = self.config, self.bus
        found = bus.sync_read(self.ids, Reg.MODEL_NUMBER)
        wrong = {i: v[Reg.MODEL_NUMBER] for i, v in found.items()
                 if v[Reg.MODEL_NUMBER] != self.table.model_number}
        if wrong:
            raise ConfigError(f"{cfg.source}: model {cfg.model} ({self.table.model_number}) configured, "
                              f"but servos report model numbers {wrong}")
        self.disable()
        rdt_raw = self.table[Reg.RETURN_DELAY_TIME].from_si(cfg.link.return_delay_us * 1e-6)
        current = bus.sync_read(self.ids, Reg.RETURN_DELAY_TIME)
        if any(v[Reg.RETURN_DELAY_TIME] != rdt_raw for v in current.values()):
            bus.sync_write(Reg.RETURN_DELAY_TIME, {i: rdt_raw for i in self.ids})
        bus.return_delay_us = cfg.link.return_delay_us
        modes = {i: cfg.drive.operating_mode for i in self.drive_ids}
        modes.update({i: cfg.steering.operating_mode for i in self.steer_ids})
        bus.sync_write(Reg.OPERATING_MODE, modes)
        for ids, group in ((self.drive_ids, cfg.drive), (self.steer_ids, cfg.steering)):
            for name, raw in group.gains.items():
                bus.sync_write(name, {i: raw for i in ids})
            for name in (Reg.PROFILE_VELOCITY, Reg.PROFILE_ACCELERATION):
                raw = getattr(group, str(name))
                if raw is not None:
                    bus.sync_write(name, {i: raw for i in ids})
        wd = self.table[Reg.BUS_WATCHDOG]
        bus.sync_write(Reg.BUS_WATCHDOG, {i: 0 for i in self.ids})  # clears a tripped watchdog
        wd_raw = wd.from_si(cfg.bus_watchdog_s)
        if wd_raw == 0 and cfg.bus_watchdog_s > 0:
            wd_raw = 1
        if wd_raw:
            bus.sync_write(Reg.BUS_WATCHDOG, {i: wd_raw for i in self.ids})
        got = bus.sync_read(self.ids, Reg.OPERATING_MODE)
        bad = {i: v[Reg.OPERATING_MODE] for i, v in got.items() if v[Reg.OPERATING_MODE] != modes[i]}
        if bad:
            raise ConfigError(f"operating mode did not take on servos {bad} (expected {modes})")

    def enable(self) -> None:
        """Torque on for all eight servos."""
        self.bus.sync_write(Reg.TORQUE_ENABLE, {i: 1 for i in self.ids})

    def disable(self) -> None:
        """Torque off for all eight servos."""
        self.bus.sync_write(Reg.TORQUE_ENABLE, {i: 0 for i in self.ids})

    # --- the cycle ---------------------------------------------------------------------------

    def goal_raw(self, drive_radps: Sequence[float], steer_rad: Sequence[float]) -> dict[int, int]:
        """Raw goals ``{id: raw}`` for wheel speeds (rad/s) and steering angles (rad).

        Raises :class:`OutOfRangeError` naming the wheel for a value beyond the configured
        limits or the register range, or NaN; nothing is clamped.
        """
        return dict(zip(self.ids, self._goal_values(drive_radps, steer_rad)))

    def _goal_values(self, drive_radps: Sequence[float], steer_rad: Sequence[float]) -> list[int]:
        """:meth:`goal_raw` as a list in the order of :attr:`ids` (drive IDs, then steering IDs)."""
        cfg = self.config
        if len(drive_radps) != 4 or len(steer_rad) != 4:
            raise ValueError(f"expected 4 wheel speeds and 4 steering angles, got "
                             f"{len(drive_radps)} and {len(steer_rad)}")
        vmax, dmax = self._vmax, self._dmax
        vel, pos = self._vel, self._pos
        drive, steer = [], []
        for w, v, d in zip(cfg.wheels, drive_radps, steer_rad):
            v, d = float(v), float(d)
            if not -vmax <= v <= vmax:          # also NaN
                raise OutOfRangeError(f"{w.name} wheel speed", v, -cfg.drive_max_radps,
                                      cfg.drive_max_radps, "rad/s")
            if not -dmax <= d <= dmax:
                raise OutOfRangeError(f"{w.name} steering angle", d, -cfg.steer_angle_max_rad,
                                      cfg.steer_angle_max_rad, "rad")
            drive.append(vel.from_si(w.drive_direction * v))
            steer.append(pos.check_raw(w.center_pulse + round(w.steer_direction * d / pos.scale)))
        return drive + steer

    def write_goals(self, drive_radps: Sequence[float], steer_rad: Sequence[float]) -> None:
        """Send all eight goals in ONE Bulk Write: Goal Velocity to the drive servos,
        Goal Position to the steering servos (wheel speeds rad/s, steering angles rad)."""
        values = self._goal_values(drive_radps, steer_rad)
        if self._goal_plan is None:
            self._goal_plan = self.bus.bulk_write_plan(
                [(i, (_GOAL_VELOCITY,)) for i in self.drive_ids] + [(i, (_GOAL_POSITION,)) for i in self.steer_ids])
        self.bus.bulk_write_values(self._goal_plan, values)

    def read_state(self) -> WheelState:
        """Present current, velocity and position of all eight servos from ONE Sync Read
        (or Fast Sync Read) of addresses 126..135, converted to the wheel frame."""
        names, rows = self.bus.sync_read_rows(self.ids, self._first, self._last, fast=self.fast)
        t = time.monotonic()
        if names is not self._names:      # the bus's plan: the same tuple each cycle
            self._names = names
            self._at = (names.index(Reg.PRESENT_CURRENT), names.index(Reg.PRESENT_VELOCITY),
                        names.index(Reg.PRESENT_POSITION))
        ic, iv, ip = self._at
        dv, dp, dc, sp, sv, sc = [], [], [], [], [], []
        for (kdv, kdp, kdc, center, ksp, ksv, ksc), d, s in zip(self._si, rows, rows[len(self.drive_ids):]):
            dv.append(kdv * d[iv])
            dp.append(kdp * d[ip])
            dc.append(kdc * d[ic])
            sp.append(ksp * (s[ip] - center))
            sv.append(ksv * s[iv])
            sc.append(ksc * s[ic])
        return WheelState(t, tuple(dv), tuple(dp), tuple(sp), tuple(sv), tuple(dc), tuple(sc))

    # --- shutdown ----------------------------------------------------------------------------

    def stop(self) -> None:
        """Zero wheel speeds (torque stays on, steering holds)."""
        self.bus.sync_write(Reg.GOAL_VELOCITY, {i: 0 for i in self.drive_ids})

    def safe_shutdown(self) -> list[Exception]:
        """Zero speeds, then torque off; never raises a bus error, returns what failed.

        A dead port (:class:`TransportError`) ends the attempt at once: the servos are then
        left to their Bus Watchdog, which :meth:`left_to_watchdog` describes and the log says.
        """
        failures: list[Exception] = []
        for step in (self.stop, self.disable):
            try:
                step()
            except (DxlError, OSError, ValueError) as exc:
                log.warning("wheel set shutdown: %s failed: %s", step.__name__, exc)
                failures.append(exc)
                if isinstance(exc, TransportError):
                    break
        if failures:
            log.error("wheel set shutdown: %s", self.left_to_watchdog(failures[-1]))
        return failures

    def left_to_watchdog(self, cause: Exception) -> str:
        """One line saying the servos could not be stopped and what stops them instead."""
        wd = self.config.bus_watchdog_s
        fate = (f"they were left to their Bus Watchdog, which stops them {wd:g} s after the last "
                f"instruction" if wd > 0 else
                "their Bus Watchdog is off, so they keep their last goals: cut the power")
        return f"could not stop the servos ({cause}); {fate}"

    def __enter__(self) -> "WheelSet":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        failures = self.safe_shutdown()
        if not failures:
            return
        note = self.left_to_watchdog(failures[-1])
        if exc is None:
            raise TransportError(note) if isinstance(failures[-1], TransportError) else DxlError(note)
        if isinstance(exc, SwerveError):
            # the one-line message the command prints must say the servos were not stopped
            exc.args = (f"{exc}; {note}",)
