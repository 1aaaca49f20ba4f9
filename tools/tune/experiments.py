"""Step experiments on one servo through a :class:`driver.bus.Bus`, with safety.

Three experiments: open-loop PWM steps (Operating Mode 16), a closed-loop velocity step (mode 1)
and a closed-loop position step (mode 3). Each reads the state block Realtime Tick (120) ..
Present Input Voltage (144) in one Sync Read as fast as the bus answers. Sample times come from
the servo's Realtime Tick (its own clock, 1 ms) when it advances, else from the experimenter's
clock (the host's monotonic clock, or robot time in lockstep); write times are clock midpoints
mapped onto the servo clock by interpolating between the samples around them.

Safety: :func:`servo_session` turns the torque off on every exit and puts the operating mode
back; every sample is checked against :class:`Limits` (position range, speed, current) and a
stall detector; a servo that does not move raises :class:`NotMovingError`. Raw control-table
integers stay inside this module; records are SI.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from swerve.driver.control_table import OperatingMode, Reg
from swerve.driver.errors import DxlError, SwerveError
from swerve.emulator.physics.params import MotorParams
from swerve.tools.run.ticker import Clock, WallLoopClock
from swerve.tools.signals import safe_stop
from swerve.tools.tune.identify import PwmRecord

STATE_FIRST, STATE_LAST = Reg.REALTIME_TICK, Reg.PRESENT_INPUT_VOLTAGE
TICK_WRAP_MS = 32768
GAIN_REGS = (Reg.VELOCITY_P_GAIN, Reg.VELOCITY_I_GAIN, Reg.POSITION_P_GAIN, Reg.POSITION_I_GAIN,
             Reg.POSITION_D_GAIN, Reg.FEEDFORWARD_1ST_GAIN, Reg.FEEDFORWARD_2ND_GAIN)
WATCHDOG_RAW = 50                       # 1 s: the servo stops if this host goes silent


class SafetyError(SwerveError):
    """An experiment left its safe envelope; the torque was turned off."""


class StallError(SafetyError):
    """The motor drew current under PWM but did not turn."""


class NotMovingError(SwerveError):
    """The servo did not move under an open-loop PWM step (no power, brake, or no physics)."""


@dataclass(frozen=True)
class Limits:
    """Safety envelope of one servo, SI (output shaft).

    ``position_min_rad``/``position_max_rad`` bound Present Position (``-inf``/``inf``: a wheel);
    ``speed_max_radps`` bounds |Present Velocity|; ``current_max_a`` bounds |Present Current|;
    a stall is ``stall_time_s`` of driven PWM with less than ``stall_move_rad`` of motion and more
    than half the expected stall current.
    """

    position_min_rad: float = -math.inf
    position_max_rad: float = math.inf
    speed_max_radps: float = math.inf
    current_max_a: float = math.inf
    stall_time_s: float = 0.1
    stall_move_rad: float = 4 * 2 * math.pi / 4096


@dataclass
class Trace:
    """Raw samples of the state block and the writes made while sampling.

    ``host_t_s`` are request/reply midpoints (monotonic clock); ``rows`` the decoded raw items;
    ``writes`` are ``(host_t_s, register, raw)``.
    """

    host_t_s: list[float] = field(default_factory=list)
    rows: list[dict[str, int]] = field(default_factory=list)
    writes: list[tuple[float, str, int]] = field(default_factory=list)

    def raw(self, name: str) -> np.ndarray:
        """One item over all samples, shape (n,)."""
        return np.array([r[name] for r in self.rows], float)

    def times(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
        """Sample times and write times on one clock, s, from the first sample.

        Returns ``(t_samples (n,), t_writes (m,), write_std (m,), clock)``: ``clock`` is
        ``"realtime_tick"`` when the servo's tick advanced with the host clock, else ``"host"``;
        ``write_std`` is half the gap between the samples around each write (when it took effect
        is only known to lie between them).
        """
        host = np.asarray(self.host_t_s)
        w_host = np.array([w[0] for w in self.writes])
        tick = self.raw(Reg.REALTIME_TICK)
        steps = np.mod(np.diff(tick), TICK_WRAP_MS)
        ticks_s = np.concatenate([[0.0], np.cumsum(steps)]) * 1e-3
        span_host = host[-1] - host[0] if host.size > 1 else 0.0
        clock = "realtime_tick" if host.size > 10 and ticks_s[-1] > 0.5 * span_host else "host"
        if clock == "realtime_tick":
            # reads within one tick: spread them by the host clock, never past the next tick
            first = np.maximum.accumulate(np.where(np.concatenate([[True], steps > 0]), np.arange(host.size), 0))
            t = ticks_s + np.clip(host - host[first], 0.0, 0.999e-3)
        else:
            t = host - host[0]
        after = np.clip(np.searchsorted(host, w_host), 1, max(host.size - 1, 1))
        t_w = np.interp(w_host, host, t)          # a write lands between the samples around it
        return t, t_w, 0.5 * (t[after] - t[after - 1]), clock


def _si(table, name: str, raw: np.ndarray) -> np.ndarray:
    return raw * (table[name].scale or 1.0)


class Experimenter:
    """Runs experiments on servo ``id_``; all writes and samples go through ``bus``.

    Parameters
    ----------
    bus : driver.bus.Bus
        An open bus.
    id_ : int
        Servo ID.
    limits : Limits
        Safety envelope.
    progress : callable, optional
        Called with the seconds of experiment time just spent (a progress bar's ``update``).
    clock : swerve.tools.run.ticker.Clock, optional
        Where experiment time comes from: the host's monotonic clock (default), or robot time
        of a lockstep emulator (:class:`swerve.tools.run.lockstep.LockstepLoopClock`), with which
        every run samples at the same robot instants and identifies the same numbers.
    """

    def __init__(self, bus, id_: int, limits: Limits, progress: Callable[[float], None] | None = None,
                 clock: Clock | None = None):
        self.bus, self.id, self.limits = bus, int(id_), limits
        self.clock = clock if clock is not None else WallLoopClock()
        self.table = bus.table(self.id)
        self.progress = progress or (lambda s: None)

    # ---- primitives ----------------------------------------------------------------------------
    def write(self, reg: Reg, raw: int, trace: Trace | None = None) -> None:
        """Write ``raw`` to ``reg``; log the host midpoint in ``trace``."""
        t0 = self.clock.now()
        self.bus.write(self.id, reg, int(raw))
        if trace is not None:
            trace.writes.append((0.5 * (t0 + self.clock.now()), str(reg), int(raw)))

    def sample(self, trace: Trace) -> dict[str, int]:
        """Read the state block once into ``trace`` and check it against the limits."""
        t0 = self.clock.now()
        row = self.bus.sync_read([self.id], STATE_FIRST, STATE_LAST)[self.id]
        trace.host_t_s.append(0.5 * (t0 + self.clock.now()))
        trace.rows.append(row)
        self._check(row)
        return row

    def _check(self, row: dict[str, int]) -> None:
        lim, tab = self.limits, self.table
        pos = tab[Reg.PRESENT_POSITION].to_si(row[Reg.PRESENT_POSITION])
        vel = tab[Reg.PRESENT_VELOCITY].to_si(row[Reg.PRESENT_VELOCITY])
        cur = tab[Reg.PRESENT_CURRENT].to_si(row[Reg.PRESENT_CURRENT])
        if not lim.position_min_rad <= pos <= lim.position_max_rad:
            raise SafetyError(f"servo ID {self.id} left its safe range: position {pos:.3f} rad outside "
                              f"[{lim.position_min_rad:.3f}, {lim.position_max_rad:.3f}] rad; torque turned off")
        if abs(vel) > lim.speed_max_radps:
            raise SafetyError(f"servo ID {self.id} exceeded the speed limit: {vel:.2f} rad/s > "
                              f"{lim.speed_max_radps:.2f} rad/s; torque turned off (lower --pwm)")
        if abs(cur) > lim.current_max_a:
            raise SafetyError(f"servo ID {self.id} exceeded the current limit: {cur:.3f} A > "
                              f"{lim.current_max_a:.3f} A; torque turned off")

    def hold(self, duration_s: float, trace: Trace, check: Callable[[Trace], None] | None = None) -> None:
        """Sample for ``duration_s`` (host clock), calling ``check(trace)`` after every sample."""
        start = last = self.clock.now()
        while (now := self.clock.now()) - start < duration_s:
            self.sample(trace)
            if check is not None:
                check(trace)
            self.progress(now - last)
            last = now

    def wait_still(self, still_s: float = 0.05, timeout_s: float = 2.0) -> None:
        """Sample until Present Position has not changed by more than 3 LSB for ``still_s``
        (the model starts every record from rest).

        Raises
        ------
        SafetyError
            If the shaft is still moving after ``timeout_s``.
        """
        trace, start = Trace(), self.clock.now()
        since, ref = start, None
        while (now := self.clock.now()) - start < timeout_s:
            pos = self.sample(trace)[Reg.PRESENT_POSITION]
            if ref is None or abs(pos - ref) > 3:
                since, ref = now, pos
            elif now - since >= still_s:
                return
        raise SafetyError(f"servo ID {self.id} does not come to rest (torque on, PWM 0) within {timeout_s:g} s; "
                          "torque turned off")

    def set_mode(self, mode: int) -> None:
        """Torque off, then Operating Mode (an EEPROM item)."""
        self.write(Reg.TORQUE_ENABLE, 0)
        if self.bus.read(self.id, Reg.OPERATING_MODE) != mode:
            self.write(Reg.OPERATING_MODE, mode)

    # ---- experiments ---------------------------------------------------------------------------
    def move_to(self, goal_rad: float, timeout_s: float = 3.0, tolerance_rad: float = 0.02) -> None:
        """Position mode to ``goal_rad`` with the servo's own gains, then torque off.

        The range check is not applied on the way (the servo may start outside the range it is
        being brought into); the speed and current limits are.

        Raises
        ------
        SafetyError
            If the goal is not reached within ``timeout_s``.
        """
        self.set_mode(OperatingMode.POSITION)
        goal = self.table[Reg.GOAL_POSITION].from_si(goal_rad)
        self.write(Reg.PROFILE_VELOCITY, 0)
        self.write(Reg.TORQUE_ENABLE, 1)
        self.write(Reg.GOAL_POSITION, goal)
        scale = self.table[Reg.PRESENT_POSITION].scale
        saved, self.limits = self.limits, replace(self.limits, position_min_rad=-math.inf,
                                                   position_max_rad=math.inf)
        try:
            trace, start = Trace(), self.clock.now()
            while self.clock.now() - start < timeout_s:
                row = self.sample(trace)
                if abs(row[Reg.PRESENT_POSITION] - goal) * scale < tolerance_rad:
                    break
            else:
                raise SafetyError(f"servo ID {self.id} did not reach {goal_rad:.3f} rad within {timeout_s:g} s "
                                  f"(at {row[Reg.PRESENT_POSITION] * scale:.3f} rad); torque turned off")
        finally:
            self.limits = saved
        self.write(Reg.TORQUE_ENABLE, 0)

    def pwm_steps(self, plan: list[tuple[float, float]], prior: MotorParams, gear_ratio: float,
                  rest_s: float = 0.1) -> tuple[PwmRecord, Trace]:
        """Open-loop PWM steps: ``plan`` = ``[(duration_s, duty -1..1), ...]`` after ``rest_s`` at 0.

        Raises
        ------
        StallError
            Driven for ``limits.stall_time_s`` without turning while drawing current.
        NotMovingError
            The shaft moved less than ``limits.stall_move_rad`` over the whole plan.
        """
        self.set_mode(OperatingMode.PWM)
        pwm_reg = self.table[Reg.GOAL_PWM]
        trace = Trace()
        self.write(Reg.GOAL_PWM, 0)
        self.write(Reg.TORQUE_ENABLE, 1)
        self.wait_still()
        self.hold(rest_s, trace)
        supply = np.mean(_si(self.table, Reg.PRESENT_INPUT_VOLTAGE, trace.raw(Reg.PRESENT_INPUT_VOLTAGE)))
        if supply <= 0:
            raise NotMovingError(f"servo ID {self.id} reports {supply:.1f} V supply: is it powered?")
        for duration, duty in plan:
            self.write(Reg.GOAL_PWM, pwm_reg.from_si(duty), trace)
            self.hold(duration, trace, self._stall_check(duty * supply / prior.resistance_ohm))
        self.write(Reg.GOAL_PWM, 0, trace)
        self.hold(rest_s, trace)
        self.write(Reg.TORQUE_ENABLE, 0)
        pos = _si(self.table, Reg.PRESENT_POSITION, trace.raw(Reg.PRESENT_POSITION))
        cur = _si(self.table, Reg.PRESENT_CURRENT, trace.raw(Reg.PRESENT_CURRENT))
        if np.ptp(pos) < self.limits.stall_move_rad:
            raise NotMovingError(
                f"servo ID {self.id} did not move under {max(abs(d) for _, d in plan):.0%} PWM (travel "
                f"{np.ptp(pos):.4f} rad, peak current {np.max(np.abs(cur)):.3f} A): is it powered and free to turn? Torque is off")
        t, t_w, t_w_std, _ = trace.times()
        keep = _distinct(trace)
        duties = np.array([w[2] for w in trace.writes], float) * pwm_reg.scale
        rec = PwmRecord(t[keep], pos[keep], cur[keep], t_w, duties * supply, t_w_std)
        return rec, trace

    def _stall_check(self, stall_current_a: float) -> Callable[[Trace], None]:
        """A check that raises StallError when driven without motion for ``stall_time_s``."""
        lim, tab = self.limits, self.table

        def check(trace: Trace) -> None:
            host = trace.host_t_s
            if abs(stall_current_a) < 1e-6 or host[-1] - trace.writes[-1][0] < lim.stall_time_s:
                return
            since = host[-1] - lim.stall_time_s
            idx = [k for k in range(len(host) - 1, -1, -1) if host[k] >= since]
            pos = [trace.rows[k][Reg.PRESENT_POSITION] for k in idx]
            cur = tab[Reg.PRESENT_CURRENT].to_si(trace.rows[-1][Reg.PRESENT_CURRENT])
            moved = (max(pos) - min(pos)) * tab[Reg.PRESENT_POSITION].scale
            if moved < lim.stall_move_rad and abs(cur) > 0.5 * abs(stall_current_a):
                raise StallError(f"servo ID {self.id} stalled: {abs(cur):.2f} A for {lim.stall_time_s * 1e3:.0f} ms "
                                 f"without turning; torque turned off (is the shaft blocked?)")
        return check

    def velocity_step(self, gains: dict[str, int], step_radps: float, rest_s: float = 0.1,
                      duration_s: float = 0.8, stop_s: float = 0.3) -> tuple[dict, Trace]:
        """Closed-loop velocity step 0 -> ``step_radps`` with ``gains`` (raw), in velocity mode.

        Returns ``(record, trace)``; ``record`` has ``t_s`` (from the step), ``y`` (Present
        Velocity, rad/s), ``goal`` (rad/s) and ``kind`` = ``"velocity"``.
        """
        goal = self.table[Reg.GOAL_VELOCITY].from_si(step_radps)
        self.set_mode(OperatingMode.VELOCITY)
        self._write_gains(gains)
        self.write(Reg.PROFILE_ACCELERATION, 0)
        self.write(Reg.GOAL_VELOCITY, 0)
        trace = Trace()
        self.write(Reg.TORQUE_ENABLE, 1)
        self.hold(rest_s, trace)
        self.write(Reg.GOAL_VELOCITY, goal, trace)
        self.hold(duration_s, trace)
        self.write(Reg.GOAL_VELOCITY, 0, trace)
        self.hold(stop_s, trace)
        self.write(Reg.TORQUE_ENABLE, 0)
        return self._step_record(trace, Reg.PRESENT_VELOCITY, "velocity",
                                 self.table[Reg.GOAL_VELOCITY].to_si(goal), 0.0, duration_s), trace

    def position_step(self, gains: dict[str, int], start_rad: float, step_rad: float,
                      settle_s: float = 0.6, duration_s: float = 0.8) -> tuple[dict, Trace]:
        """Closed-loop position step ``start_rad`` -> ``start_rad + step_rad`` (position mode)."""
        reg = self.table[Reg.GOAL_POSITION]
        g0, g1 = reg.from_si(start_rad), reg.from_si(start_rad + step_rad)
        for g in (g0, g1):
            if not self.limits.position_min_rad <= reg.to_si(g) <= self.limits.position_max_rad:
                raise SafetyError(f"position step goal {reg.to_si(g):.3f} rad is outside the safe range "
                                  f"[{self.limits.position_min_rad:.3f}, {self.limits.position_max_rad:.3f}] rad")
        self.set_mode(OperatingMode.POSITION)
        self._write_gains(gains)
        self.write(Reg.PROFILE_VELOCITY, 0)
        self.write(Reg.PROFILE_ACCELERATION, 0)
        trace = Trace()
        self.write(Reg.TORQUE_ENABLE, 1)
        self.write(Reg.GOAL_POSITION, g0)
        self.hold(settle_s, trace)
        trace = Trace()
        self.hold(0.05, trace)
        self.write(Reg.GOAL_POSITION, g1, trace)
        self.hold(duration_s, trace)
        self.write(Reg.TORQUE_ENABLE, 0)
        return self._step_record(trace, Reg.PRESENT_POSITION, "position", reg.to_si(g1), reg.to_si(g0),
                                 duration_s), trace

    def _write_gains(self, gains: dict[str, int]) -> None:
        for name, raw in gains.items():
            self.write(Reg(name), raw)

    def _step_record(self, trace: Trace, reg: Reg, kind: str, goal: float, y0: float,
                     duration_s: float) -> dict:
        t, t_w, _, clock = trace.times()
        y = _si(self.table, reg, trace.raw(reg))
        keep = _distinct(trace)
        t_rel = t[keep] - t_w[0]
        end = min(duration_s, t_w[1] - t_w[0] if t_w.size > 1 else math.inf)   # until the next write
        sel = (t_rel >= 0) & (t_rel < end)
        return {"kind": kind, "t_s": t_rel[sel], "y": y[keep][sel], "goal": goal, "y0": y0,
                "t_all_s": t_rel, "y_all": y[keep], "clock": clock}


def _distinct(trace: Trace) -> np.ndarray:
    """Indices of samples that differ from the previous one (repeated reads of one servo update
    carry no new information and would understate the noise)."""
    keep = [0] + [k for k in range(1, len(trace.rows)) if trace.rows[k] != trace.rows[k - 1]]
    return np.asarray(keep, int)


@contextmanager
def servo_session(bus, id_: int):
    """Guard one servo for the experiments: on every exit the torque goes off and the operating
    mode, Bus Watchdog and (on error) the gains are put back.

    Yields a dict of the original raw items (``operating_mode`` and the gain registers); put
    ``{register name: raw}`` under ``"new_gains"`` in it to have them written (RAM) after the mode
    is restored (changing the mode may reload a servo's default gains) instead of the originals.
    """
    saved = {str(r): bus.read(id_, r) for r in (Reg.OPERATING_MODE, *GAIN_REGS)}
    watchdog = bus.read(id_, Reg.BUS_WATCHDOG)
    state = dict(saved, new_gains={})
    bus.write(id_, Reg.TORQUE_ENABLE, 0)
    bus.write(id_, Reg.BUS_WATCHDOG, 0)
    bus.write(id_, Reg.BUS_WATCHDOG, WATCHDOG_RAW)
    failed = True
    try:
        yield state
        failed = False
    finally:
        with safe_stop():       # a stop signal waits until the servo is safe
            try:
                bus.write(id_, Reg.TORQUE_ENABLE, 0)
                bus.write(id_, Reg.BUS_WATCHDOG, 0)
                bus.write(id_, Reg.BUS_WATCHDOG, max(watchdog, 0))
                if bus.read(id_, Reg.OPERATING_MODE) != saved[str(Reg.OPERATING_MODE)]:
                    bus.write(id_, Reg.OPERATING_MODE, saved[str(Reg.OPERATING_MODE)])
                gains = state["new_gains"] if state["new_gains"] and not failed else \
                    {str(r): saved[str(r)] for r in GAIN_REGS}
                for name, raw in gains.items():
                    bus.write(id_, Reg(name), int(raw))
            except DxlError as exc:
                if not failed:            # never mask the error that is already propagating
                    raise SafetyError(f"could not put servo ID {id_} back (torque off, mode, gains): {exc}") from exc
