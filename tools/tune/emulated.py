"""An in-process emulated bus for ``swerve tune --emulate`` and the tests.

Each servo of the robot config runs the emulator's own :class:`ServoModel` with the physics of
``configs/emulator.yaml`` (drive or steering motor by the servo's role; steering servos start at
their centre). The servos are unloaded — a wheel lifted off the ground, as a tuning session on
the robot should be done — so the identified values compare with Table 1 directly.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from swerve.driver.robot_config import RobotConfig
from swerve.emulator import Emulator, LinkSettings, WallClock, make_servos
from swerve.emulator.physics.params import PhysicsConfig, SensorParams
from swerve.emulator.physics.servo_model import ServoModel, wheel_servo

#: ``--noise``: encoder noise before quantisation (pulse) and current-sensor noise (A), std.
NOISE = SensorParams(position_noise_std_pulse=0.5, current_noise_std_a=0.004)


def servo_models(rc: RobotConfig, cfg: PhysicsConfig, *, noise: bool = False,
                 seed: int | None = None) -> Callable[[object], ServoModel]:
    """A ``dynamics(servo) -> ServoModel`` factory for :class:`emulator.Emulator`."""
    sensors = replace(cfg.sensors, position_noise_std_pulse=NOISE.position_noise_std_pulse,
                      current_noise_std_a=NOISE.current_noise_std_a) if noise else cfg.sensors
    rng = np.random.default_rng(seed)
    centers = {w.steer_id: w.center_pulse for w in rc.wheels}

    def dynamics(servo) -> ServoModel:
        return wheel_servo(cfg, rc.model, steering=servo.id in centers, center_pulse=centers.get(servo.id),
                           sensors=sensors, rng=rng)

    return dynamics


def make_emulator(rc: RobotConfig, cfg: PhysicsConfig | None, *, noise: bool = False, seed: int | None = None,
                  baud: int | None = None, **kwargs) -> Emulator:
    """An (unstarted) :class:`Emulator` with every servo of ``rc``, clocked at 1 kHz in real time;
    ``cfg=None``: static servos. ``kwargs``: :class:`LinkSettings` fields."""
    ids = sorted(set(rc.drive_ids) | set(rc.steer_ids))
    dynamics = servo_models(rc, cfg, noise=noise, seed=seed) if cfg is not None else None
    baud = baud or rc.link.baud
    return Emulator(make_servos(ids, rc.model, baud, dynamics=dynamics), link=LinkSettings(baud=baud, **kwargs),
                    clock=WallClock(1.0, 1000.0))
