"""Lockstep: the emulator owns robot time. Wire-time accounting, the byte barrier, pausing,
the command-line surface and the pytest fixtures; none of the verdicts depend on wall time."""
from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swerve.configs import shipped
from swerve.driver.bus import Bus, ExchangeSettings
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.physics.params import load_config
from swerve.driver.control_table import Reg
from swerve.driver.errors import DxlTimeoutError
from swerve.emulator.clock import DEFAULT_REPLY_LATENCY_S
from swerve.emulator.factory import build_emulator
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.timing import Lockstep
from swerve.tools.commands.emulate import parse_control, parse_port_line
from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepLoopClock, LockstepError

ROOT = Path(__file__).resolve().parents[1]
BYTE_S = 10 / 1_000_000          # one byte at 1 Mbps, 8N1


#: Reply slack of the tests that count the clock's requests: long enough that the bus never asks
#: its reply gate (a request of its own, sent when a reply is later than the slack) on a loaded host.
COUNTING_MARGIN_S = 2.0


@pytest.fixture
def bus_in_lockstep():
    """A register-only 3-servo bus in lockstep, its driver, and a clock on its control channel."""
    with build_emulator(ids=[1, 2, 3], timing=Lockstep()) as emu:
        with LockstepLoopClock(emu.control.path) as clock, Bus(emu.port, 1_000_000, default_model="xh430-w210",
                                                           timeout_margin_s=LOCKSTEP_TIMEOUT_MARGIN_S) as bus:
            clock.attach(bus)           # its reply gate: a loaded host delays, never loses, a reply
            yield emu, bus, clock


def test_an_exchange_costs_its_wire_time_in_robot_time(bus_in_lockstep):
    emu, bus, clock = bus_in_lockstep
    t0 = clock.now()
    assert t0 == 0.0                                  # nothing has happened yet
    bus.ping(2)
    delay_s = emu.servo(2).return_delay_s             # Return Delay Time item (500 us by default)
    expected = (10 + 14) * BYTE_S + delay_s + DEFAULT_REPLY_LATENCY_S   # request, reply frames
    assert clock.now() - t0 == pytest.approx(expected, abs=1e-12)
    t1 = clock.now()
    bus.write(1, Reg.LED, 1)                          # write: 13-byte request, 11-byte status
    assert clock.now() - t1 == pytest.approx(24 * BYTE_S + emu.servo(1).return_delay_s
                                             + DEFAULT_REPLY_LATENCY_S, abs=1e-12)


def _steps_once_served(emu, bus) -> int:
    """The emulator's physics steps, read in this process once a ping was served: the emulator
    answers an advance before it runs the physics, and serves the next byte only after it (the
    ping's own wire time, 0.8 ms in all, adds no step at the times used here)."""
    bus.ping(1)
    return emu.clock.stats.steps


def test_advance_runs_the_physics_to_the_requested_time_and_no_further(bus_in_lockstep):
    emu, bus, clock = bus_in_lockstep
    clock.sleep_until(0.016)
    assert clock.now() == 0.016
    clock.sleep_until(0.010)                          # time never goes back
    assert clock.now() == 0.016
    assert _steps_once_served(emu, bus) == 16 and emu.sim_time_s == pytest.approx(0.016)
    time.sleep(0.2)                                   # nobody asks: the robot stays paused
    assert emu.clock.stats.steps == 16


def test_the_barrier_serves_bytes_written_before_the_time_request(bus_in_lockstep):
    """A write without a reply, then at once a time request: the write is executed first,
    whatever the pty's delivery delay, and its wire time is charged before the advance."""
    emu, bus, clock = bus_in_lockstep
    for k in range(200):
        bus.sync_write(Reg.GOAL_POSITION, {1: k, 2: k, 3: k})   # no reply
        assert clock.now() == pytest.approx((k + 1) * (14 + 3 * 5) * BYTE_S)
        with emu.lock:
            assert emu.servo(3).read("goal_position") == k


def test_a_fault_sent_on_the_channel_takes_effect_in_order(bus_in_lockstep):
    emu, bus, clock = bus_in_lockstep
    clock.fault("vanish", 2)
    with pytest.raises(DxlTimeoutError):
        bus.ping(2)
    clock.fault("restore", 2)
    assert bus.ping(2).id == 2
    with pytest.raises(LockstepError, match="unknown fault"):
        clock.fault("melt", 2)
    assert clock.counters()["packets_received"] == 2


