"""What the tracking loop does when a servo latches a hardware error (``--on-servo-fault``).

A policy object is passed into the loop; the loop calls ``policy.recover(fault, wheels, rehome)``
when a read reports a hardware alert, and resumes only if it returns True:

- :class:`StopOnFault` (``stop``, the default) never recovers: the loop stops the robot.
- :class:`RecoverFromFault` (``recover``) stops the wheels and waits until they stand still
  (the torque goes off during the restore, and a rolling robot would coast), reboots the
  faulted servo(s) (a Reboot instruction is the only way to clear Hardware Error Status,
  e-Manual), waits until each answers a Ping again, restores operating modes, gains, profiles, return delay and the
  Bus Watchdog from the robot file (:meth:`WheelSet.configure`, torque off), turns the torque
  back on and lets the loop re-home the steering (``rehome()``). The loop does not advance
  the reference while it waits, so the trajectory resumes where it stopped. At most
  ``max_recoveries`` within ``window_s`` seconds; beyond that it refuses and the loop stops.

Every step is recorded in :attr:`events` (for the log and the run summary).
"""
from __future__ import annotations

import collections
import logging
import time
from dataclasses import asdict, dataclass
from typing import Callable, Protocol

from swerve.driver.bus import ExchangeSettings
from swerve.driver.control_table import Reg
from swerve.driver.errors import ConfigError, CorruptPacketError, DxlError, DxlTimeoutError, SwerveError

log = logging.getLogger(__name__)

#: Recoveries allowed within :data:`WINDOW_S` before the policy gives up.
MAX_RECOVERIES = 3
WINDOW_S = 60.0
#: Longest wait for the other drive wheels to stop before the torque goes off, s, and the speed
#: (raw Present Velocity, 0.229 rpm units) that counts as stopped.
STANDSTILL_TIMEOUT_S = 2.0
STANDSTILL_RAW = 1
#: Longest wait for a rebooted servo to answer again, s (a servo restarts within about a second).
REBOOT_TIMEOUT_S = 3.0


class Fault(Protocol):
    """What the loop hands a policy when it aborts (:class:`swerve.tools.run.loop.LoopAbort`)."""

    #: Why the loop stopped: ``"hardware error"`` is the one a policy may recover from.
    cause: str
    #: The servos concerned (empty when no servo is named).
    ids: tuple[int, ...]


@dataclass(frozen=True)
class ServoFaults:
    """How servo faults were handled, for the run summary: the ``on_servo_fault`` policy (stop /
    recover), the ``recoveries`` done, and every step as ``"<t_s> ID <ids> <step>: <detail>"``."""

    on_servo_fault: str
    recoveries: int
    recovery_steps: tuple[str, ...] = ()


@dataclass(frozen=True)
class RecoveryEvent:
    """One step: ``t_s`` (the policy's clock, s: monotonic, or robot time in lockstep), servo
    ``ids``, ``step`` name and a ``detail`` sentence."""

    t_s: float
    ids: tuple[int, ...]
    step: str
    detail: str

    def as_dict(self) -> dict:
        return asdict(self)

    def line(self) -> str:
        return f"{self.t_s:.3f} ID {','.join(map(str, self.ids)) or '-'} {self.step}: {self.detail}"


class StopOnFault:
    """Never recover: the loop stops the robot on a servo fault."""

    name = "stop"

    def __init__(self):
        self.events: list[RecoveryEvent] = []

    def recover(self, fault: Fault, wheels, rehome: Callable[[], None]) -> bool:
        return False

    def summary(self):
        """The run summary's :class:`ServoFaults`."""
        return ServoFaults(self.name, 0)


