"""The online loop against fake wheels on a fake clock: tracking, timing, failure policy."""
from types import SimpleNamespace

import numpy as np
import pytest

from swerve.controller.kinematics import Geometry, Limits, rk4_step
from swerve.controller.ltv import error_system
from swerve.controller.gains_io import GainSchedule
from swerve.tools.run.loop import LoopAbort, TrackingLoop
from swerve.tools.run.ticker import ForegroundClock
from swerve.controller.reference import build_reference
from swerve.controller.trajectory import load_trajectory
from swerve.controller.riccati import finite_horizon_lqr
from swerve.controller.tracking import TrackingLaw
from swerve.driver.errors import DxlTimeoutError, ServoError


class FakeClock(ForegroundClock):
    def __init__(self):
        self.t = 1000.0

    def now(self):
        return self.t

    def sleep_until(self, t):
        self.t = max(self.t, t)


class FakeWheels:
    """Ideal actuators: wheel speed and steering angle reach their goals at once."""

    def __init__(self, clock, geom, state, work_s=0.002):
        self.clock, self.geom, self.work_s = clock, geom, work_s
        self.s = np.asarray(state, float).copy()
        self.v1 = 0.0
        self.t_last = clock.t
        self.fail = None          # callable(read_no) -> exception or None
        self.reads = self.stops = 0

    def _advance(self):
        dt = self.clock.t - self.t_last
        if dt > 0:
            self.s = rk4_step(self.s, [self.v1, 0, 0], dt, self.geom)
        self.t_last = self.clock.t

    def read_state(self):
        self.clock.t += self.work_s
        self._advance()
        self.reads += 1
        if self.fail is not None:
            exc = self.fail(self.reads)
            if exc is not None:
                raise exc
        d1, d2 = self.s[3], self.s[4]
        w = self.v1 / self.geom.wheel_radius_m
        return SimpleNamespace(t_s=self.clock.t, drive_radps=(w,) * 4, drive_rad=None, steer_rad=(d1, d2, d2, d1),
                               drive_current_a=(0.1,) * 4, steer_current_a=(0.0,) * 4)

    def write_goals(self, drive, steer):
        self._advance()
        self.v1 = float(np.mean(drive)) * self.geom.wheel_radius_m
        self.s[3], self.s[4] = steer[0], steer[1]

    def stop(self):
        self.stops += 1
        self.v1 = 0.0


@pytest.fixture(scope="module")
def line_law():
    geom, lim = Geometry(), Limits()
    traj = load_trajectory("line")
    ref = build_reference(traj, geom, lim)
    Ad, Bd = error_system(ref)
    K, _ = finite_horizon_lqr(Ad, Bd, traj.Q, traj.R, traj.tau_s)
    gains = GainSchedule(K, ref.phi_rad[:-1], traj.tau_s, traj.Q, traj.R, traj.name, "riccati", float("nan"))
    return TrackingLaw(ref, gains, lim), traj, geom


def test_loop_tracks_the_line_and_reports_timing(line_law):
    law, traj, geom = line_law
    fc = FakeClock()
    start = traj.start_state(geom)
    wheels = FakeWheels(fc, geom, start)
    cycles = []
    loop = TrackingLoop(wheels, law, geom, time_scale=1.0, clock=fc,
                        true_pose=lambda: wheels.s[:3], on_cycle=cycles.append)
    res = loop.run(start)
    s = res.tracking
    assert res.completed and res.aborted is None
    assert res.cycles == traj.n_steps == len(cycles)
    assert s.error_source == "true_pose"
    assert s.final_position_error_m < 0.02
    assert s.max_abs_v1_mps <= 0.13 + 1e-9
    assert res.timing.overruns == 0 and res.timing.loop_period_p50_ms == pytest.approx(16.0)
    assert s.odometry_vs_true_max_m < 1e-3      # ideal wheels: odometry is exact up to sampling
    assert wheels.stops == 1                       # the loop stops the wheels at the end
    c = cycles[10]
    assert set(c) >= {"cmd_drive_radps", "meas_steer_rad", "est_pose", "ref_pose", "true_pose", "flags"}
    assert c["cmd_drive_radps"].shape == (4,) and c["meas_current_a"].shape == (8,)


def test_missing_servo_aborts_naming_it(line_law):
    law, traj, geom = line_law
    fc = FakeClock()
    wheels = FakeWheels(fc, geom, traj.start_state(geom))
    wheels.fail = lambda n: DxlTimeoutError([7], 0x82, 0.01) if n > 50 else None
    res = TrackingLoop(wheels, law, geom, clock=fc, max_failed_reads=3).run(
        traj.start_state(geom))
    assert isinstance(res.aborted, LoopAbort) and res.aborted.ids == (7,)
    assert "servo ID 7 stopped answering" in str(res.aborted)
    assert res.completed is False and res.aborted.cause == "no reply"
    assert res.failed_reads == 4 and wheels.stops == 1


def test_isolated_timeouts_are_counted_not_fatal(line_law):
    law, traj, geom = line_law
    fc = FakeClock()
    wheels = FakeWheels(fc, geom, traj.start_state(geom))
    wheels.fail = lambda n: DxlTimeoutError([3], 0x82, 0.01) if n % 50 == 0 else None
    res = TrackingLoop(wheels, law, geom, clock=fc).run(traj.start_state(geom))
    assert res.completed
    assert res.failed_reads == traj.n_steps // 50


def test_hardware_alert_aborts_immediately(line_law):
    law, traj, geom = line_law
    fc = FakeClock()
    wheels = FakeWheels(fc, geom, traj.start_state(geom))
    wheels.fail = lambda n: ServoError(2, 0x80, 0x82, hardware_error="overload") if n == 20 else None
    res = TrackingLoop(wheels, law, geom, clock=fc).run(traj.start_state(geom))
    assert res.aborted.cause == "hardware error" and res.aborted.ids == (2,)
    assert "overload" in str(res.aborted)


def test_stall_longer_than_the_watchdog_aborts(line_law):
    law, traj, geom = line_law
    fc = FakeClock()
    wheels = FakeWheels(fc, geom, traj.start_state(geom))

    def stall(n):
        if n == 30:
            fc.t += 0.5          # the process froze for half a second
        return None
    wheels.fail = stall
    res = TrackingLoop(wheels, law, geom, clock=fc, watchdog_s=0.1).run(
        traj.start_state(geom))
    assert res.aborted is not None and res.aborted.cause == "stalled"
    assert "Bus Watchdog" in str(res.aborted) and wheels.stops == 1
    assert 25 <= res.cycles <= 31


def test_a_robot_that_cannot_follow_is_stopped_not_run_forever(line_law):
    law, traj, geom = line_law
    fc = FakeClock()
    wheels = FakeWheels(fc, geom, traj.start_state(geom))
    wheels.write_goals = lambda drive, steer: None     # the wheels ignore every command
    res = TrackingLoop(wheels, law, geom, clock=fc, max_time_factor=1.5).run(
        traj.start_state(geom))
    assert res.aborted is not None and res.aborted.cause == "diverged"
    assert res.cycles <= 1.5 * traj.n_steps + 2
    assert wheels.stops == 1
