"""What the tracking loop does when a servo latches a hardware error (``--on-servo-fault``).

A policy object is passed into the loop; the loop calls ``policy.recover(fault, wheels, rehome)``
when a read reports a hardware alert, and resumes only if it returns True:

- :class:`StopOnFault` (``stop``, the default) never recovers: the loop stops the robot.
- :class:`RecoverFromFault` (``recover``) stops the wheels, reboots the faulted servo(s) (a
  Reboot instruction is the only way to clear Hardware Error Status, e-Manual), waits until
  each answers a Ping again, restores operating modes, gains, profiles, return delay and the
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
from typing import Callable

from swerve.driver.errors import CorruptPacketError, DxlError, DxlTimeoutError

log = logging.getLogger(__name__)

#: Recoveries allowed within :data:`WINDOW_S` before the policy gives up.
MAX_RECOVERIES = 3
WINDOW_S = 60.0
#: Longest wait for a rebooted servo to answer again, s (a servo restarts within about a second).
REBOOT_TIMEOUT_S = 3.0


@dataclass(frozen=True)
class RecoveryEvent:
    """One step: ``t_s`` (monotonic s), servo ``ids``, ``step`` name and a ``detail`` sentence."""

    t_s: float
    ids: tuple[int, ...]
    step: str
    detail: str

    def as_dict(self) -> dict:
        return asdict(self)


class StopOnFault:
    """Never recover: the loop stops the robot on a servo fault."""

    name = "stop"

    def __init__(self):
        self.events: list[RecoveryEvent] = []

    def recover(self, fault, wheels, rehome: Callable[[], None]) -> bool:
        return False

    def summary(self) -> dict:
        return {"on_servo_fault": self.name, "recoveries": 0, "recovery_events": []}


class RecoverFromFault:
    """Reboot and reconfigure a faulted servo, then let the loop resume (see module doc).

    ``clock``: monotonic seconds (injectable for tests); ``sleep``: how to wait, s.
    """

    name = "recover"

    def __init__(self, *, max_recoveries: int = MAX_RECOVERIES, window_s: float = WINDOW_S,
                 reboot_timeout_s: float = REBOOT_TIMEOUT_S, clock: Callable[[], float] = time.monotonic,
                 sleep: Callable[[float], None] = time.sleep):
        if max_recoveries < 1 or window_s <= 0:
            raise ValueError("max_recoveries must be >= 1 and window_s > 0")
        self.max_recoveries = int(max_recoveries)
        self.window_s = float(window_s)
        self.reboot_timeout_s = float(reboot_timeout_s)
        self.clock, self.sleep = clock, sleep
        self.events: list[RecoveryEvent] = []
        self.recoveries = 0
        self._recent: collections.deque[float] = collections.deque()

    def _note(self, ids, step: str, detail: str) -> None:
        ev = RecoveryEvent(self.clock(), tuple(ids), step, detail)
        self.events.append(ev)
        log.warning("servo fault recovery: %s (IDs %s): %s", step, ",".join(map(str, ids)) or "-", detail)

    def recover(self, fault, wheels, rehome: Callable[[], None]) -> bool:
        """Try to recover from ``fault`` (a loop abort with ``cause`` and ``ids``). True: resume."""
        ids = tuple(getattr(fault, "ids", ()) or ())
        if getattr(fault, "cause", None) != "hardware error" or not ids:
            self._note(ids, "refused", f"not a servo hardware error ({getattr(fault, 'cause', fault)})")
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
        try:
            wheels.stop()
            self._note(ids, "stop", "zero wheel speed commanded to every drive servo")
            bus = wheels.bus
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
            rehome()
            self._note(ids, "rehome", "steering back at the reference angles")
        except DxlError as exc:
            self._note(ids, "failed", str(exc))
            return False
        self.recoveries += 1
        self._note(ids, "resume", f"recovery {self.recoveries} done; resuming the trajectory")
        return True

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

    def summary(self) -> dict:
        return {"on_servo_fault": self.name, "recoveries": self.recoveries,
                "recovery_events": [e.as_dict() for e in self.events]}


def policy(name: str, **kwargs):
    """The policy for ``--on-servo-fault NAME`` (``stop`` or ``recover``)."""
    if name == "stop":
        return StopOnFault()
    if name == "recover":
        return RecoverFromFault(**kwargs)
    from swerve.driver.errors import ConfigError
    raise ConfigError(f"--on-servo-fault {name!r}: expected stop or recover")
