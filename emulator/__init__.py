"""Software bus of Dynamixel X-series servos on a pty; physics lives in ``emulator.physics``.

Modules: :mod:`memory` (control-table bytes and rules), :mod:`servo` (one servo's state),
:mod:`instructions` (what every instruction does), :mod:`reply_pacing` (when replies go out, fault
draws), :mod:`stepping` (physics steps and true state), :mod:`faults` (fault injection),
:mod:`pty_link` (the pty), :mod:`clock` (who owns simulated time), :mod:`server`
(:class:`Emulator`: the serve loop, composed of those), :mod:`factory` (:func:`build_emulator`,
from parsed configs).
"""
from swerve.emulator.bus_stats import Stats
from swerve.emulator.clock import FrozenClock, PhysicsClock, WallPhysicsClock
from swerve.emulator.faults import Faults
from swerve.emulator.server import Emulator, LinkSettings
from swerve.emulator.servo import VirtualServo, make_servos

__all__ = ["Emulator", "Faults", "FrozenClock", "LinkSettings", "PhysicsClock", "Stats", "VirtualServo",
           "WallPhysicsClock", "make_servos"]
