"""Shipped configuration data: ``robot.yaml``, ``emulator.yaml``, ``models/``, ``trajectories/``.

The files ship inside the wheel as package data and are found through
:mod:`importlib.resources`, never through the working directory. A user's robot file lives
outside the package; :func:`locate_robot_file` says which one applies.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

#: Environment variable naming the robot file.
ENV_VAR = "SWERVE_CONFIG"


def shipped_dir() -> Path:
    """Directory of the shipped configs (a real directory: wheels and checkouts both unpack it)."""
    return Path(str(resources.files(__name__)))


def shipped(name: str) -> Path:
    """Path of a shipped config file, e.g. ``shipped("models/xh430-w210.yaml")``."""
    return shipped_dir() / name


def user_robot_file() -> Path:
    """``$XDG_CONFIG_HOME/swerve/robot.yaml`` (``~/.config/swerve/robot.yaml`` by default)."""
    base = os.environ.get("XDG_CONFIG_HOME") or Path.home() / ".config"
    return Path(base) / "swerve" / "robot.yaml"


@dataclass(frozen=True)
class ConfigChoice:
    """A config file and why it was chosen (``"--config"``, ``"$SWERVE_CONFIG"``, ``"user"``, ``"shipped"``)."""

    path: Path
    source: str

    def describe(self) -> str:
        """One phrase for logs and summaries, e.g. ``/home/pi/.config/swerve/robot.yaml (user)``."""
        return f"{self.path} ({self.source})"


def locate_robot_file(cli_path: str | os.PathLike | None = None) -> ConfigChoice:
    """The robot file to use: ``--config``, then ``$SWERVE_CONFIG``, then the user's, then the shipped one."""
    if cli_path is not None and str(cli_path) != "":
        return ConfigChoice(Path(cli_path), "--config")
    env = os.environ.get(ENV_VAR)
    if env:
        return ConfigChoice(Path(env), f"${ENV_VAR}")
    user = user_robot_file()
    if user.is_file():
        return ConfigChoice(user, "user")
    return ConfigChoice(shipped("robot.yaml"), "shipped")
