"""WheelSet over a pty: configuration, one-packet goal writes and state reads, safe exit.

With ``--port`` these run on the real robot with zero wheel speeds and a small steering
angle; value checks that need the emulator's memory are skipped there.
"""
from __future__ import annotations

import math

import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import ConfigError, DxlTimeoutError, OutOfRangeError
from swerve.driver.robot_config import load_robot_config
from swerve.driver.wheelset import WheelSet, WheelState

CFG = load_robot_config()
VEL = 0.023980823922402087   # rad/s per Goal/Present Velocity unit
POS = 2 * math.pi / 4096     # rad per pulse
CUR = 0.00269                # A per Present Current unit


@pytest.fixture
def wheels(bus):
    ws = WheelSet(bus, CFG)
    with ws:
        yield ws


class _FrameCounter:
    """Counts frames the bus puts on the wire."""

    def __init__(self, bus, monkeypatch):
        self.n = 0
        real = bus._transport.write

        def write(data):
            self.n += 1
            real(data)
        monkeypatch.setattr(bus._transport, "write", write)


def test_configure_writes_modes_gains_watchdog(wheels, bus):
    wheels.configure()
    modes = bus.sync_read(wheels.ids, Reg.OPERATING_MODE)
    assert {i: v["operating_mode"] for i, v in modes.items()} == {1: 1, 2: 1, 3: 1, 4: 1, 5: 3, 6: 3, 7: 3, 8: 3}
    want_v = wheels.config.drive.gains["velocity_p_gain"]
    want_p = wheels.config.steering.gains["position_p_gain"]
    assert (want_v, want_p) != (100, 900)               # differ from the servo defaults: a write shows
    assert bus.read(1, Reg.VELOCITY_P_GAIN) == want_v and bus.read(5, Reg.POSITION_P_GAIN) == want_p
    assert bus.read(8, Reg.BUS_WATCHDOG) == 5          # 0.1 s / 20 ms
    assert bus.read(2, Reg.RETURN_DELAY_TIME) == 0
    assert bus.read(3, Reg.TORQUE_ENABLE) == 0
    wheels.enable()
    assert all(v["torque_enable"] == 1 for v in bus.sync_read(wheels.ids, Reg.TORQUE_ENABLE).values())


def test_goals_one_packet_with_signs_and_center(wheels, bus, emu, monkeypatch):
    wheels.configure()
    wheels.enable()
    frames = _FrameCounter(bus, monkeypatch)
    v, d1, d2 = 1.0, 0.2, -0.1
    wheels.write_goals([v, v, v, v], [d1, d2, d2, d1])
    assert frames.n == 1
    bus.ping(1)  # a round trip: the emulator has processed the bulk write
    raw_v = round(v / VEL)
    assert [emu.servo(i).read("goal_velocity") for i in (1, 2, 3, 4)] == [raw_v, raw_v, -raw_v, -raw_v]
    assert [emu.servo(i).read("goal_position") for i in (5, 6, 7, 8)] == [
        2048 + round(d1 / POS), 2048 + round(d2 / POS), 2048 + round(d2 / POS), 2048 + round(d1 / POS)]


def test_read_state_one_sync_read_in_si(wheels, bus, emu, monkeypatch):
    emu.servo(3).write("present_velocity", 40)
    emu.servo(3).write("present_current", -10)
    emu.servo(3).write("present_position", 5000)
    emu.servo(7).write("present_position", 2048 + 100)
    emu.servo(7).write("present_velocity", -3)
    frames = _FrameCounter(bus, monkeypatch)
    s = wheels.read_state()
    assert frames.n == 1
    assert isinstance(s, WheelState)
    assert s.drive_radps[2] == pytest.approx(-40 * VEL)       # right side mirrored
    assert s.drive_current_a[2] == pytest.approx(10 * CUR)
    assert s.drive_rad[2] == pytest.approx(-5000 * POS)
    assert s.steer_rad[2] == pytest.approx(100 * POS)
    assert s.steer_radps[2] == pytest.approx(-3 * VEL)
    assert s.steer_rad[0] == pytest.approx(-2048 * POS)       # emulator starts at 0 pulses
    assert s.t_s > 0