def test_a_background_sleep_lets_the_client_work_and_reports_when_it_was_asked(bus_in_lockstep):
    emu, bus, clock = bus_in_lockstep
    bus.sync_write(Reg.GOAL_POSITION, {1: 7, 2: 7, 3: 7})          # 29 bytes, no reply
    clock.start_sleep(0.016)
    requests = clock.requests
    asked = clock.end_sleep()
    assert clock.requests == requests                               # one request in all
    assert asked == pytest.approx(29 * BYTE_S) and clock.now() == 0.016
    assert _steps_once_served(emu, bus) == 16
    with pytest.raises(LockstepError, match="without start_sleep"):
        clock.end_sleep()


def test_any_request_collects_a_pending_sleep_first(bus_in_lockstep):
    emu, bus, clock = bus_in_lockstep
    bus.ping(1)
    t0 = clock.now()
    clock.start_sleep(0.005)
    assert clock.counters()["packets_received"] == 1                # answered in order
    assert clock.now() == 0.005
    assert clock.end_sleep() == t0                                  # the sleep still ends once
    assert _steps_once_served(emu, bus) == 5


def test_now_brings_the_true_pose_with_it():
    """On a robot, the time after a read and the true pose are one request."""
    robot = load_robot_config(shipped("robot.yaml"))
    with build_emulator(robot, load_config(shipped("emulator.yaml")), timing=Lockstep(), body=BodySettings()) as emu:
        with LockstepLoopClock(emu.control.path) as clock, Bus(emu.port, 1_000_000, default_model="xh430-w210",
                                                           timeout_margin_s=COUNTING_MARGIN_S) as bus:
            clock.attach(bus)           # its reply gate: a loaded host delays, never loses, a reply
            clock.sleep_until(0.1)
            bus.ping(1)
            n = clock.requests
            t = clock.now()
            pose = clock.pose()
            assert clock.requests == n + 1
            assert t > 0.1 and pose == emu.pose
            bus.ping(2)                                              # bytes since: ask again
            clock.pose()
            assert clock.requests == n + 2


def test_the_time_after_a_read_can_be_asked_while_its_reply_is_on_the_way():
    robot = load_robot_config(shipped("robot.yaml"))
    with build_emulator(robot, load_config(shipped("emulator.yaml")), timing=Lockstep(), body=BodySettings()) as emu:
        with LockstepLoopClock(emu.control.path) as clock, Bus(emu.port, 1_000_000, default_model="xh430-w210",
                                                           timeout_margin_s=COUNTING_MARGIN_S) as bus:
            clock.attach(bus)
            clock.sleep_until(0.1)
            n = clock.requests
            clock.ask_after_next_write()
            bus.ping(3)                                 # the request goes out with the ping
            assert clock.requests == n + 1
            t, pose = clock.now(), clock.pose()
            assert clock.requests == n + 1              # both came with it
            delay = emu.servo(3).return_delay_s
            cable_end = 0.1 + (10 + 14) * BYTE_S + delay + DEFAULT_REPLY_LATENCY_S     # 0.10079 s
            # the robot file's USB adapter (1 ms latency timer) hands it over at its next expiry
            assert robot.link.adapter_latency_ms == 1 and cable_end < 0.101
            assert t == pytest.approx(0.101, abs=1e-12)
            assert pose == emu.pose
            bus.ping(3)                                 # not armed again: written() sends nothing
            assert clock.requests == n + 1
            assert clock.now() > t and clock.requests == n + 2


def test_bad_requests_get_an_error_line_and_the_channel_keeps_serving(bus_in_lockstep):
    emu, bus, clock = bus_in_lockstep
    with pytest.raises(LockstepError, match="unknown request"):
        clock._ask("jump 3")
    with pytest.raises(LockstepError):
        clock._ask("advance nan 0")
    assert clock.info()["rate_hz"] == 1000.0


