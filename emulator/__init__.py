"""Software bus of Dynamixel X-series servos on a pty; physics lives in ``emulator.physics``.

Modules: :mod:`memory` (control-table bytes and rules), :mod:`servo` (instruction semantics),
:mod:`faults` (fault injection), :mod:`pty_link` (the pty), :mod:`clock` (who owns simulated
time), :mod:`server` (:class:`Emulator`, composed of those), :mod:`robot_emulator`
(:func:`build_emulator`, from parsed configs).
"""
from swerve.emulator.clock import FrozenClock, PhysicsClock, WallPhysicsClock
from swerve.emulator.faults import Faults
from swerve.emulator.server import Emulator, LinkSettings, Stats, make_servos
from swerve.emulator.servo import VirtualServo

__all__ = ["Emulator", "Faults", "FrozenClock", "LinkSettings", "PhysicsClock", "Stats", "VirtualServo",
           "WallPhysicsClock", "make_servos"]
