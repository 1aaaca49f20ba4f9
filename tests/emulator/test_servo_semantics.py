"""Servo semantics without a pty: memory rules, watchdog, clock hook, dynamics, baud gating."""
from __future__ import annotations

import threading
import time

import pytest

from swerve.driver import packets as pk
from swerve.driver.control_table import Reg, table_for
from swerve.driver.errors import ConfigError
from swerve.driver.packets import ErrorNumber
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.clock import WallPhysicsClock
from swerve.emulator.factory import build_emulator
from swerve.emulator.faults import Faults
from swerve.emulator.instructions import execute
from swerve.emulator.memory import ServoMemory, WriteRejected
from swerve.emulator.server import Emulator
from swerve.emulator.stepping import SteppedWorld
from swerve.emulator.timing import Frozen
from swerve.emulator.servo import StepDynamics, VirtualServo, make_servos

TABLE = table_for("xh430-w210")


def servo(id_=1) -> VirtualServo:
    return VirtualServo(TABLE, id_, 1_000_000)


def test_defaults_and_identity():
    s = servo(7)
    assert (s.read(Reg.MODEL_NUMBER), s.read(Reg.ID), s.read(Reg.BAUD_RATE)) == (1010, 7, 3)
    assert s.read(Reg.RETURN_DELAY_TIME) == 250 and s.return_delay_s == pytest.approx(500e-6)
    assert s.read(Reg.GOAL_PWM) == 885 and s.read(Reg.SECONDARY_ID) == 255


def test_write_is_all_or_nothing():
    m = ServoMemory(TABLE)
    # LED (65) is fine but 66..67 are reserved: the whole write fails and LED stays 0
    with pytest.raises(WriteRejected) as exc:
        m.write(65, b"\x01\x00\x00")
    assert exc.value.number == ErrorNumber.ACCESS and m.get(Reg.LED) == 0


def test_limit_error_is_configurable():
    m = ServoMemory(TABLE, limit_error=ErrorNumber.DATA_RANGE)
    with pytest.raises(WriteRejected) as exc:
        m.write(104, (500).to_bytes(4, "little", signed=True))
    assert exc.value.number == ErrorNumber.DATA_RANGE


def test_time_based_profile_velocity_not_capped_by_velocity_limit():
    m = ServoMemory(TABLE)
    with pytest.raises(WriteRejected):
        m.write(112, (1000).to_bytes(4, "little"))
    m.write(10, b"\x04")                                 # Drive Mode bit 2: time-based profile
    m.write(112, (1000).to_bytes(4, "little"))
    assert m.get(Reg.PROFILE_VELOCITY) == 1000


def test_operating_mode_change_resets_goal_limits_and_profile():
    s = servo()
    s.memory.write(112, (50).to_bytes(4, "little"))
    s.memory.write(100, (100).to_bytes(2, "little"))
    assert s.bus_write(11, b"\x01") == ErrorNumber.NONE
    assert (s.read(Reg.PROFILE_VELOCITY), s.read(Reg.GOAL_PWM)) == (0, 885)


def test_unknown_instruction_and_action_without_registration():
    s = servo()
    assert execute(s, pk.InstructionPacket(1, 0x30)).error == ErrorNumber.INSTRUCTION
    assert execute(s, pk.action(1)).error == ErrorNumber.INSTRUCTION
    assert execute(s, pk.InstructionPacket(1, pk.Instruction.READ, b"\x84\x00")).error == ErrorNumber.DATA_LENGTH


