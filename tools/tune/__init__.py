"""``swerve tune``: identify a servo's DC motor and design its loop gains.

Modules: :mod:`experiments` (step experiments through a :class:`driver.bus.Bus`, with safety),
:mod:`identify` (Levenberg–Marquardt fit with confidence intervals), :mod:`design` (gain search by
simulating :class:`emulator.physics.servo_model.ServoModel`), :mod:`metrics` (overshoot, rise,
settle), :mod:`report` (PNG figures, JSON/YAML results). Usage and results: ``README.md``.
"""
