"""The robot body as :func:`swerve.emulator.factory.build_emulator` takes it (``body=BodySettings()``).

A frozen value, so it travels to another process (:class:`swerve.emulator.process.EmulatorProcess`);
the factory builds the body's physics from it (:class:`~swerve.emulator.physics.robot_world.RobotWorld`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable

from swerve.driver.robot_config import RobotConfig


@dataclass(frozen=True)
class BodySettings:
    """The robot body on an emulated bus: the eight servos move it through their wheels.

    ``start_pose``: initial true pose ``(x_m, y_m, theta_rad)``. ``wheel_load``: reflect the
    robot's mass onto the drive shafts; ``None``: as the physics config says
    (``configs/emulator.yaml: body.load_enabled``).
    """

    start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0)
    wheel_load: bool | None = None


def robot_on_bus(robot: RobotConfig, ids: Iterable[int] | None) -> bool:
    """True if every servo of ``robot`` is among ``ids`` (``None``: the robot's own IDs), so the
    bus can move its body."""
    return ids is None or set(robot.drive_ids + robot.steer_ids) <= set(ids)


__all__ = ["BodySettings", "robot_on_bus"]
