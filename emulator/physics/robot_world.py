"""The robot body as the emulator's world: the servos' shafts move it after each step.

:class:`RobotWorld` implements :class:`swerve.emulator.stepping.World` for a
:class:`~swerve.emulator.physics.robot.RobotPhysics` (body, tyres, eight servo models).
"""
from __future__ import annotations

from typing import Mapping, Sequence

from swerve.emulator.physics.robot import RobotPhysics
from swerve.emulator.physics.servo_adapter import ServoDynamics
from swerve.emulator.physics.servo_model import ServoModel
from swerve.emulator.servo import VirtualServo


class RobotWorld:
    """The robot body of the emulator: moved by the servos' shafts after each step."""

    def __init__(self, physics: RobotPhysics):
        self.physics = physics
        self._coupled_dynamics: list[ServoDynamics] | None = None   # the dynamics run_coupled found eligible

    @property
    def pose(self) -> tuple[float, float, float]:
        return self.physics.body.pose

    def step(self, dt_s: float) -> None:
        self.physics.step_body(dt_s)

    def traces(self) -> dict[ServoModel, tuple] | None:
        """Empty per-step trace lists for a run of several steps, servo after servo
        (:meth:`RobotPhysics.traces`), or ``None`` if the body must step between the servos."""
        return self.physics.traces()

    def step_many(self, dt_s: float, n: int, traces: Mapping[ServoModel, tuple]) -> None:
        """``n`` body steps from the servos' recorded ``traces`` (:meth:`RobotPhysics.step_body_many`)."""
        self.physics.step_body_many(dt_s, n, traces)

    def run_coupled(self, servos: Sequence[VirtualServo], dt_s: float, n: int) -> int:
        """Up to ``n`` steps of the ``servos`` (their timers, Bus Watchdog and physics) and the
        body in one compiled call (:meth:`RobotPhysics.run_coupled`), where the compiled kernel
        exists and no servo draws sensor noise; the same result as
        ``n`` times each servo's :meth:`VirtualServo.advance` then :meth:`step`. Runs up to the
        next watchdog trip or physics-raised Hardware Error. Returns the steps run (0: this world
        cannot, step tick by tick)."""
        if n < 1:
            return 0
        dynamics = [s.dynamics for s in servos]
        if dynamics != self._coupled_dynamics and not self._eligible(dynamics):
            return 0
        physics = self.physics
        most = n
        for s in servos:
            most = min(most, s.begin_steps(dt_s, most))
        ran = physics.run_coupled(dt_s, most, {d.model: d.current_inputs() for d in dynamics})
        for s, d in zip(servos, dynamics):
            s.end_steps(dt_s, ran, d.take_hardware_error())
        return ran

    def _eligible(self, dynamics: list) -> bool:
        """Whether :meth:`run_coupled` can run the servos with these ``dynamics``: the physics
        runs coupled (:meth:`RobotPhysics.coupled`) and they are its servos' :class:`ServoDynamics`,
        none with sensor noise. Remembered for the same list of objects (a servo given other
        dynamics is checked again)."""
        physics = self.physics
        ok = (physics.coupled() and len(dynamics) == len(physics.servos)
              and all(isinstance(d, ServoDynamics) and d.batchable for d in dynamics))
        self._coupled_dynamics = dynamics if ok else None
        return ok
