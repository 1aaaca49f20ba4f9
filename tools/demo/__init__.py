"""``swerve demo``'s tasks: :mod:`.plan` (what the tasks are and what they give back, light to
import) and :mod:`.runs` (what a pool worker does for a task: gains, simulation, the run on the
emulator, its figures, the calibration). The command is :mod:`swerve.tools.commands.demo`."""
