"""Software bus of Dynamixel X-series servos on a pty; physics lives in ``emulator.physics``.

Modules: :mod:`memory` (control-table bytes and rules), :mod:`servo` (one servo's state),
:mod:`instructions` (what every instruction does), :mod:`reply_pacing` (when replies go out, fault
draws), :mod:`stepping` (physics steps and true state), :mod:`faults` (fault injection),
:mod:`pty_link` (the pty), :mod:`clock` (who owns simulated time), :mod:`server`
(:class:`Emulator`: the serve loop, composed of those), :mod:`factory` (:func:`build_emulator`,
from parsed configs), :mod:`process` and :mod:`child` (the emulator in a child process).

The package imports none of them, so a program that needs one module (the run's parent process
needs only :mod:`process`) does not load the others.
"""
