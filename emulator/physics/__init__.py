"""Pure servo and robot-body physics for the emulator: no I/O, no clocks.

Modules: :mod:`units` (control-table LSBs), :mod:`params` (config dataclasses and loader),
:mod:`motor` (DC motor + gearbox, exact ZOH), :mod:`bessel` (2nd-order Bessel filter),
:mod:`firmware` (profile generator, velocity PI, position PID + feed-forward),
:mod:`servo_model` (one servo behind raw control-table integers), :mod:`body` (robot pose),
:mod:`robot` (eight servos on one body). Design notes: ``README.md`` next to this file.
"""
