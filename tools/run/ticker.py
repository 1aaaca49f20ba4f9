"""Periodic loop timing on a clock passed in: absolute deadlines, counted overruns.

The k-th cycle is due at ``t0 + k * period_s``; the schedule never drifts with the work done
in a cycle. A cycle whose work runs past its successor's deadline is an *overrun*: the missed
slots are skipped (so slot index and trajectory time stay aligned with the clock) and counted.

The clock is a :class:`Clock`: the robot uses :class:`WallLoopClock` (the monotonic clock); a
lockstep emulator run uses robot time (:class:`swerve.tools.run.lockstep.LockstepLoopClock`); tests
pass a fake one. A clock whose sleeps take its caller's time subclasses :class:`ForegroundClock`
for the members such a clock does nothing in.
"""
from __future__ import annotations

import contextlib
import gc
import time
from dataclasses import dataclass, field
from typing import Callable, Protocol

import numpy as np

from swerve.tools.run.summary import LoopTiming


class Clock(Protocol):
    """Where a loop's time comes from: seconds on a monotonic scale."""

    def now(self) -> float:
        """Current time, s."""

    def sleep_until(self, t: float) -> None:
        """Return once :meth:`now` is at or past ``t`` (s)."""

    def stamp_ns(self) -> int:
        """A log stamp for the current cycle, ns."""

    def start_sleep(self, t: float) -> None:
        """Ask for a sleep until ``t`` (s) that passes while the caller works (see
        :meth:`Ticker.wait`); a clock that cannot sleep in the background does nothing."""

    def end_sleep(self) -> float:
        """Wait for the sleep :meth:`start_sleep` asked for; the clock's time when it was asked
        (a clock that cannot sleep in the background: :meth:`now`), s."""

    def ask_after_next_write(self) -> None:
        """Have the clock learn the time right after the next bus write, while the reply is on its
        way (a lockstep clock); any other clock does nothing."""

    def defer(self, work: Callable[[], None]) -> None:
        """Run ``work`` (the rest of a cycle, e.g. writing its log) where it delays the loop least:
        a clock whose other side works after each bus write (a lockstep emulator) keeps it
        until the next write has gone out; any other clock runs it now."""

    def run_deferred(self) -> None:
        """Run the work :meth:`defer` kept, if any (before the loop ends)."""


class ForegroundClock:
    """What a :class:`Clock` whose time runs on while its caller works provides besides ``now``
    and ``sleep_until`` (which a subclass defines): wall-clock log stamps, and nothing to do in
    the background."""

    def stamp_ns(self) -> int:
        """Wall-clock time (Unix epoch), ns."""
        return time.time_ns()

    def start_sleep(self, t: float) -> None:
        """Nothing: the sleep happens in :meth:`Ticker.wait`'s ``sleep_until``."""

    def end_sleep(self) -> float:
        """:meth:`now` (the caller's work has taken its time already)."""
        return self.now()

    def ask_after_next_write(self) -> None:
        """Nothing: the time is read when asked."""

    def defer(self, work: Callable[[], None]) -> None:
        """``work()`` now: the time it takes is the caller's."""
        work()

    def run_deferred(self) -> None:
        """Nothing: :meth:`defer` keeps nothing."""


class WallLoopClock(ForegroundClock):
    """The host's monotonic clock (:func:`time.monotonic`); sleeps with :func:`time.sleep`."""

    def now(self) -> float:
        return time.monotonic()

    def sleep_until(self, t: float) -> None:
        remaining = t - time.monotonic()
        while remaining > 0:  # sleep may return early on some platforms; never spin
            time.sleep(remaining)
            remaining = t - time.monotonic()