def test_read_state_fast(bus, emu):
    emu.servo(1).write("present_velocity", -5)
    with WheelSet(bus, CFG, fast=True) as ws:
        assert ws.read_state().drive_radps[0] == pytest.approx(-5 * VEL)


def test_out_of_range_goal_raises_and_sends_nothing(wheels, bus, monkeypatch):
    frames = _FrameCounter(bus, monkeypatch)
    too_fast = CFG.drive_max_radps * 1.01
    with pytest.raises(OutOfRangeError, match="rear_right wheel speed"):
        wheels.write_goals([0, 0, too_fast, 0], [0, 0, 0, 0])
    with pytest.raises(OutOfRangeError, match="front_left steering angle"):
        wheels.write_goals([0, 0, 0, 0], [2.0, 0, 0, 0])
    with pytest.raises(OutOfRangeError):
        wheels.write_goals([math.nan, 0, 0, 0], [0, 0, 0, 0])
    with pytest.raises(ValueError):
        wheels.write_goals([0, 0, 0], [0, 0, 0, 0])
    assert frames.n == 0
    wheels.write_goals([CFG.drive_max_radps] * 4, [CFG.steer_angle_max_rad] * 4)  # limits themselves OK


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_exit_stops_and_disables_on_exception(bus, emu, exc):
    with pytest.raises(exc):
        with WheelSet(bus, CFG) as ws:
            ws.configure()
            ws.enable()
            ws.write_goals([1.0] * 4, [0.1] * 4)
            raise exc("boom")
    bus.ping(1)
    assert [emu.servo(i).read("goal_velocity") for i in (1, 2, 3, 4)] == [0, 0, 0, 0]
    assert [emu.servo(i).read("torque_enable") for i in range(1, 9)] == [0] * 8


def test_exit_tolerates_dead_bus(target):
    bus = Bus(target.url, target.baud, timeout_margin_s=target.margin_s)
    with pytest.raises(RuntimeError, match="original"):
        with WheelSet(bus, CFG) as ws:
            bus.close()
            raise RuntimeError("original")
    assert ws.safe_shutdown()  # reports what failed instead of raising


def test_configure_names_missing_servo(wheels, emu):
    emu.faults.vanish(6)
    with pytest.raises(DxlTimeoutError) as ei:
        wheels.configure()
    assert 6 in ei.value.ids


def test_configure_rejects_wrong_model(hw_port):
    if hw_port:
        pytest.skip("needs the emulator")
    build_emulator = pytest.importorskip("swerve.emulator.factory").build_emulator
    Frozen = pytest.importorskip("swerve.emulator.timing").Frozen
    # every servo answers: a generous reply slack only keeps a loaded host from cutting a reply off
    with build_emulator(model="xh430-w350", timing=Frozen()) as emu, \
            Bus(emu.port, timeout_margin_s=5.0) as bus:
        with pytest.raises(ConfigError, match="1000"):
            WheelSet(bus, CFG).configure()


class _NoBus:
    """Stands in for a Bus where only the pure conversion is exercised."""

    def set_model(self, id_, model):
        pass


from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_v = st.floats(-CFG.drive_max_radps, CFG.drive_max_radps)
_d = st.floats(-CFG.steer_angle_max_rad, CFG.steer_angle_max_rad)


@settings(max_examples=200, deadline=None)
@given(st.lists(_v, min_size=4, max_size=4), st.lists(_d, min_size=4, max_size=4))
def test_goal_conversion_roundtrips_within_half_lsb(v, d):
    ws = WheelSet(_NoBus(), CFG)
    raw = ws.goal_raw(v, d)
    for k, w in enumerate(CFG.wheels):
        assert abs(w.drive_direction * raw[w.drive_id] * VEL - v[k]) <= VEL / 2 + 1e-12
        assert abs(w.steer_direction * (raw[w.steer_id] - w.center_pulse) * POS - d[k]) <= POS / 2 + 1e-12
