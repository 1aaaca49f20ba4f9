"""Shared fixtures for the physics tests: the real configs, servo factories."""
from __future__ import annotations

from pathlib import Path

import pytest

from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.robot import load_robot_geometry
from swerve.emulator.physics.servo_model import ServoModel

ROOT = Path(__file__).resolve().parents[3]



@pytest.fixture(scope="session")
def cfg():
    return load_config(ROOT / "configs" / "emulator.yaml")


@pytest.fixture(scope="session")
def geometry():
    return load_robot_geometry(ROOT / "configs" / "robot.yaml")


@pytest.fixture
def drive(cfg):
    return lambda **kw: ServoModel(cfg.drive_motor, cfg.gear_ratio("xh430-w210"), cfg.supply_voltage_v,
                                   kw.pop("firmware", cfg.firmware), **kw)


@pytest.fixture
def steer(cfg):
    return lambda **kw: ServoModel(cfg.steering_motor, cfg.gear_ratio("xh430-w210"), cfg.supply_voltage_v,
                                   kw.pop("firmware", cfg.firmware), **kw)
