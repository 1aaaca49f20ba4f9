"""Who owns simulated time: the clock object the emulator's bus thread calls between requests.

The bus thread (:class:`swerve.emulator.server.Emulator`) serves requests and, whenever none is
waiting, calls ``clock.run(world)``. The clock runs the physics steps it decides are due (each
with ``world.step_many(dt, 1)``, which takes the bus lock for one step) and returns how long the bus thread
may block in ``select`` before calling again. Its behaviour is passed in, as pyserial's
``serial.threaded.ReaderThread(serial, protocol_factory)`` gets its protocol passed in:

* :class:`FrozenClock`: simulated time stands still (a register-only bus; ``emu.advance(dt_s)``
  still steps it by hand, e.g. in tests).
* :class:`WallPhysicsClock`: ``time_scale`` simulated seconds per wall second, in steps of ``1/rate_hz``.

* :class:`LockstepPhysicsClock`: simulated time advances only when asked (Gazebo's lockstep, ROS
  ``use_sim_time``): a client moves it with :meth:`LockstepPhysicsClock.advance_to` (through the control
  channel, :mod:`swerve.emulator.lockstep_socket`), and every bus exchange is charged at its wire time.

Besides ``run``, a clock sees each exchange: :meth:`PhysicsClock.on_request` once an instruction
has arrived (``wire_s``: its bytes at the line speed) and :meth:`PhysicsClock.on_replies` before
the replies go out. A wall-paced clock ignores both (the server then paces replies in wall time);
the lockstep clock charges them in simulated time. It runs the physics up to an instruction's
arrival before the instruction executes; the steps that replies or an ``advance`` owe it runs
after the answer has gone out (in ``run``, or in :meth:`PhysicsClock.catch_up` when the true
state is asked for first), so the client works while the emulator steps.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from dataclasses import dataclass
from typing import Protocol

from swerve.driver.errors import ConfigError

log = logging.getLogger(__name__)

#: Longest the clock runs steps before re-reading the wall clock and its backlog, s.
MAX_BATCH_WALL_S = 2e-3
#: Pause after a step when another thread waits for the bus lock, s.
HAND_OVER_S = 5e-5
#: Shortest wait of the clock when it is ahead (batches steps at high time scales), s.
MIN_SLEEP_S = 1e-3
#: Backlog (wall seconds of demanded steps) beyond which simulated time is dropped and counted.
MAX_BACKLOG_WALL_S = 0.5


class StepWorld(Protocol):
    """What the emulator offers its clock (implemented by :class:`~swerve.emulator.server.Emulator`)."""

    def step(self, dt_s: float) -> None:
        """Advance every servo (and the body, if any) by ``dt_s`` simulated s, under the bus lock."""

    def step_many(self, dt_s: float, n: int) -> None:
        """``n`` :meth:`step` s with the same result, as few times under the lock as it allows."""

    def request_pending(self) -> bool:
        """True if bytes from the client wait: the clock should return soon so requests go first."""

    def lock_wanted(self) -> bool:
        """True if another thread waits for the bus lock (the clock should pause briefly)."""

    def wake(self) -> None:
        """Make the bus thread call :meth:`PhysicsClock.run` again now (from any thread)."""


class PhysicsClock(Protocol):
    """The emulator's owner of simulated time (see the module docstring)."""

    rate_hz: float            # physics steps per simulated second
    stats: "ClockStats"
    reply_latency_s: float    # a servo's time to start answering that the clock charges, s (0: none)
    now_s: float | None       # robot time the clock keeps, s; None: the physics time is robot time

    def run(self, world: StepWorld) -> float:
        """Run the steps that are due; return wall seconds the bus thread may block (``inf``: until
        a request or :meth:`StepWorld.wake`). Called by the bus thread only, between requests."""

    def on_request(self, world: StepWorld, wire_s: float) -> None:
        """An instruction of ``wire_s`` seconds on the wire has arrived (before it is executed)."""

    def on_replies(self, world: StepWorld, wire_s: float, replies: int, hold_s: float = 0.0) -> bool:
        """``replies`` status frames totalling ``wire_s`` (bytes, return delays) are due, and the
        USB adapter holds the last byte ``hold_s`` after it left the cable. True: the clock
        charged them in simulated time, so they go out at once; False: the server paces them in
        wall time."""

    def catch_up(self, world: StepWorld) -> None:
        """Run the steps simulated time has passed but the physics has not yet (a lockstep clock
        leaves those owed by replies and ``move_to`` for later); the emulator calls it before the
        true state is read or a fault applied."""


