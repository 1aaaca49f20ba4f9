"""Physics stepping and the true state: every servo, then the world, in simulated time.

:class:`Stepper` runs the clock steps the clock (:mod:`swerve.emulator.clock`) asks for: one
:meth:`~Stepper.step` is every servo's :meth:`~swerve.emulator.servo.VirtualServo.advance`
(Realtime Tick, Bus Watchdog, physics), then ``world.step``; :meth:`~Stepper.step_many` runs
``n`` of them with the same result, batched where the servos do not interact within a step.
It holds the simulated time and reads the true state (``sim_time_s``, the body's pose), which
never crosses the bus. The :class:`World` Protocol declares what the robot body offers.
"""
from __future__ import annotations

import time
from typing import Protocol, Sequence

from swerve.driver.errors import ConfigError
from swerve.emulator.bus_stats import Stats
from swerve.emulator.clock import HAND_OVER_S, HandOverLock
from swerve.emulator.servo import VirtualServo

#: Most physics steps :meth:`Stepper.step_many` runs under one hold of the lock (~2 ms of CPU).
MAX_STEPS_PER_HOLD = 100


class World(Protocol):
    """What moves besides the servos (the robot body): stepped after them, under the bus lock.

    A world that steps one tick at a time after the servos subclasses :class:`SteppedWorld` for
    the members that batch or couple the steps.
    """

    pose: tuple[float, float, float]    # true (x_m, y_m, theta_rad)
    physics: object | None              # the physics model behind it (``RobotPhysics``), if any

    def step(self, dt_s: float) -> None:
        """Advance by ``dt_s`` simulated s from the servos' present shaft states."""

    def traces(self) -> dict | None:
        """Empty per-step trace lists for a run of several steps, servo after servo, then the
        body from the traces (:meth:`step_many`); ``None`` if the body must step between the
        servos."""

    def step_many(self, dt_s: float, n: int, traces: dict) -> None:
        """``n`` body steps from the servos' recorded ``traces`` (from :meth:`traces`)."""

    def run_coupled(self, servos: Sequence[VirtualServo], dt_s: float, n: int) -> int:
        """Up to ``n`` steps of the ``servos`` and the body together in one call, as many
        :meth:`VirtualServo.advance` then :meth:`step`; the steps run (0: step tick by tick)."""


class SteppedWorld:
    """The :class:`World` members of a body stepped one tick at a time after the servos, with
    no physics model to show; a subclass defines ``pose`` and ``step``."""

    physics = None

    def traces(self) -> dict | None:
        return None

    def step_many(self, dt_s: float, n: int, traces: dict) -> None:
        for _ in range(n):
            self.step(dt_s)

    def run_coupled(self, servos: Sequence[VirtualServo], dt_s: float, n: int) -> int:
        return 0


class Stepper:
    """The servos and the world stepped in simulated time, and their true state.

    Parameters
    ----------
    servos : sequence of VirtualServo
        Stepped in this order, each step.
    world : World, optional
        The robot body, stepped after the servos; gives :meth:`true_state`.
    lock : HandOverLock
        The bus lock guarding every servo's memory (:meth:`step` and :meth:`step_many` take it).
    stats : Stats
        The bus counters (``clock_ticks`` counts the steps).
    """

    def __init__(self, servos: Sequence[VirtualServo], world: World | None, lock: HandOverLock, stats: Stats):
        self.servos = servos
        self.world = world
        self.lock = lock
        self.stats = stats
        #: Simulated seconds stepped so far (clock and ``advance`` together).
        self.sim_time_s = 0.0

    def step(self, dt_s: float) -> None:
        """One clock step of ``dt_s`` simulated s: every servo, then the world, under the lock."""
        with self.lock:
            self._tick(dt_s)

    def step_many(self, dt_s: float, n: int) -> None:
        """``n`` clock steps of ``dt_s`` simulated s; the same result as ``n`` calls of
        :meth:`step` (nothing from the bus can come in between). The lock is held for at most
        :data:`MAX_STEPS_PER_HOLD` steps at a time, and handed over when another thread waits."""
        while n > 0:
            k = min(n, MAX_STEPS_PER_HOLD)
            with self.lock:
                self.ticks(dt_s, k)
            n -= k
            if n and self.lock.waiting:
                time.sleep(HAND_OVER_S)

    def ticks(self, dt_s: float, n: int) -> None:
        """``n`` steps of ``dt_s`` s (the caller holds the lock). A world that steps its servos
        and body together in one call (``world.run_coupled``, the compiled robot) runs them so;
        otherwise, where the servos do not interact within a step (no shared noise draws, a body
        that does not load the shafts), each servo runs all ``n`` steps at once
        (:meth:`VirtualServo.advance_many`) and the body follows from their recorded states; the
        rest one step at a time."""
        n -= self._coupled_ticks(dt_s, n)
        traces = self._batch_traces() if n > 1 else None
        if traces is None:
            for _ in range(n):
                self._tick(dt_s)
            return
        for s in self.servos:
            s.advance_many(dt_s, n, traces)
        if self.world is not None:
            self.world.step_many(dt_s, n, traces)
        for _ in range(n):                  # the same float sum as n single ticks
            self.sim_time_s += dt_s
        self.stats.clock_ticks += n

    def _tick(self, dt_s: float) -> None:
        for s in self.servos:
            s.advance(dt_s)
        if self.world is not None:
            self.world.step(dt_s)
        self.sim_time_s += dt_s
        self.stats.clock_ticks += 1

    def _coupled_ticks(self, dt_s: float, n: int) -> int:
        """Up to ``n`` :meth:`_tick` s run by a world whose servos and body step together in one
        call (``world.run_coupled``, e.g. a robot on tyres); returns how many ran (0: none)."""
        run = self.world.run_coupled if self.world is not None else None
        done = 0
        while run is not None and done < n:
            ran = run(self.servos, dt_s, n - done)
            if not ran:
                break
            for _ in range(ran):            # the same float sum as single ticks
                self.sim_time_s += dt_s
            self.stats.clock_ticks += ran
            done += ran
        return done

    def _batch_traces(self) -> dict | None:
        """The trace lists for a batched run of steps (``{}`` without a world), or ``None`` if
        the steps must interleave servo by servo."""
        for s in self.servos:
            d = s.dynamics
            if d is not None and not d.batchable:
                return None
        if self.world is None:
            return {}
        return self.world.traces()

    def true_state(self) -> tuple[float, tuple[float, float, float]]:
        """``(sim_time_s, (x_m, y_m, theta_rad))`` read under one lock (a coherent pair)."""
        if self.world is None:
            raise ConfigError("this emulated bus has no robot body, so no pose")
        with self.lock:
            return self.sim_time_s, self.world.pose
