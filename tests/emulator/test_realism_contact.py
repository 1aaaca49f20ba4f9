"""Wheels that fight each other, THROUGH THE BUS: WheelSet goals to the robot emulator with the
tyre-contact body; the true pose and slip come from the emulator's status, never the bus.
No clock (``timing=Frozen()``): simulated time advances only in ``emu.advance``."""
from __future__ import annotations

import math

import numpy as np
import pytest

from swerve.configs import shipped
from swerve.driver.bus import Bus
from swerve.driver.robot_config import load_robot_config
from swerve.driver.wheelset import WheelSet
from swerve.emulator.physics.contact import ContactBody
from swerve.emulator.factory import robot_emulator
from swerve.emulator.timing import Frozen
from swerve.emulator.status_file import status

ROBOT = shipped("robot.yaml")
CFG = load_robot_config(ROBOT)
SPEED_MPS = 0.08


def drive(physics: str, steer_rad, duration_s: float = 2.0) -> dict:
    """Run the robot at SPEED_MPS with steering ``steer_rad`` (wheel order); return its status."""
    physics_file = shipped("emulator-realistic.yaml" if physics == "realistic" else "emulator.yaml")
    with robot_emulator(ROBOT, physics_file, timing=Frozen(), rate_hz=1000) as emu:
        with Bus(emu.port, emu.baud, timeout_margin_s=1.0) as bus, WheelSet(bus, CFG) as wheels:
            wheels.configure()
            wheels.enable()
            for k in range(round((0.5 + duration_s) / 0.05)):   # writes keep the Bus Watchdog fed
                speed = SPEED_MPS / CFG.wheel_radius_m if k >= 10 else 0.0   # steer first, 0.5 s
                wheels.write_goals([speed] * 4, steer_rad)
                bus.ping(CFG.drive_ids[0])      # a Bulk Write has no reply: wait until it is executed
                emu.advance(0.05)
            assert isinstance(emu.world.physics.body, ContactBody) == (physics == "realistic")
            with emu.lock:
                doc = status(emu)
            doc["slip_energy_j"] = getattr(emu.world.physics.body, "slip_energy_j", 0.0)
            return doc


@pytest.fixture(scope="module")
def straight():
    return drive("realistic", [0.0] * 4)


def test_one_wheel_steered_20_degrees_off_yaws_the_body_and_every_wheel_slips(straight):
    off = drive("realistic", [math.radians(20), 0.0, 0.0, 0.0])
    assert off["pose"][2] - straight["pose"][2] > 0.05
    slips = np.array([w["slip_mps"] for w in off["wheels"]])
    assert np.all(slips > 3e-3)
    assert off["slip_energy_j"] > 20 * straight["slip_energy_j"]


def test_consistent_commands_drive_straight_on_the_realistic_floor(straight):
    x, y, theta = straight["pose"]
    # tolerances: wheel radii 1.012/0.992/1.018/0.985 and steering offsets -> a small drift only
    assert x == pytest.approx(SPEED_MPS * 2.0, rel=0.05)
    assert abs(theta) < 0.05 and abs(y) < 0.02
