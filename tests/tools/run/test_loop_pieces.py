"""Pure pieces of the online loop: absolute-deadline ticker and odometry."""
import numpy as np
import pytest

from swerve.controller.kinematics import Geometry, rk4_step
from swerve.tools.run.ticker import ForegroundClock, Ticker
from swerve.controller.odometry import Odometry, model_inputs


class FakeClock(ForegroundClock):
    def __init__(self):
        self.t = 100.0
        self.work = []          # extra time consumed by each cycle's "work"

    def now(self):
        return self.t

    def sleep_until(self, t):
        assert t > self.t
        self.t = t


def test_ticker_keeps_absolute_deadlines_and_counts_overruns():
    fc = FakeClock()
    tk = Ticker(0.016, clock=fc)
    t0 = tk.start()
    slots = []
    for i in range(10):
        fc.t += 0.050 if i == 4 else 0.003   # one cycle's work takes 50 ms > 3 periods
        slots.append(tk.wait())
        assert fc.t == pytest.approx(t0 + slots[-1] * 0.016)   # woke exactly on a slot: no drift
    assert slots[:4] == [1, 2, 3, 4]
    assert slots[4:6] == [8, 9]                              # slots 5, 6, 7 were missed
    assert tk.stats.overruns == 1 and tk.stats.missed_slots == 3
    s = tk.stats.timing()
    assert s.overruns == 1 and s.loop_period_p50_ms == pytest.approx(16.0)


class BackgroundClock(FakeClock):
    """A clock that sleeps while its caller works (as a lockstep emulator's does)."""

    def __init__(self):
        super().__init__()
        self.log = []

    def start_sleep(self, t):
        self.log.append(("start", t))
        self.asked, self.target = self.t, t

    def end_sleep(self):
        self.log.append(("end", self.target))
        self.t = max(self.t, self.target)
        return self.asked


def test_ticker_runs_the_rest_of_the_cycle_while_a_background_clock_sleeps():
    fc = BackgroundClock()
    tk = Ticker(0.016, clock=fc)
    t0 = tk.start()
    fc.t += 0.003
    k = tk.wait(lambda: fc.log.append("work"))
    assert k == 1 and fc.t == pytest.approx(t0 + 0.016)
    assert fc.log == [("start", t0 + 0.016), "work", ("end", t0 + 0.016)]
    assert tk.last_busy_s == pytest.approx(0.003)       # the time when the sleep was asked


def test_ticker_counts_an_overrun_seen_by_a_background_clock():
    fc = BackgroundClock()
    tk = Ticker(0.016, clock=fc)
    t0 = tk.start()
    fc.t += 0.040                                       # past slots 1 and 2
    assert tk.wait(lambda: None) == 3
    assert fc.t == pytest.approx(t0 + 3 * 0.016)
    assert tk.stats.overruns == 1 and tk.stats.missed_slots == 2


def test_ticker_runs_the_rest_of_the_cycle_first_on_a_plain_clock():
    fc = FakeClock()
    tk = Ticker(0.016, clock=fc)
    t0 = tk.start()
    tk.wait(lambda: setattr(fc, "t", fc.t + 0.020))    # the work itself overruns the period
    assert tk.stats.overruns == 1 and fc.t == pytest.approx(t0 + 2 * 0.016)


def test_ticker_rejects_bad_period():
    with pytest.raises(ValueError):
        Ticker(0.0)


def test_odometry_matches_the_model_on_a_circle():
    g = Geometry()
    delta = np.arctan(2 * g.a_m / 1.0)              # symmetric steering for R = 1 m
    v1, dt = 0.1, 0.016
    odo = Odometry(g)
    s = np.array([0, 0, 0, delta, -delta])
    speeds = np.full(4, v1 / g.wheel_radius_m)
    steer = np.array([delta, -delta, -delta, delta])
    odo.update(dt, speeds, steer)
    for _ in range(500):
        odo.update(dt, speeds, steer)
        s = rk4_step(s, [v1, 0, 0], dt, g)
    np.testing.assert_allclose(odo.pose, s[:3], atol=1e-9)
    # the body moves on a circle of radius R = (a^2+b^2)/(a tan delta) = 1 m about (0, 1)
    assert np.hypot(odo.pose[0], odo.pose[1] - 1.0) == pytest.approx(1.0, rel=1e-3)


def test_model_inputs_average_front_and_rear():
    v1, d1, d2 = model_inputs([1, 1, 1, 1], [0.2, -0.1, -0.3, 0.4])
    assert (v1, d1, d2) == (1.0, pytest.approx(0.3), pytest.approx(-0.2))
    with pytest.raises(ValueError):
        model_inputs([1, 1, 1], [0, 0, 0, 0])


