"""The robot file as the controller sees it: geometry and limits.

The controller takes plain numbers (:class:`~swerve.controller.kinematics.Geometry`,
:class:`~swerve.controller.kinematics.Limits`); the robot file is read and validated by the
driver's one parser (:func:`swerve.driver.robot_config.load_robot_config`). This module joins
the two, so neither imports the other.
"""
from __future__ import annotations

import os

from swerve.configs import ConfigChoice, locate_robot_file, shipped
from swerve.controller.kinematics import Geometry, Limits
from swerve.driver.robot_config import RobotConfig, load_robot_config


def geometry_and_limits(cfg: RobotConfig) -> tuple[Geometry, Limits]:
    """``(Geometry, Limits)`` of a validated robot config (m, m/s, rad/s, rad)."""
    return (Geometry(cfg.a_m, cfg.b_m, cfg.wheel_radius_m),
            Limits(cfg.v1_max_mps, cfg.steer_rate_max_radps, cfg.steer_angle_max_rad))


def load_robot(path: str | os.PathLike | None = None) -> tuple[Geometry, Limits]:
    """Geometry and limits of a robot file; ``None``: the shipped ``robot.yaml``.

    Raises :class:`swerve.core.errors.ConfigError` naming the file, key and problem.
    """
    return geometry_and_limits(load_robot_config(shipped("robot.yaml") if path is None else path))


def locate_and_load(cli_path: str | os.PathLike | ConfigChoice | None) -> tuple[ConfigChoice, RobotConfig]:
    """The robot file ``--config`` (or its look-up, :func:`swerve.configs.locate_robot_file`)
    names, and its validated contents. A :class:`ConfigChoice` is taken as already made."""
    choice = cli_path if isinstance(cli_path, ConfigChoice) else locate_robot_file(cli_path)
    return choice, load_robot_config(choice.path)
