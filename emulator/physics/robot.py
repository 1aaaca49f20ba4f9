"""Eight servos on one robot body: the emulator's whole physical world.

``RobotPhysics.step(dt, tables)`` advances every servo with its raw control-table items, then the
body from the drive-wheel ground speeds and the steering angles (``configs/robot.yaml``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from swerve.driver.robot_config import DEFAULT_PATH, WheelConfig, load_robot_config

from . import units as u
from .body import RobotBody
from .params import PhysicsConfig
from .servo_model import ServoModel, wheel_servo


@dataclass(frozen=True)
class RobotGeometry:
    """The parts of ``configs/robot.yaml`` the physics needs."""

    model: str
    wheel_radius_m: float
    wheels: tuple[WheelConfig, ...]


def load_robot_geometry(path: str | Path = DEFAULT_PATH) -> RobotGeometry:
    """Wheel positions, IDs, direction signs and steering centres, read and checked by
    :func:`driver.robot_config.load_robot_config` (the one parser of ``robot.yaml``).

    Raises
    ------
    ConfigError
        On a missing or malformed key (the message names it).
    """
    cfg = load_robot_config(path)
    return RobotGeometry(cfg.model, cfg.wheel_radius_m, cfg.wheels)


class RobotPhysics:
    """Eight :class:`ServoModel` (4 drive, 4 steering) coupled to a :class:`RobotBody`.

    Parameters
    ----------
    cfg : PhysicsConfig
        ``configs/emulator.yaml``.
    geometry : RobotGeometry
        ``configs/robot.yaml``.
    rng : numpy.random.Generator, optional
        Shared noise source.
    """

    def __init__(self, cfg: PhysicsConfig, geometry: RobotGeometry, rng: np.random.Generator | None = None):
        self.geometry = geometry
        rng = rng if rng is not None else np.random.default_rng()
        self.servos: dict[int, ServoModel] = {}
        wheel_inertia = cfg.body.total_mass_kg / len(geometry.wheels) * geometry.wheel_radius_m ** 2
        for w in geometry.wheels:
            self.servos[w.drive_id] = wheel_servo(cfg, geometry.model, steering=False, rng=rng)
            if cfg.body.load_enabled:   # the robot's mass, reflected onto each drive shaft
                self.servos[w.drive_id].external_load(0.0, wheel_inertia)
            # steering servos start with the wheels straight
            self.servos[w.steer_id] = wheel_servo(cfg, geometry.model, steering=True,
                                                  center_pulse=w.center_pulse, rng=rng)
        self.body = RobotBody([(w.x_m, w.y_m) for w in geometry.wheels])

    def wheel_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground speeds (m/s, signed, forward positive) and steering angles (rad), shape (4,) each."""
        g = self.geometry
        speeds = np.array([w.drive_direction * self.servos[w.drive_id].velocity_radps * g.wheel_radius_m
                           for w in g.wheels])
        steer = np.array([w.steer_direction * (self.servos[w.steer_id].position_pulse - w.center_pulse)
                          * u.RAD_PER_PULSE for w in g.wheels])
        return speeds, steer

    def step(self, dt_s: float, tables: Mapping[int, Mapping[str, int]]) -> dict[int, dict[str, int]]:
        """Advance all servos (raw ``tables`` by ID) and the body by ``dt_s``; return present items by ID."""
        out = {sid: self.servos[sid].step(dt_s, tables[sid]) for sid in self.servos}
        self.step_body(dt_s)
        return out

    def step_body(self, dt_s: float) -> tuple[float, float, float]:
        """Advance only the body from the servos' present shaft states (servos stepped elsewhere,
        e.g. by the emulator's servo loop); return the pose."""
        return self.body.step(dt_s, *self.wheel_state())