def test_odometry_uses_wheel_angles_over_quantised_speeds():
    g = Geometry()
    step = 0.229 * 2 * np.pi / 60                   # Present Velocity LSB, rad/s
    true_w = 2.0                                    # wheel speed, rad/s (not a multiple of the LSB)
    quantised = np.floor(true_w / step) * step      # what the servo reports
    dt, n = 0.016, 1000
    by_speed, by_angle = Odometry(g), Odometry(g)
    for k in range(n + 1):
        by_speed.update(dt, [quantised] * 4, [0] * 4)
        by_angle.update(dt, [quantised] * 4, [0] * 4, wheel_angles_rad=[true_w * k * dt] * 4)
    distance = true_w * g.wheel_radius_m * n * dt
    assert by_angle.pose[0] == pytest.approx(distance, rel=1e-9)
    assert abs(by_speed.pose[0] - distance) > 1e-3  # the speed LSB biases the distance by mm


def test_odometry_equals_its_algorithm_written_with_numpy():
    """update() in plain floats against the documented algorithm on numpy arrays: means of
    the wheel samples, distance from the angles when both samples have them (else the mean
    speed), steering linear over dt, one RK4 step; dt = 0 only stores the sample."""
    g = Geometry(0.12, 0.1, 0.03)
    rng = np.random.default_rng(5)
    odo = Odometry(g, (0.1, -0.2, 0.3))
    pose, last, prev_angles, angles = np.array([0.1, -0.2, 0.3]), None, None, np.zeros(4)
    for k in range(400):
        speeds, steer = rng.normal(3, 1, 4), rng.normal(0, 0.5, 4)
        angles = angles + speeds * 0.016
        sample_angles = angles if k % 5 else None
        dt = 0.0 if k % 7 == 0 else 0.016 * rng.uniform(0.5, 3)
        v = float(np.mean(speeds * g.wheel_radius_m))
        d1, d2 = float(np.mean(steer[[0, 3]])), float(np.mean(steer[[1, 2]]))
        if last is not None and dt > 0:
            if sample_angles is not None and prev_angles is not None:
                v_bar = g.wheel_radius_m * float(np.mean(sample_angles - prev_angles)) / dt
            else:
                v_bar = 0.5 * (last[0] + v)
            u = [v_bar, (d1 - last[1]) / dt, (d2 - last[2]) / dt]
            pose = rk4_step(np.array([*pose, last[1], last[2]]), u, dt, g, substeps=1)[:3]
        last, prev_angles = (v, d1, d2), sample_angles
        np.testing.assert_allclose(odo.update(dt, speeds, steer, sample_angles), pose,
                                   rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(odo.state, [*pose, d1, d2], rtol=1e-14, atol=1e-15)


def test_cycle_dict_is_a_cycle_record():
    """The loop's on_cycle dict: CycleRecord fields, float64 arrays, NaN while unmeasured."""
    from swerve.tools.run.loop import TrackingLoop
    from swerve.driver.wheelset import WheelState
    from swerve.tools.logs import CycleRecord

    meas = WheelState(1.0, (1.0, 2.0, 3.0, 4.0), (0.0,) * 4, (0.1, 0.2, 0.3, 0.4), (0.0,) * 4,
                      (0.5, 0.6, 0.7, 0.8), (-0.5, -0.6, -0.7, -0.8))
    sd = np.array([1.0, 2.0, 0.3, 0.1, -0.1])
    for m in (meas, None):
        f = TrackingLoop._cycle(3, 0.048, 0.016, [3.0] * 4, [0.1, -0.1, -0.1, 0.1], 0.1, 0.2,
                                -0.2, m, np.array([0.5, 0.6, 0.7]), sd, np.full(3, np.nan), 2, 48_000_000)
        rec = CycleRecord(**f)
        assert rec.stamp_ns == 48_000_000
        for name in ("cmd_drive_radps", "meas_drive_radps", "meas_current_a", "est_pose",
                     "ref_pose", "ref_delta"):
            assert f[name].dtype == np.float64
        np.testing.assert_array_equal(rec.ref_pose, sd[:3])
        np.testing.assert_array_equal(rec.ref_delta, sd[3:])
        if m is None:
            assert np.isnan(rec.meas_current_a).all() and np.isnan(rec.meas_steer_rad).all()
        else:
            np.testing.assert_array_equal(rec.meas_current_a, [*m.drive_current_a, *m.steer_current_a])
            np.testing.assert_array_equal(rec.meas_steer_rad, m.steer_rad)


def test_collector_is_paused_inside_a_timed_loop_and_restored_after():
    import gc

    from swerve.tools.run.ticker import collector_paused

    assert gc.isenabled()
    with collector_paused():
        assert not gc.isenabled() and gc.get_freeze_count() > 0
    assert gc.isenabled() and gc.get_freeze_count() == 0
    gc.disable()                       # a caller that had it off keeps it off
    try:
        with collector_paused():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()



def test_wall_clock_sleeps_until_its_deadline_and_is_a_clock():
    from swerve.tools.run.ticker import Ticker, WallLoopClock

    clock = WallLoopClock()
    assert isinstance(Ticker(0.016).clock, WallLoopClock)   # the default clock
    t = clock.now() + 0.002
    clock.sleep_until(t)
    assert clock.now() >= t
    clock.sleep_until(t - 1.0)                      # a deadline already past returns at once
