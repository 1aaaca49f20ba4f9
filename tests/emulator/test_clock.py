"""The clock objects on a fake world and a fake wall clock: which steps they run, when they
yield to a request, how they account for time they cannot deliver. No real time passes."""
from __future__ import annotations

import math

import pytest

from swerve.driver.errors import ConfigError
from swerve.emulator import clock as clk
from swerve.emulator.clock import FrozenClock, WallPhysicsClock, clock_for


class FakeWorld:
    """Counts steps; a request arrives after ``request_after`` steps; the lock is never wanted."""

    def __init__(self, request_after: int | None = None):
        self.dts: list[float] = []
        self.request_after = request_after

    def step(self, dt_s: float) -> None:
        self.dts.append(dt_s)

    def step_many(self, dt_s: float, n: int) -> None:
        for _ in range(n):
            self.step(dt_s)

    def request_pending(self) -> bool:
        return self.request_after is not None and len(self.dts) >= self.request_after

    def lock_wanted(self) -> bool:
        return False

    def wake(self) -> None:
        pass


@pytest.fixture
def wall(monkeypatch):
    """A settable monotonic clock, seen by the clock module only."""
    now = [0.0]
    monkeypatch.setattr(clk.time, "monotonic", lambda: now[0])
    return now


def test_frozen_clock_never_steps():
    c, world = FrozenClock(2000.0), FakeWorld()
    assert c.run(world) == math.inf and world.dts == []
    assert c.rate_hz == 2000.0 and c.stats.steps == 0


def test_wall_clock_runs_what_wall_time_demands(wall):
    c, world = WallPhysicsClock(time_scale=2.0, rate_hz=1000.0), FakeWorld()
    wait = c.run(world)                       # starts the clock: nothing owed yet
    assert world.dts == [] and wait == pytest.approx(clk.MIN_SLEEP_S)
    wall[0] += 0.010                          # 10 ms of wall time at 2x: 20 steps of 1 ms
    assert c.run(world) == clk.MIN_SLEEP_S
    assert world.dts == [pytest.approx(1e-3)] * 20
    assert (c.stats.steps, c.stats.batches, c.stats.lost_sim_s) == (20, 1, 0.0)


def test_wall_clock_yields_to_a_pending_request(wall):
    c, world = WallPhysicsClock(1.0, 1000.0), FakeWorld(request_after=3)
    c.run(world)
    wall[0] += 0.010                          # 10 steps owed
    assert c.run(world) == 0.0                # more is owed: come back at once
    assert len(world.dts) == 3 and c.stats.backlog_s == pytest.approx(7e-3)
    world.request_after = None
    c.run(world)
    assert len(world.dts) == 10               # the rest, delivered later


def test_wall_clock_drops_and_counts_a_backlog_beyond_the_limit(wall):
    c, world = WallPhysicsClock(1.0, 1000.0), FakeWorld()
    c.run(world)
    wall[0] += 2.0                            # a 2 s stall: 2000 steps owed, 500 kept
    while c.run(world) == 0.0:
        pass
    assert c.stats.fell_behind == 1
    assert c.stats.lost_sim_s == pytest.approx(2.0 - clk.MAX_BACKLOG_WALL_S)
    assert len(world.dts) == round(clk.MAX_BACKLOG_WALL_S * 1000)
    # every demanded second is delivered or reported lost
    assert len(world.dts) * 1e-3 + c.stats.lost_sim_s == pytest.approx(2.0)


def test_clock_for_and_bad_settings():
    assert isinstance(clock_for(0.0, 500.0), FrozenClock)
    assert isinstance(clock_for(3.0), WallPhysicsClock)
    for bad in (lambda: clock_for(-1.0), lambda: WallPhysicsClock(0.0), lambda: WallPhysicsClock(1.0, 0.0),
                lambda: FrozenClock(-5.0)):
        with pytest.raises(ConfigError):
            bad()


class StepsOnRequest(clk.WallPacedClock):
    """A clock that only steps when asked (the shape of a lockstep clock), to test the seam."""

    def __init__(self, rate_hz: float = 1000.0):
        self.rate_hz = rate_hz
        self.stats = clk.ClockStats(rate_hz=rate_hz)
        self.owed = 0
        self.calls = 0

    def request(self, emu, steps: int) -> None:
        self.owed += steps
        emu.wake()

    def run(self, world) -> float:
        self.calls += 1
        while self.owed:
            world.step(1.0 / self.rate_hz)
            self.owed -= 1
            self.stats.steps += 1
        return math.inf


