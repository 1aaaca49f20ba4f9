"""The USB-serial adapter's latency timer (1 ms wanted): read from sysfs on the robot, from the
emulated adapter with ``--emulate``; both through :class:`LatencyTimer`.

An FTDI adapter (the U2D2) holds a reply that does not fill a USB packet until its latency
timer expires: 16 ms as shipped (ROBOTIS e-Manual, DYNAMIXEL Wizard 2.0, "USB Latency
Setting"; FTDI AN232B-04), so each read can cost a whole 16 ms control period.
"""
from __future__ import annotations

import dataclasses
import os
from typing import Protocol

from swerve.driver.transport import latency_fix_command, latency_timer_ms
from swerve.tools.doctor.report import PASS, WARN, Check

#: udev rule that sets every FTDI adapter's latency timer to 1 ms when it is plugged in.
UDEV_RULE = ('ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", '
             'ATTR{latency_timer}="1"')
UDEV_RULE_PATH = "/etc/udev/rules.d/99-u2d2-latency.rules"
#: The latency timer doctor wants, ms.
WANTED_MS = 1
NAME = "latency timer"


class LatencyTimer(Protocol):
    """An adapter's latency timer, as doctor reads and sets it."""

    device: str                 # what to call it in the report

    def read_ms(self) -> int | None:
        """The timer in ms, or ``None`` when there is no USB-serial adapter."""

    def set_ms(self, value: int) -> None:
        """Set the timer (OSError when not allowed)."""

    def fix_text(self) -> str:
        """The one-line remedy that sets it to 1 ms for good."""


class SysfsLatencyTimer:
    """A ttyUSB's timer in ``/sys/bus/usb-serial/devices/ttyUSBn/latency_timer``."""

    def __init__(self, port: str, sysfs_root: str | None = None):
        self.port = port
        self.sysfs_root = sysfs_root
        self.device = os.path.basename(os.path.realpath(port))

    def read_ms(self) -> int | None:
        kw = {} if self.sysfs_root is None else {"sysfs_root": self.sysfs_root}
        return latency_timer_ms(self.port, warn=False, **kw)

    def set_ms(self, value: int) -> None:
        path = os.path.join(self.sysfs_root or "/sys/bus/usb-serial/devices", self.device, "latency_timer")
        with open(path, "w") as fh:
            fh.write(f"{value}\n")

    def fix_text(self) -> str:
        return f"{latency_fix_command(self.device)}; to keep it, put '{UDEV_RULE}' in {UDEV_RULE_PATH}"


class EmulatedLatencyTimer:
    """The emulator's USB adapter (:class:`swerve.emulator.adapter.UsbAdapter`), or none."""

    def __init__(self, adapter):
        self.adapter = adapter
        self.device = "emulated U2D2"

    def read_ms(self) -> int | None:
        return None if self.adapter is None else self.adapter.latency_ms

    def set_ms(self, value: int) -> None:
        self.adapter.settings = dataclasses.replace(self.adapter.settings, latency_ms=value)

    def fix_text(self) -> str:
        return ("set link.adapter_latency_ms: 1 in the robot file or pass --adapter-latency-ms 1; on the robot: "
                f"{latency_fix_command()}, kept by the udev rule '{UDEV_RULE}' in {UDEV_RULE_PATH}")


def check_latency(timer: LatencyTimer, *, fix: bool = False) -> tuple[Check, str | None]:
    """The adapter's latency timer against 1 ms. Returns ``(check, what fix did or None)``."""
    value = timer.read_ms()
    if value is None:
        return Check(NAME, PASS, f"{timer.device} is not a USB-serial adapter (no latency timer)"), None
    if value <= WANTED_MS:
        return Check(NAME, PASS, f"{timer.device}: {value} ms"), None
    msg = f"{timer.device}: {value} ms; every reply may wait that long (want {WANTED_MS} ms)"
    done = None
    if fix:
        try:
            timer.set_ms(WANTED_MS)
        except OSError as exc:
            msg += f" (could not set it: {exc.strerror})"
        else:
            value = timer.read_ms() or value
            done = f"set the latency timer of {timer.device} to {WANTED_MS} ms (until the adapter is replugged)"
            if value <= WANTED_MS:
                return Check(NAME, PASS, f"{timer.device}: {value} ms"), done
    return Check(NAME, WARN, msg, timer.fix_text()), done