@dataclass
class LoopStats:
    """Measured cycle periods (s) and overrun counts of a :class:`Ticker`."""

    period_s: float
    periods_s: list[float] = field(default_factory=list)
    overruns: int = 0
    missed_slots: int = 0
    late_s: list[float] = field(default_factory=list)

    def timing(self) -> LoopTiming:
        """Percentiles of the measured periods (ms) and the overrun counts."""
        p = np.asarray(self.periods_s) * 1e3
        q = (lambda x: float(np.percentile(p, x))) if p.size else (lambda x: float("nan"))
        return LoopTiming(
            loop_period_target_ms=self.period_s * 1e3,
            loop_period_p50_ms=q(50),
            loop_period_p99_ms=q(99),
            loop_period_max_ms=float(p.max()) if p.size else float("nan"),
            loop_cycles=int(p.size) + (1 if p.size else 0),
            overruns=self.overruns,
            missed_slots=self.missed_slots)


class Ticker:
    """Wake up every ``period_s`` on absolute deadlines.

    ``wait()`` sleeps until the next due slot and returns its index ``k`` (slot 0 is the
    call to :meth:`start`). ``period_s`` is in the clock's seconds; ``clock`` is a
    :class:`Clock` (default :class:`WallLoopClock`).
    """

    def __init__(self, period_s: float, clock: Clock | None = None):
        if not period_s > 0:
            raise ValueError(f"period must be positive, got {period_s}")
        self.period_s = float(period_s)
        self.clock = WallLoopClock() if clock is None else clock
        self.stats = LoopStats(self.period_s)
        self._t0 = None
        self._k = 0
        self._last_wake = None
        #: Clock seconds from the latest wake-up to the following :meth:`wait` (the cycle's work).
        self.last_busy_s = 0.0

    def start(self) -> float:
        """Start the schedule now; returns ``t0`` (monotonic seconds)."""
        self._t0 = self._last_wake = self.clock.now()
        self._k = 0
        return self._t0

    @property
    def slot(self) -> int:
        return self._k

    def deadline(self, k: int) -> float:
        return self._t0 + k * self.period_s

    def wait(self, meanwhile: Callable[[], None] | None = None) -> int:
        """Sleep until the next slot; return its index (slots missed by an overrun are skipped).

        ``meanwhile``: the rest of the cycle's work (e.g. writing the log), handed to the clock's
        ``defer`` between its ``start_sleep`` and ``end_sleep``. A clock that sleeps in the
        background (a lockstep emulator, whose time host work does not take) runs it while the
        emulator steps the physics and serves the next cycle's read; on a
        :class:`ForegroundClock` it runs at once and is part of the cycle."""
        if self._t0 is None:
            raise RuntimeError("Ticker.start() first")
        nxt = self._k + 1
        self.clock.start_sleep(self.deadline(nxt))     # a no-op advance if the work ran past it
        if meanwhile is not None:
            self.clock.defer(meanwhile)
        now = self.clock.end_sleep()                   # the clock's time when the sleep was asked
        self.last_busy_s = now - self._last_wake
        if now > self.deadline(nxt):  # the work ran past the next deadline: overrun
            behind = int((now - self._t0) // self.period_s)  # last slot already begun
            self.stats.overruns += 1
            self.stats.missed_slots += behind - nxt + 1
            self.stats.late_s.append(now - self.deadline(nxt))
            nxt = behind + 1
        if self.deadline(nxt) > self.clock.now():
            self.clock.sleep_until(self.deadline(nxt))
        wake = self.clock.now()
        self.stats.periods_s.append(wake - self._last_wake)
        self._last_wake = wake
        self._k = nxt
        return nxt


@contextlib.contextmanager
def collector_paused():
    """Hold the cyclic garbage collector off for a timed loop.

    A full collection of a process that has loaded numpy, scipy, rosbags and matplotlib walks
    ~90 000 objects: measured 30 ms, two periods at 62.5 Hz. Inside this block the existing
    objects are frozen (``gc.freeze``) and automatic collection is off; reference counting
    still frees everything that forms no cycle. On exit the collector is back as it was and
    collects any cycles made meanwhile.
    """
    enabled = gc.isenabled()
    gc.collect()
    gc.freeze()
    gc.disable()
    try:
        yield
    finally:
        gc.unfreeze()
        if enabled:
            gc.enable()

