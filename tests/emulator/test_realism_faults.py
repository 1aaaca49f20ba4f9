"""Faults the firmware raises from the physics, seen THROUGH THE BUS (driver.bus.Bus against the
robot emulator, no clock: simulated time advances only in ``emu.advance``)."""
from __future__ import annotations

import pytest

from swerve.configs import shipped
from swerve.driver.bus import Bus
from swerve.driver.control_table import HardwareError, Reg
from swerve.driver.errors import ServoError
from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.factory import robot_emulator
from swerve.emulator.timing import Frozen

REALISTIC = resolve_emulator_config("realistic")
OVERLOAD_S = load_config(REALISTIC).protection.overload_time_s
DRIVE = 1


@pytest.fixture
def emu():
    with robot_emulator(shipped("robot.yaml"), REALISTIC, timing=Frozen(), rate_hz=1000) as e:
        yield e


@pytest.fixture
def bus(emu):
    with Bus(emu.port, emu.baud, timeout_margin_s=1.0) as b:
        yield b


def test_stalled_drive_raises_overload_drops_torque_and_only_reboot_clears_it(emu, bus):
    bus.write(DRIVE, Reg.OPERATING_MODE, u.MODE_PWM)
    bus.write(DRIVE, Reg.TORQUE_ENABLE, 1)
    emu.world.physics.servos[DRIVE].motor.blocked = True       # the wheel is held against a wall
    bus.write(DRIVE, Reg.GOAL_PWM, 885)
    emu.advance(OVERLOAD_S - 0.1)
    assert bus.hardware_error(DRIVE) == 0
    assert bus.read(DRIVE, Reg.TORQUE_ENABLE) == 1
    assert bus.read(DRIVE, Reg.PRESENT_CURRENT) * u.AMP_PER_CURRENT_UNIT > 1.2
    emu.advance(0.2)
    with pytest.raises(ServoError) as err:                # every status now carries the Alert bit
        bus.read(DRIVE, Reg.PRESENT_CURRENT)
    assert err.value.alert
    assert bus.hardware_error(DRIVE) == HardwareError.OVERLOAD
    assert emu.servo(DRIVE).read(Reg.TORQUE_ENABLE) == 0  # Shutdown (63) default includes overload
    emu.advance(0.05)
    assert emu.world.physics.servos[DRIVE].motor.current_a == 0.0   # bridge open
    with pytest.raises(ServoError):
        bus.write(DRIVE, Reg.TORQUE_ENABLE, 1)            # cannot come back before a reboot
    assert emu.servo(DRIVE).read(Reg.TORQUE_ENABLE) == 0
    emu.world.physics.servos[DRIVE].motor.blocked = False
    bus.reboot(DRIVE)
    emu.advance(0.01)
    assert bus.hardware_error(DRIVE) == 0
    bus.read(DRIVE, Reg.PRESENT_CURRENT)                  # no alert any more
    bus.write(DRIVE, Reg.TORQUE_ENABLE, 1)
    assert bus.read(DRIVE, Reg.TORQUE_ENABLE) == 1


def test_input_voltage_below_the_limit_sets_its_bit_but_keeps_torque(emu, bus):
    bus.write(DRIVE, Reg.MIN_VOLTAGE_LIMIT, 120)          # 12.0 V: the idle sag alone (11.95 V) crosses it
    bus.write(DRIVE, Reg.TORQUE_ENABLE, 1)
    emu.advance(0.05)
    assert bus.hardware_error(DRIVE) == HardwareError.INPUT_VOLTAGE
    assert emu.servo(DRIVE).read(Reg.TORQUE_ENABLE) == 1  # not in Shutdown's default 0x34
    assert emu.world.physics.bus_voltage_v < 12.0 and emu.servo(DRIVE).read(Reg.PRESENT_INPUT_VOLTAGE) <= 120