def test_golden_ping_reply_bytes():
    s = VirtualServo(TABLE, 1)
    s.memory.set(Reg.MODEL_NUMBER, 1030)      # the e-Manual example is an XM430-W210, FW 38
    s.memory.set(Reg.FIRMWARE_VERSION, 38)
    st = execute(s, pk.InstructionPacket.decode(bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")))
    assert st.encode() == bytes.fromhex("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")


def test_bus_watchdog_trips_locks_goals_and_clears():
    s = servo()
    s.memory.write(64, b"\x01")
    s.memory.write(98, b"\x02")                          # 40 ms
    s.advance(0.030)
    assert s.read(Reg.BUS_WATCHDOG) == 2
    s.note_traffic()
    s.advance(0.030)
    assert s.read(Reg.BUS_WATCHDOG) == 2                 # traffic restarted the timer
    s.advance(0.015)
    assert s.read(Reg.BUS_WATCHDOG) == -1                # reads -1 when tripped
    assert s.bus_write(104, (10).to_bytes(4, "little")) == ErrorNumber.DATA_RANGE
    assert s.read(Reg.TORQUE_ENABLE) == 1                # torque stays on
    assert s.bus_write(98, b"\x00") == ErrorNumber.NONE
    assert s.bus_write(104, (10).to_bytes(4, "little")) == ErrorNumber.NONE


def test_watchdog_only_supervises_with_torque_on():
    s = servo()
    s.memory.write(98, b"\x01")
    s.advance(1.0)
    assert s.read(Reg.BUS_WATCHDOG) == 1


def test_realtime_tick_wraps():
    s = servo()
    s.advance(32.767)
    assert s.read(Reg.REALTIME_TICK) == 32767
    s.advance(0.002)
    assert s.read(Reg.REALTIME_TICK) == 1


class _Spin(StepDynamics):
    """A stand-in dynamics: present velocity follows goal velocity, position integrates."""

    def __init__(self):
        self.calls = 0
        self.pos = 0.0
        self.v = 0

    def advance(self, dt_s, table):
        self.calls += 1
        self.v = table["goal_velocity"] if table["torque_enable"] else 0
        self.pos += self.v * dt_s

    def outputs(self):
        return {"present_velocity": self.v, "present_position": int(self.pos), "moving": int(self.v != 0)}


def test_dynamics_hook_writes_outputs():
    s = servo()
    s.dynamics = _Spin()
    s.memory.write(64, b"\x01")
    s.memory.write(104, (100).to_bytes(4, "little"))
    for _ in range(1000):
        s.advance(0.001)
    assert s.dynamics.calls == 1000
    assert (s.read(Reg.PRESENT_VELOCITY), s.read(Reg.MOVING)) == (100, 1)
    assert s.read(Reg.PRESENT_POSITION) == pytest.approx(100, abs=1)


def test_emulator_clock_drives_dynamics_and_world():
    ticked = threading.Event()

    class World(SteppedWorld):
        def __init__(self):
            self.steps = 0

        def step(self, dt_s):
            self.steps += 1
            if self.steps >= 50:
                ticked.set()

    world = World()
    with Emulator(make_servos([1, 2], "xh430-w210", 1_000_000, dynamics=lambda s: _Spin()), clock=WallPhysicsClock(2.0),
                  world=world) as emu:
        assert ticked.wait(10.0)
        assert emu.servo(1).dynamics.calls >= 50
        assert emu.servo(1).read(Reg.REALTIME_TICK) > 0


def test_frozen_time_and_manual_advance():
    with build_emulator(ids=[1], timing=Frozen()) as emu:
        time.sleep(0.02)
        assert emu.servo(1).read(Reg.REALTIME_TICK) == 0
        emu.advance(0.1)
        assert emu.servo(1).read(Reg.REALTIME_TICK) == 100


def test_robot_config_and_bad_arguments():
    with build_emulator(load_robot_config("configs/robot.yaml"), timing=Frozen()) as emu:
        assert [s.id for s in emu.servos] == list(range(1, 9))
        assert emu.model == "XH430-W210" and emu.baud == 1_000_000
    with pytest.raises(ConfigError):
        build_emulator(ids=[1, 1])
    with pytest.raises(ConfigError):
        build_emulator(ids=[1], baud=12345)
    with pytest.raises(ConfigError):
        Faults.parse("drop=2")
    f = Faults.parse("drop=0.5,corrupt=0.1,delay=0.001,vanish=3+4,hwerror=2:overload+input_voltage,seed=3")
    assert (f.drop_rate, f.corrupt_rate, f.delay_s, f.vanished) == (0.5, 0.1, 0.001, {3, 4})
    with build_emulator(ids=[2, 3, 4], faults=f, timing=Frozen()) as emu:
        assert emu.servo(2).read(Reg.HARDWARE_ERROR_STATUS) == 0x21
    with pytest.raises(ConfigError, match="not on the emulated bus"):
        build_emulator(ids=[2], faults=f, timing=Frozen())


def test_baud_gating_follows_client_speed():
    import serial

    with build_emulator(ids=[1, 2], timing=Frozen()) as emu:
        emu.servo(2).write(Reg.BAUD_RATE, 1)          # 57600
        with serial.Serial(emu.port, 57600, timeout=0.5) as port:
            port.write(pk.ping(2).encode())
            reply = port.read(14)
            assert pk.StatusPacket.decode(reply).id == 2
            port.write(pk.ping(1).encode())
            assert port.read(14) == b""                # ID 1 listens at 1 Mbps only
        assert emu.stats.wrong_baud_packets == 0
