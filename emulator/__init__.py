"""Software bus of Dynamixel X-series servos on a pty (issue #3); physics lives in ``emulator.physics``.

Modules: :mod:`memory` (control-table bytes and rules), :mod:`servo` (instruction semantics),
:mod:`faults` (fault injection), :mod:`pty_link` (the pty), :mod:`server` (:class:`Emulator`).
"""
from swerve.emulator.faults import Faults
from swerve.emulator.server import Emulator, Stats
from swerve.emulator.servo import VirtualServo

__all__ = ["Emulator", "Faults", "Stats", "VirtualServo"]