class RobotTimeClock(PhysicsClock, Protocol):
    """A :class:`PhysicsClock` that keeps robot time of its own (``now_s`` is never None) and
    moves it on a client's request: the clock a lockstep control channel needs
    (:class:`LockstepPhysicsClock`)."""

    now_s: float

    def move_to(self, t_s: float) -> float:
        """Move robot time to ``t_s`` (never back); the physics follows in :meth:`PhysicsClock.run`
        or :meth:`PhysicsClock.catch_up`. Returns the new robot time, s."""


@dataclass
class ClockStats:
    """How the physics clock kept up with wall time (written by the bus thread)."""

    time_scale: float = 0.0
    rate_hz: float = 0.0
    wall_s: float = 0.0         # wall time since the clock started
    steps: int = 0              # physics steps run by the clock
    batches: int = 0            # runs of back-to-back steps (one per wake-up or 2 ms of work)
    backlog_s: float = 0.0      # simulated time owed right now (steps due but not yet run)
    max_backlog_s: float = 0.0  # largest simulated time the clock was behind wall time * scale
    fell_behind: int = 0        # times the backlog exceeded MAX_BACKLOG_WALL_S and time was dropped
    lost_sim_s: float = 0.0     # simulated time dropped then (the world ran slower than scale)
    cpu_s: float = 0.0          # CPU time spent in physics steps (thread_time)

    @property
    def achieved_scale(self) -> float:
        """Simulated seconds delivered per wall second (``time_scale`` when it kept up)."""
        return self.steps / self.rate_hz / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per CPU second of physics (servos, body, clock upkeep)."""
        return self.steps / self.rate_hz / self.cpu_s if self.cpu_s > 0 else math.inf

    def as_dict(self) -> dict[str, float | None]:
        """All fields plus the two ratios; a ratio without data (no CPU time yet) is ``None``."""
        d = dataclasses.asdict(self)
        d.update(achieved_scale=self.achieved_scale, real_time_factor=self.real_time_factor)
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


class WallPacedClock:
    """The :class:`PhysicsClock` members of a clock whose bus exchanges take wall time: it keeps
    no robot time of its own, charges no exchange, and never owes the physics steps."""

    reply_latency_s = 0.0      # the emulator's own answering time is real
    now_s = None

    def on_request(self, world: StepWorld, wire_s: float) -> None:
        pass

    def on_replies(self, world: StepWorld, wire_s: float, replies: int, hold_s: float = 0.0) -> bool:
        return False

    def catch_up(self, world: StepWorld) -> None:
        pass


class FrozenClock(WallPacedClock):
    """Simulated time stands still; the bus only answers (``emu.advance`` steps by hand)."""

    def __init__(self, rate_hz: float = 1000.0):
        if not rate_hz > 0:
            raise ConfigError(f"clock rate must be > 0 Hz, got {rate_hz:g}")
        self.rate_hz = float(rate_hz)
        self.stats = ClockStats(time_scale=0.0, rate_hz=self.rate_hz)

    def run(self, world: StepWorld) -> float:
        return math.inf


class WallPhysicsClock(WallPacedClock):
    """``time_scale`` simulated seconds per wall second, in fixed steps of ``1/rate_hz``.

    Runs the steps wall time demands (``time_scale * rate_hz`` per wall second) back to back until
    caught up, until a request arrives, or for :data:`MAX_BATCH_WALL_S`; a request thus waits for
    one step at most, and physics never competes with the bus for the interpreter lock. Beyond
    :data:`MAX_BACKLOG_WALL_S` of backlog, simulated time is dropped and counted in :attr:`stats`
    (``lost_sim_s``, ``fell_behind``) instead of slowing down silently.
    """

    def __init__(self, time_scale: float = 1.0, rate_hz: float = 1000.0):
        if not (math.isfinite(time_scale) and time_scale > 0):
            raise ConfigError(f"time scale must be > 0 for a wall clock, got {time_scale:g}")
        if not rate_hz > 0:
            raise ConfigError(f"clock rate must be > 0 Hz, got {rate_hz:g}")
        self.time_scale = float(time_scale)
        self.rate_hz = float(rate_hz)
        self.stats = ClockStats(time_scale=self.time_scale, rate_hz=self.rate_hz)
        self._t0: float | None = None     # wall time of the first call
        self._skipped = 0                 # steps dropped when the clock fell behind

    def run(self, world: StepWorld) -> float:
        st = self.stats
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = now
        dt = 1.0 / self.rate_hz
        steps_per_wall_s = self.rate_hz * self.time_scale
        st.wall_s = now - self._t0
        backlog = int(st.wall_s * steps_per_wall_s) - self._skipped - st.steps
        if backlog <= 0:
            due = self._t0 + (st.steps + self._skipped + 1) / steps_per_wall_s
            return max(MIN_SLEEP_S, due - now)
        max_backlog = max(1, int(MAX_BACKLOG_WALL_S * steps_per_wall_s))
        if backlog > max_backlog:
            drop = backlog - max_backlog
            self._skipped += drop
            backlog = max_backlog
            st.fell_behind += 1
            st.lost_sim_s += drop * dt
            if st.fell_behind == 1:
                log.warning("physics clock fell behind at time scale %g; dropping simulated time "
                            "(see clock_stats)", self.time_scale)
        st.max_backlog_s = max(st.max_backlog_s, backlog * dt)
        cpu0 = time.thread_time()
        deadline = now + MAX_BATCH_WALL_S
        n = 0
        try:
            while n < backlog:
                world.step_many(dt, 1)     # one step, compiled where the world can be
                n += 1
                if world.request_pending():
                    break
                if world.lock_wanted():
                    time.sleep(HAND_OVER_S)   # let a waiting thread (faults, pose readers) take the lock
                if n & 7 == 0 and time.monotonic() > deadline:
                    break
        finally:
            n = max(n, 1)                     # a step that raised still counts (no retry storm)
            st.steps += n
            st.batches += 1
            st.backlog_s = (backlog - n) * dt
            st.cpu_s += time.thread_time() - cpu0
        return 0.0 if n < backlog else MIN_SLEEP_S


#: Time a servo takes to start answering once an instruction has arrived, on top of its Return
#: Delay Time, s (UNCONFIRMED: 50 us per servo, as reported for MX-series buses at RoboCup).
DEFAULT_REPLY_LATENCY_S = 50e-6
#: Slack when a requested time is compared with the step grid, in steps (float round-off).
_GRID_SLACK = 1e-6


class LockstepPhysicsClock:
    """Simulated time that advances only when asked; the bus costs what it would on the cable.

    :attr:`now_s` is robot time (s since start). It moves forward in two ways, both in the bus
    thread: :meth:`advance_to` or :meth:`move_to` (a client's request through the control
    channel), and every bus exchange: the instruction's bytes (``on_request``), then per reply
    the Return Delay Time, ``reply_latency_s`` and its bytes (``on_replies``). The physics runs
    every whole step of ``1/rate_hz`` up to :attr:`now_s`: before an instruction executes (so a
    read sees the state at the time its instruction ended on the wire, to one step), in
    :meth:`advance_to`, and otherwise in :meth:`run` or :meth:`catch_up`. The steps replies and
    :meth:`move_to` owe thus run after the answer is out, while the client works; nothing the
    bus or the control channel serves reads the world in between (a reader in the emulator's
    own process syncs through a ``pose`` request). At a requested time on the step grid the physics stands
    exactly there. Once caught up, :meth:`run` lets the bus thread sleep until the next
    request: a client that stops asking leaves the robot paused. ``stats.achieved_scale`` is
    then the real-time factor (robot s per wall s).
    """

    def __init__(self, rate_hz: float = 1000.0, reply_latency_s: float = DEFAULT_REPLY_LATENCY_S):
        if not rate_hz > 0:
            raise ConfigError(f"clock rate must be > 0 Hz, got {rate_hz:g}")
        if not (math.isfinite(reply_latency_s) and reply_latency_s >= 0):
            raise ConfigError(f"reply latency must be >= 0 s, got {reply_latency_s:g}")
        self.rate_hz = float(rate_hz)
        self.reply_latency_s = float(reply_latency_s)
        self.stats = ClockStats(time_scale=0.0, rate_hz=self.rate_hz)
        self.now_s = 0.0
        self.bus_s = 0.0                  # robot time spent on bus exchanges
        self._t0: float | None = None     # wall time of the first call

    def run(self, world: StepWorld) -> float:
        self._run_to(world)     # the steps owed by replies or move_to, if any
        return math.inf

    def catch_up(self, world: StepWorld) -> None:
        self._run_to(world)

    def move_to(self, t_s: float) -> float:
        """Move robot time to ``t_s`` (never back); the physics follows in :meth:`run` or
        :meth:`catch_up`. Returns :attr:`now_s`."""
        if not math.isfinite(t_s):
            raise ConfigError(f"cannot advance to t = {t_s!r} s")
        self.now_s = max(self.now_s, float(t_s))
        return self.now_s

    def advance_to(self, world: StepWorld, t_s: float) -> float:
        """Move robot time to ``t_s`` (never back) and run the physics there; returns :attr:`now_s`."""
        self.move_to(t_s)
        self._run_to(world)
        return self.now_s

    def on_request(self, world: StepWorld, wire_s: float) -> None:
        self.now_s += wire_s
        self.bus_s += wire_s
        self._run_to(world)

    def on_replies(self, world: StepWorld, wire_s: float, replies: int, hold_s: float = 0.0) -> bool:
        cost = wire_s + replies * self.reply_latency_s + hold_s
        self.now_s += cost
        self.bus_s += cost
        return True

    def _run_to(self, world: StepWorld) -> None:
        st = self.stats
        now = time.monotonic()
        if self._t0 is None:
            self._t0 = now
        due = math.floor(self.now_s * self.rate_hz + _GRID_SLACK) - st.steps
        if due > 0:
            dt = 1.0 / self.rate_hz
            cpu0 = time.thread_time()
            try:
                world.step_many(dt, due)    # no bus event can come between these steps
            finally:
                st.steps += due         # a run that raised still counts (no retry storm)
                st.batches += 1
                st.cpu_s += time.thread_time() - cpu0
        st.wall_s = time.monotonic() - self._t0


def clock_for(time_scale: float, rate_hz: float = 1000.0) -> PhysicsClock:
    """:class:`WallPhysicsClock` at ``time_scale``, or :class:`FrozenClock` for ``time_scale == 0``."""
    if time_scale < 0:
        raise ConfigError(f"time scale must be >= 0, got {time_scale:g}")
    return WallPhysicsClock(time_scale, rate_hz) if time_scale > 0 else FrozenClock(rate_hz)


class HandOverLock:
    """The emulator's one lock, plus who is waiting for it (so the clock can step aside).

    A plain :class:`threading.Lock` is not fair: a clock that releases it and takes it
    again at once starves another thread waiting for it (fault injection, pose readers).
    The clock checks :attr:`waiting` after each physics step and pauses only then, so it
    loses no time when nobody waits. ``set.add``/``discard`` are atomic.
    """

    def __init__(self):
        self._lock = threading.Lock()
        self.waiting: set[int] = set()

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        if self._lock.acquire(False):
            return True
        if not blocking:
            return False
        me = threading.get_ident()
        self.waiting.add(me)
        try:
            return self._lock.acquire(True, timeout)
        finally:
            self.waiting.discard(me)

    def release(self) -> None:
        self._lock.release()

    def locked(self) -> bool:
        return self._lock.locked()

    __enter__ = acquire

    def __exit__(self, *exc) -> None:
        self._lock.release()
