"""The emulated robot driven through the bus with the project's WheelSet.

The robot is moved only by bus traffic (one Bulk Write of goals and one Sync Read of state per
16 ms cycle, as the controller does); the true pose comes from the emulator's in-process API or
its status file, never from the bus. Deterministic tests step simulated time with
``emu.advance``; one test runs the physics clock at 5x real time and checks generous bounds only.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import load_robot_config
from swerve.driver.wheelset import WheelSet
from swerve.emulator.physics.params import SensorParams
from swerve.emulator.clock import HandOverLock
from swerve.emulator.factory import robot_emulator
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.timing import Frozen, WallTime
from swerve.emulator.sensor_noise import parse_noise
from swerve.emulator.status_file import read_status, status

ROOT = Path(__file__).resolve().parents[2]
#: Reply-timeout margin: generous, because an in-process emulator on a loaded 2-core machine
#: can stall for hundreds of ms; with timing=Frozen() nothing is ever lost, so it costs nothing.
MARGIN_S = 1.0
ROBOT = ROOT / "configs" / "robot.yaml"
PHYSICS = ROOT / "configs" / "emulator.yaml"
CFG = load_robot_config(ROBOT)
A_M = CFG.wheels[0].x_m
B_M = CFG.wheels[0].y_m
PERIOD_S = 0.016
V1_MPS = 0.1


def drive(v_radps, steer_rad, seconds: float, **kwargs):
    """Drive the robot for ``seconds`` of simulated time; return the pose log (n, 4) of
    ``(t_s, x, y, theta)`` after each cycle, the last WheelState and the final status."""
    with robot_emulator(ROBOT, PHYSICS, timing=Frozen(), **kwargs) as emu, \
            Bus(emu.port, emu.baud, timeout_margin_s=MARGIN_S) as bus, WheelSet(bus, CFG) as wheels:
        wheels.configure()
        wheels.enable()
        log = []
        for _ in range(round(seconds / PERIOD_S)):
            wheels.write_goals(v_radps, steer_rad)
            state = wheels.read_state()
            emu.advance(PERIOD_S)
            log.append((emu.sim_time_s, *emu.pose))
        with emu.lock:
            doc = status(emu)
        return np.array(log), state, doc


def test_equal_speeds_zero_steering_drive_straight_at_v1():
    log, state, status = drive([V1_MPS / CFG.wheel_radius_m] * 4, [0.0] * 4, 3.0)
    half = len(log) // 2                      # after the e-Manual-default PI has settled (0.43 s)
    speed = (log[-1, 1] - log[half, 1]) / (log[-1, 0] - log[half, 0])
    assert speed == pytest.approx(V1_MPS, rel=0.01)
    assert abs(log[-1, 2]) < 1e-3 and abs(log[-1, 3]) < 1e-3      # no sideways drift, no turn
    assert state.drive_radps == pytest.approx([V1_MPS / CFG.wheel_radius_m] * 4, rel=0.01)
    assert status["slip_rms_mps"] < 1e-6                            # the wheels agree


@pytest.mark.parametrize("delta", [0.3, -0.5], ids=["left-0.3rad", "right-0.5rad"])
def test_symmetric_steering_gives_the_kinematic_radius(delta):
    """Front wheels at δ, rear at −δ, all at v1: the paper's (1)–(3) give ẋ_b = v1 cos δ,
    θ̇ = a sin δ / (a² + b²) · v1, so the radius is R = (a² + b²) / (a tan δ)."""
    log, state, status = drive([V1_MPS / CFG.wheel_radius_m] * 4, [delta, -delta, -delta, delta], 4.0)
    steady = log[len(log) // 2:]
    arc = np.sum(np.hypot(np.diff(steady[:, 1]), np.diff(steady[:, 2])))
    radius = arc / (steady[-1, 3] - steady[0, 3])                     # signed: + = turning left
    predicted = (A_M ** 2 + B_M ** 2) / (A_M * math.tan(delta))
    assert radius == pytest.approx(predicted, rel=0.01)
    assert state.steer_rad == pytest.approx([delta, -delta, -delta, delta], abs=2e-3)
    assert status["slip_rms_mps"] > 1e-3      # equal speeds on a curve: the fit reports the misfit


def test_mismatched_wheels_follow_the_least_squares_fit():
    """Left wheels at v1, right wheels stopped, no steering: the least-squares twist of
    emulator/physics/body.py is vx = v1/2, ω = −b v1 / (2 (a² + b²)) (turning right)."""
    v = V1_MPS / CFG.wheel_radius_m
    log, _, status = drive([v, v, 0.0, 0.0], [0.0] * 4, 2.0)
    steady = log[len(log) // 2:]
    omega = (steady[-1, 3] - steady[0, 3]) / (steady[-1, 0] - steady[0, 0])
    assert omega == pytest.approx(-B_M * V1_MPS / (2 * (A_M ** 2 + B_M ** 2)), rel=0.02)
    assert status["twist"][0] == pytest.approx(V1_MPS / 2, rel=0.02)
    assert status["slip_rms_mps"] > 0.01


def test_start_pose_is_honoured():
    log, _, _ = drive([V1_MPS / CFG.wheel_radius_m] * 4, [0.0] * 4, 1.0, body=BodySettings(start_pose=(1.0, -2.0, math.pi / 2)))
    x, y, theta = log[-1, 1:]
    assert x == pytest.approx(1.0, abs=1e-3)          # heading +y: x stays, y grows
    assert y > -2.0 + 0.05
    assert theta == pytest.approx(math.pi / 2, abs=1e-3)


def test_wall_clock_at_time_scale_5_with_status_file(tmp_path):
    """Wall clock on: the robot drives, the status file follows, the clock accounts for every
    demanded simulated second (delivered or reported lost). Generous bounds only: on a loaded
    machine the physics may not reach 5x (it then reports the dropped time)."""
    status_path = tmp_path / "status.json"
    scale = 5.0
    switch_before = sys.getswitchinterval()
    with robot_emulator(ROBOT, PHYSICS, timing=WallTime(scale), status_file=status_path) as emu, \
            Bus(emu.port, emu.baud, timeout_margin_s=0.5) as bus, WheelSet(bus, CFG) as wheels:
        wall0 = time.monotonic()
        sim0 = emu.sim_time_s
        wheels.configure()
        # 100 ms of simulated watchdog is 20 ms of wall time here: a descheduled test process
        # would trip it. This test is about the clock, so the watchdog is off.
        bus.sync_write(Reg.BUS_WATCHDOG, {i: 0 for i in wheels.ids})
        wheels.enable()
        first = read_status(status_path)
        drive_t0, (x0, _, _) = emu.sim_time_s, emu.pose
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            wheels.write_goals([V1_MPS / CFG.wheel_radius_m] * 4, [0.0] * 4)
            state = wheels.read_state()
            time.sleep(PERIOD_S / scale)
        stats = emu.clock_stats.as_dict()                 # snapshot (the clock goes on)
        wall = time.monotonic() - wall0
        sim = emu.sim_time_s - sim0
        driven_s = emu.sim_time_s - drive_t0
        x, y, _ = emu.pose
        time.sleep(0.2)                                   # > 2 status periods (20 Hz)
        last = read_status(status_path)
    final = read_status(status_path)                      # written again at close
    assert sys.getswitchinterval() == switch_before       # the process-wide setting is restored
    assert sim > 0.5 * wall                               # the clock ran (5x if the CPU allows)
    # every owed second is delivered, dropped (and counted) or still owed (the backlog)
    assert sim + stats["lost_sim_s"] + stats["backlog_s"] == pytest.approx(scale * wall, rel=0.2)
    assert (stats["lost_sim_s"] > 0) == (stats["fell_behind"] > 0)
    assert x - x0 > 0.5 * V1_MPS * (driven_s - 0.5)       # PI settles in 0.43 s, then 0.1 m/s
    assert abs(y) < 0.01 * (x - x0) + 1e-3
    assert state.drive_radps[0] > 0
    assert last["t_s"] > first["t_s"] and last["pose"][0] > first["pose"][0]
    assert final["t_s"] >= last["t_s"]
    assert set(final) >= {"t_s", "pose", "twist", "wheels", "slip_rms_mps", "clock"}
    assert [w["name"] for w in final["wheels"]] == [w.name for w in CFG.wheels]


def test_status_file_holds_the_true_pose_at_close(tmp_path):
    """Deterministic: with a frozen clock the status file is written at start, and last at close."""
    path = tmp_path / "pose.json"
    with robot_emulator(ROBOT, PHYSICS, timing=Frozen(), status_file=path, body=BodySettings(start_pose=(0.5, 0.0, 0.0))) as emu, \
            Bus(emu.port, emu.baud, timeout_margin_s=MARGIN_S) as bus, WheelSet(bus, CFG) as wheels:
        assert read_status(path)["pose"] == [0.5, 0.0, 0.0] and read_status(path)["t_s"] == 0.0
        wheels.configure()
        wheels.enable()
        for _ in range(40):
            wheels.write_goals([V1_MPS / CFG.wheel_radius_m] * 4, [0.0] * 4)
            wheels.read_state()       # a round trip: the (reply-less) Bulk Write has landed
            emu.advance(PERIOD_S)
        t_s, pose = emu.true_state()
        assert (t_s, pose) == (emu.sim_time_s, emu.pose)
    text = path.read_text()
    assert "Infinity" not in text and "NaN" not in text        # strict JSON for any reader
    doc = read_status(path)
    assert doc["t_s"] == pytest.approx(t_s) and doc["t_s"] == pytest.approx(40 * PERIOD_S)
    assert doc["pose"] == pytest.approx(list(pose))
    assert doc["pose"][0] > 0.5 + 0.02
    assert doc["wheels"][0]["speed_mps"] == pytest.approx(V1_MPS, rel=0.02)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["pose.json"]   # no temp file left


def test_noise_spec_parses_and_rejects():
    base = SensorParams()
    params, seed = parse_noise("position=0.5, current=0.003,seed=7", base)
    assert (params.position_noise_std_pulse, params.current_noise_std_a, params.voltage_noise_std_v,
            seed) == (0.5, 0.003, 0.0, 7)
    assert parse_noise(None, base) == (base, None)
    with pytest.raises(ConfigError, match="unknown key 'temperature'"):
        parse_noise("temperature=1", base)
    with pytest.raises(ConfigError, match="standard deviation"):
        parse_noise("voltage=-1", base)
    with pytest.raises(ConfigError, match="key=value"):
        parse_noise("position", base)


def test_position_noise_reaches_the_bus():
    """With encoder noise the steering servos' Present Position jitters around the goal."""
    with robot_emulator(ROBOT, PHYSICS, timing=Frozen(), noise="position=2,seed=3") as emu, \
            Bus(emu.port, emu.baud, timeout_margin_s=MARGIN_S) as bus, WheelSet(bus, CFG) as wheels:
        wheels.configure()
        wheels.enable()
        angles = []
        for _ in range(20):
            wheels.write_goals([0.0] * 4, [0.2] * 4)
            angles.append(wheels.read_state().steer_rad[0])
            emu.advance(PERIOD_S)
    assert len(set(angles[10:])) > 1
    assert np.mean(angles[10:]) == pytest.approx(0.2, abs=0.01)


def test_robot_config_ids_must_be_on_the_bus():
    with pytest.raises(ConfigError, match="not on the emulated bus"):
        robot_emulator(ROBOT, PHYSICS, timing=Frozen(), ids=[1, 2, 3, 4, 5, 6, 7], body=BodySettings())


def test_hand_over_lock_shows_who_waits():
    """The clock steps aside only when someone waits: the lock must report waiters, then forget them."""
    lock = HandOverLock()
    got = threading.Event()

    def contender():
        with lock:
            got.set()

    with lock:
        t = threading.Thread(target=contender)
        t.start()
        deadline = time.monotonic() + 5.0
        while not lock.waiting and time.monotonic() < deadline:
            time.sleep(0.001)
        assert lock.waiting == {t.ident}
        assert not got.is_set()
    assert got.wait(5.0)
    t.join(5.0)
    assert lock.waiting == set() and not lock.locked()
    assert lock.acquire(blocking=False) and not lock.acquire(blocking=False)
    lock.release()
