"""The application layer above driver and controller: the robot run.

:mod:`.ticker` paces a loop on a clock passed in (:class:`~.ticker.WallLoopClock` on the robot,
:class:`~.lockstep.LockstepLoopClock` for robot time owned by a lockstep emulator);
:mod:`.loop` is the 62.5 Hz tracking loop (wheels in, law out, log callback);
:mod:`.robot` turns the robot file into the controller's geometry and limits;
:mod:`.summary` is the typed run summary; :mod:`.orchestrate` runs one trajectory end to end
(config, trajectory, gains, bus or emulator, loop, log) for ``swerve run`` and ``swerve demo``.
"""
