"""Software bus of Dynamixel X-series servos on a pty; physics lives in ``emulator.physics``.

Modules: :mod:`memory` (control-table bytes and rules), :mod:`servo` (instruction semantics),
:mod:`faults` (fault injection), :mod:`pty_link` (the pty), :mod:`clock` (who owns simulated
time), :mod:`server` (:class:`Emulator`, composed of those), :mod:`robot_emulator`
(:func:`build_emulator`, from parsed configs).

The package imports none of them, so a program that needs one module (the run's parent process
needs only :mod:`process`) does not load the others.
"""