def test_emulate_lockstep_prints_its_control_socket_and_stays_paused():
    proc = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "emulate", "--lockstep", "--ids", "1-2"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        port, baud, ids = parse_port_line(line)
        control = parse_control(line)
        assert ids == [1, 2] and control is not None and Path(control).exists()
        with LockstepLoopClock(control) as clock, Bus(port, baud, default_model="xh430-w210",
                                                  timeout_margin_s=LOCKSTEP_TIMEOUT_MARGIN_S) as bus:
            clock.attach(bus)           # its reply gate: a loaded host delays, never loses, a reply
            assert bus.ping(1).id == 1
            t = clock.now()
            assert t > 0
            tick0 = bus.read(1, Reg.REALTIME_TICK)
            t1 = clock.now()
            time.sleep(0.3)                           # wall time passes, robot time does not
            assert clock.now() == t1
            clock.sleep_until(t1 + 0.5)
            ticks = (bus.read(1, Reg.REALTIME_TICK) - tick0) % 32768      # 1 ms per tick
            assert 500 <= ticks <= 501                # + the read's own wire time (< 1 ms)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 0
        assert not Path(control).exists()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_emulate_lockstep_with_a_time_scale_is_a_one_line_error():
    out = subprocess.run([sys.executable, "-m", "swerve.tools.cli", "emulate", "--lockstep", "--time-scale", "2"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1


def test_run_lockstep_with_a_port_is_a_one_line_error():
    out = subprocess.run([sys.executable, "-m", "swerve.tools.cli", "run", "--trajectory", "line",
                          "--lockstep", "--port", "/dev/null", "--no-log"],
                         cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    assert len(out.stderr.strip().splitlines()) == 1 and "--lockstep" in out.stderr


@pytest.mark.emulated_bus(ids=[4, 5, 6], physics=True)
def test_emulated_bus_fixture_takes_its_servos_from_the_marker(emulated_bus):
    with Bus(emulated_bus, 1_000_000) as bus:
        assert [r.id for r in bus.scan(range(1, 8))] == [4, 5, 6]


def test_emulated_robot_moves_in_robot_time_only(emulated_robot):
    """Drive straight for ~1 s of robot time: the body moves about v * 1 s, and then stays put
    while wall time passes."""
    from swerve.configs import shipped
    from swerve.driver.robot_config import load_robot_config
    from swerve.driver.wheelset import WheelSet

    cfg = load_robot_config(shipped("robot.yaml"))
    with emulated_robot.open_bus(baud=cfg.link.baud, default_model=cfg.model) as bus:
        with WheelSet(bus, cfg) as wheels:
            wheels.configure()
            wheels.enable()
            v_mps = 0.1
            t0 = emulated_robot.time_s
            for _ in range(62):                       # goals every 16 ms keep the Bus Watchdog fed
                wheels.write_goals([v_mps / cfg.wheel_radius_m] * 4, [0.0] * 4)
                emulated_robot.advance(0.016)
            assert 62 * 0.016 < emulated_robot.time_s - t0 < 62 * 0.018   # + each write's wire time
            x, y, theta = emulated_robot.pose
            assert 0.8 * v_mps < x < 1.05 * v_mps and abs(y) < 1e-3 and abs(theta) < 1e-3
            time.sleep(0.2)
            assert emulated_robot.pose == (x, y, theta)
            wheels.stop()


def test_a_bus_opened_by_the_fixture_lets_the_clock_ask_with_the_read(emulated_robot):
    """A loop on the fixture's clock asks for the time after a read as the request goes out."""
    with emulated_robot.open_bus(timeout_margin_s=COUNTING_MARGIN_S) as bus:
        clock = emulated_robot.clock
        clock.ask_after_next_write()
        n = clock.requests
        bus.ping(1)
        assert clock.requests == n + 1                  # sent by the bus's write, not by now()
        t = clock.now()
        assert clock.requests == n + 1 and t == emulated_robot.time_s > 0


def test_an_attached_bus_waits_for_every_reply_the_emulator_sent(bus_in_lockstep):
    """With the clock as its reply gate, an exchange's outcome is what the emulator did, however
    late the host delivers: with no wall-clock margin at all, every reply is still taken, and a
    servo that is gone times out at once (the emulator says it sent nothing)."""
    emu, bus, clock = bus_in_lockstep
    clock.attach(bus)
    # the wire time alone: most replies arrive after it
    with bus.exchanging(ExchangeSettings(retries=0, timeout_margin_s=0.0)):
        for _ in range(50):
            assert bus.ping(2).id == 2
            assert bus.sync_read([1, 2, 3], Reg.PRESENT_POSITION)
        clock.fault("vanish", 3)
        with pytest.raises(DxlTimeoutError) as err:
            bus.sync_read([1, 2, 3], Reg.PRESENT_POSITION)
        assert err.value.ids == (3,)
        assert bus.ping(1).id == 1 and bus.drained_bytes == 0