def _wait(predicate, limit_s: float = 10.0) -> bool:
    """Poll until ``predicate()``; the limit only ends a failing test."""
    import time

    end = time.monotonic() + limit_s
    while not predicate() and time.monotonic() < end:
        time.sleep(0.001)
    return predicate()


def test_a_clock_passed_in_owns_simulated_time():
    from swerve.emulator.server import Emulator
    from swerve.emulator.servo import make_servos

    c = StepsOnRequest()
    with Emulator(make_servos([1], "xh430-w210", 1_000_000), clock=c) as emu:
        assert _wait(lambda: c.calls > 0)        # the bus thread called it; nothing was owed
        assert emu.sim_time_s == 0.0
        c.request(emu, 250)
        assert _wait(lambda: c.stats.steps == 250)
        with emu.lock:
            assert emu.sim_time_s == pytest.approx(0.250)
            assert emu.servo(1).read("realtime_tick") == 250


def test_lockstep_clock_steps_only_when_asked_and_exactly_to_the_step_grid():
    from swerve.emulator.clock import LockstepPhysicsClock

    c, world = LockstepPhysicsClock(rate_hz=1000.0, reply_latency_s=50e-6), FakeWorld()
    assert c.run(world) == math.inf and world.dts == []        # nobody asked: nothing runs
    assert c.advance_to(world, 0.016) == 0.016
    assert len(world.dts) == 16 and c.stats.steps == 16
    assert c.advance_to(world, 0.010) == 0.016 and len(world.dts) == 16    # never back
    assert c.run(world) == math.inf and len(world.dts) == 16
    for k in range(1, 1001):                  # float deadlines t0 + k * period land on the grid
        c.advance_to(world, 0.016 + k * 0.016)
        assert c.stats.steps == 16 * (k + 1)


def test_lockstep_clock_charges_requests_and_replies_and_runs_the_physics_through_them():
    from swerve.emulator.clock import LockstepPhysicsClock

    c, world = LockstepPhysicsClock(rate_hz=1000.0, reply_latency_s=50e-6), FakeWorld()
    c.on_request(world, 1.2e-3)               # the instruction ends on the wire at 1.2 ms
    assert len(world.dts) == 1 and c.now_s == pytest.approx(1.2e-3)    # it executes at 1 ms
    assert c.on_replies(world, 1.0e-3, replies=8) is True      # 1 ms of frames + 8 x 50 us
    assert c.now_s == pytest.approx(2.6e-3) and c.bus_s == pytest.approx(2.6e-3)
    assert len(world.dts) == 1                # the replies' steps wait until they are out:
    assert c.run(world) == math.inf           # the bus thread runs them before it blocks
    assert len(world.dts) == 2                # the physics stands at 2 ms, the last whole step
    c.on_replies(world, 1.0e-3, replies=0)
    c.catch_up(world)                         # or before the true state is read
    assert len(world.dts) == 3


def test_lockstep_clock_move_to_leaves_the_physics_to_run_or_catch_up():
    from swerve.emulator.clock import LockstepPhysicsClock

    c, world = LockstepPhysicsClock(rate_hz=1000.0), FakeWorld()
    assert c.move_to(0.016) == 0.016 and world.dts == []       # the answer can go out first
    assert c.move_to(0.010) == 0.016                           # never back
    c.catch_up(world)
    assert len(world.dts) == 16 and c.stats.steps == 16
    c.move_to(0.032)
    assert c.run(world) == math.inf and c.stats.steps == 32
    with pytest.raises(ConfigError):
        c.move_to(math.inf)


def test_wall_and_frozen_clocks_leave_reply_pacing_to_the_server():
    world = FakeWorld()
    for c in (FrozenClock(), WallPhysicsClock(1.0)):
        c.on_request(world, 1e-3)
        assert c.on_replies(world, 1e-3, 1) is False and world.dts == []


def test_lockstep_clock_rejects_bad_settings():
    from swerve.emulator.clock import LockstepPhysicsClock

    with pytest.raises(ConfigError):
        LockstepPhysicsClock(rate_hz=0.0)
    with pytest.raises(ConfigError):
        LockstepPhysicsClock(reply_latency_s=-1e-6)
    with pytest.raises(ConfigError):
        LockstepPhysicsClock().advance_to(FakeWorld(), math.nan)