class RecoverFromFault:
    """Reboot and reconfigure a faulted servo, then let the loop resume (see module doc).

    ``bus_margin_s``/``bus_retries``: reply slack and retries while recovering (the loop keeps
    both small for its own reads; configuration is not time-critical). ``clock``: seconds
    (monotonic by default; a lockstep run passes robot time, see :func:`policy`); ``sleep``: how
    to wait, s, on that clock. Every wait (standstill, reboot) and the rate limit's window are
    measured on it.
    """

    name = "recover"

    def __init__(self, *, max_recoveries: int = MAX_RECOVERIES, window_s: float = WINDOW_S,
                 reboot_timeout_s: float = REBOOT_TIMEOUT_S, bus_margin_s: float = 0.0,
                 bus_retries: int = 1, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        if max_recoveries < 1 or window_s <= 0:
            raise ValueError("max_recoveries must be >= 1 and window_s > 0")
        self.max_recoveries = int(max_recoveries)
        self.window_s = float(window_s)
        self.reboot_timeout_s = float(reboot_timeout_s)
        self.bus_margin_s, self.bus_retries = float(bus_margin_s), int(bus_retries)
        self.standstill_timeout_s = STANDSTILL_TIMEOUT_S
        self.clock, self.sleep = clock, sleep
        self.events: list[RecoveryEvent] = []
        self.recoveries = 0
        self._recent: collections.deque[float] = collections.deque()

    def _note(self, ids, step: str, detail: str) -> None:
        ev = RecoveryEvent(self.clock(), tuple(ids), step, detail)
        self.events.append(ev)
        log.warning("servo fault recovery: %s (IDs %s): %s", step, ",".join(map(str, ids)) or "-", detail)

    def recover(self, fault: Fault, wheels, rehome: Callable[[], None]) -> bool:
        """Try to recover from ``fault`` (a loop abort). True: resume."""
        ids = tuple(fault.ids)
        if fault.cause != "hardware error" or not ids:
            self._note(ids, "refused", f"not a servo hardware error ({fault.cause})")
            return False
        now = self.clock()
        while self._recent and now - self._recent[0] > self.window_s:
            self._recent.popleft()
        if len(self._recent) >= self.max_recoveries:
            self._note(ids, "refused", f"{len(self._recent)} recoveries within {self.window_s:.0f} s already; "
                                       "stopping")
            return False
        self._recent.append(now)
        self._note(ids, "fault", str(fault))
        bus = wheels.bus
        patient = ExchangeSettings(max(bus.retries, self.bus_retries), max(bus.timeout_margin_s, self.bus_margin_s))
        try:
            with bus.exchanging(patient):
                self._restart(wheels, ids)
            rehome()
            self._note(ids, "rehome", "steering back at the last commanded angles")
        except SwerveError as exc:       # a bus error, or the loop's abort while re-homing
            self._note(ids, "failed", str(exc))
            return False
        self.recoveries += 1
        self._note(ids, "resume", f"recovery {self.recoveries} done; resuming the trajectory")
        return True

    def _restart(self, wheels, ids) -> None:
        """Stop the wheels, reboot the servos ``ids``, set all eight up again and turn the torque on."""
        bus = wheels.bus
        wheels.stop()
        waited = self._wait_standstill(wheels, ids)
        self._note(ids, "stop", "zero wheel speed commanded; " + (
            f"the other drive wheels stood still after {waited:.2f} s" if waited is not None else
            f"the other drive wheels still turned after {self.standstill_timeout_s:.1f} s"))
        for i in ids:
            try:
                bits = bus.hardware_error(i)
            except DxlError:
                bits = None
            bus.reboot(i)
            self._wait_answer(bus, i)
            self._note([i], "reboot", "rebooted" + (f" (Hardware Error Status was 0x{bits:02X})"
                                                   if bits is not None else "") + "; answers a Ping again")
        wheels.configure()
        self._note(ids, "restore", "operating modes, gains, profiles, return delay and Bus Watchdog "
                                   "written from the robot file")
        wheels.enable()
        self._note(ids, "torque", "torque on for all eight servos")

    def _wait_standstill(self, wheels, faulted) -> float | None:
        """Wait until the healthy drive servos report zero speed (the torque goes off next, and a
        robot still rolling would coast); seconds waited, or None at the timeout."""
        ids = [i for i in wheels.drive_ids if i not in faulted]
        start = self.clock()
        while ids:
            vel = wheels.bus.sync_read(ids, Reg.PRESENT_VELOCITY)
            if all(abs(v[Reg.PRESENT_VELOCITY]) <= STANDSTILL_RAW for v in vel.values()):
                break
            if self.clock() - start > self.standstill_timeout_s:
                return None
            self.sleep(0.02)
        return self.clock() - start

    def _wait_answer(self, bus, id_: int) -> None:
        end = self.clock() + self.reboot_timeout_s
        while True:
            try:
                bus.ping(id_)
                return
            except (DxlTimeoutError, CorruptPacketError):
                if self.clock() > end:
                    raise DxlTimeoutError([id_], 0x01, self.reboot_timeout_s,
                                          "the servo did not come back after its reboot") from None
                self.sleep(0.05)

    def summary(self):
        """The run summary's :class:`ServoFaults`."""
        return ServoFaults(self.name, self.recoveries, tuple(e.line() for e in self.events))


def policy(name: str, timeout_margin_s: float = 0.0, clock=None):
    """The policy for ``--on-servo-fault NAME`` (``stop`` or ``recover``); ``timeout_margin_s``:
    the run's reply slack before the loop narrows it, used while recovering. ``clock``: the
    loop's :class:`~swerve.tools.run.ticker.Clock` when it is not the wall clock (lockstep): the
    recovery then waits on it, so robot time, and the emulator's physics, advance while it waits
    (``None``: monotonic wall time)."""
    if name == "stop":
        return StopOnFault()
    if name == "recover":
        if clock is None:
            return RecoverFromFault(bus_margin_s=timeout_margin_s)
        return RecoverFromFault(bus_margin_s=timeout_margin_s, clock=clock.now,
                                sleep=lambda dt_s: clock.sleep_until(clock.now() + dt_s))
    raise ConfigError(f"--on-servo-fault {name!r}: expected stop or recover")
