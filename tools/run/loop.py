"""The online tracking loop: read 8 servos, estimate the pose, apply K(t), command 8 servos.

One cycle every ``tau`` (16 ms, 62.5 Hz) of robot time, on absolute deadlines of the clock passed
in (:class:`swerve.tools.run.ticker.Ticker`); with an emulator running ``time_scale`` times
faster than real time the wall period is ``tau / time_scale``. Per cycle:

1. one (fast) sync read of present current/velocity/position of all eight servos;
2. odometry on the measured wheel speeds and steering angles with model (1)-(5);
3. the tracking law (:meth:`TrackingLaw.step`) on the state ``(x, y, theta, delta1, delta2)``
   where the pose is the odometry estimate and the steering angles are the previous step's
   goals (the law's input model integrates the steering rates);
4. one bulk write of ``[v1/r] * 4`` and the law's steering goals ``[d1, d2, d2, d1]``;
5. ``on_cycle(fields)`` with a dict of :class:`swerve.tools.logs.record.CycleRecord` fields.

The wheels object is injected (a :class:`Wheels`, e.g. :class:`driver.wheelset.WheelSet`), so
the same loop runs on the robot and on the emulator. The clock is an object too (:class:`~swerve.tools.run.ticker.Clock`).
Failures stop the loop with :class:`LoopAbort` naming the
servo and the cause: a hardware-error alert, too many consecutive failed reads (a missing
servo), or a stall long enough for the servos' Bus Watchdog to expire.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import numpy as np

from swerve.controller.kinematics import Geometry, drive_angular_speed, wheel_command_floats
from swerve.controller.odometry import Odometry
from swerve.controller.simulate import SimResult, metrics
from swerve.controller.tracking import TrackingLaw
from swerve.driver.errors import CorruptPacketError, DxlTimeoutError, ServoError, SwerveError
from swerve.tools.logs.record import CycleFlag
from swerve.tools.run.summary import LoopTiming, TrackingErrors, tracking_errors
from swerve.tools.run.ticker import Clock, Ticker, WallLoopClock, collector_paused

log = logging.getLogger(__name__)

_OVERRUN, _STALE = int(CycleFlag.OVERRUN), int(CycleFlag.STALE)
_NO_POSE = (np.nan,) * 3


class WheelReading(Protocol):
    """One read of the four wheel modules, wheel frame, SI (:class:`driver.wheelset.WheelState`)."""

    drive_radps: Sequence[float]        #: (4,) wheel speeds, rad/s
    steer_rad: Sequence[float]          #: (4,) steering angles, rad
    drive_current_a: Sequence[float]    #: (4,) drive motor currents, A
    steer_current_a: Sequence[float]    #: (4,) steering motor currents, A
    #: (4,) wheel rotation angles, rad (multi-turn), or None where the wheels do not report them
    #: (odometry then integrates the speeds)
    drive_rad: Sequence[float] | None


class Wheels(Protocol):
    """What the loop drives: four wheel modules (:class:`driver.wheelset.WheelSet` on a bus)."""

    def read_state(self) -> WheelReading:
        """One read of all four modules; raises the driver's errors on a failed read."""

    def write_goals(self, drive_radps: Sequence[float], steer_rad: Sequence[float]) -> None:
        """Command wheel speeds (4,), rad/s, and steering angles (4,), rad."""

    def stop(self) -> None:
        """Zero wheel speeds."""


class LoopAbort(SwerveError):
    """The loop stopped the robot: ``cause`` says why, ``ids`` which servos."""

    def __init__(self, message: str, cause: str, ids=()):
        self.cause = cause
        self.ids = tuple(ids)
        super().__init__(message)


@dataclass(frozen=True)
class LoopResult:
    """What :meth:`TrackingLoop.run` measured.

    Per cycle: ``t_s`` (n,) trajectory time, ``est_states`` (n, 5) the law's input state,
    ``true_poses`` (n, 3) ground truth (NaN without one), ``ref_states`` (n, 5), ``inputs``
    (n, 3) applied ``(v1_mps, omega1_radps, omega2_radps)``. Summary: ``tracking`` (None if
    no cycle ran), ``timing``, ``cycles``, ``failed_reads``, ``time_scale``; ``aborted`` the
    :class:`LoopAbort` that stopped the run, or None.
    """

    t_s: np.ndarray
    est_states: np.ndarray
    true_poses: np.ndarray
    ref_states: np.ndarray
    inputs: np.ndarray
    tracking: TrackingErrors | None
    timing: LoopTiming
    cycles: int
    failed_reads: int
    time_scale: float
    aborted: LoopAbort | None = None

    @property
    def completed(self) -> bool:
        """The run reached the end of its reference."""
        return self.aborted is None


class TrackingLoop:
    """Run a :class:`TrackingLaw` on real (or emulated) wheels.

    Parameters
    ----------
    wheels : Wheels
        Reads the wheel modules (:class:`WheelReading`), writes their goals, stops them.
    law : TrackingLaw
    geom : Geometry
        Wheel layout and radius.
    time_scale : float
        Robot seconds per wall second (1 on hardware; the emulator's ``--time-scale``).
    max_failed_reads : int
        Consecutive failed reads tolerated (then :class:`LoopAbort`, cause ``"no reply"``).
    watchdog_s : float
        The servos' Bus Watchdog, robot seconds: a gap in bus traffic this long aborts the loop.
    max_time_factor : float
        The run is aborted (cause ``"diverged"``) once robot time exceeds this many times the
        trajectory's duration: the reference governor slows the reference while the robot
        saturates, so a robot that cannot follow would otherwise never finish.
    true_pose : callable, optional
        ``() -> (x, y, theta)`` ground truth (emulator only), logged beside the estimate.
    on_cycle : callable, optional
        Called each cycle with a dict whose keys are :class:`swerve.tools.logs.record.CycleRecord`
        fields (SI; NaN where unknown), e.g. to write the log. Handed to the clock's ``defer``:
        on the wall clock it runs before the loop sleeps; in lockstep once the next cycle's read
        instruction is out, so a control request it sends (e.g. a fault) is served after that read.
    clock : Clock, optional
        Where time comes from (default :class:`~swerve.tools.run.ticker.WallLoopClock`).
    fault_policy : object, optional
        ``recover(abort, wheels, rehome) -> bool`` (:mod:`swerve.tools.recovery`), asked when a
        servo reports a hardware error; True resumes the run after ``rehome()`` has steered back
        to the last commanded angles. The trajectory time does not advance meanwhile, so the
        reference waits for the robot. ``None``: stop, as on any other abort.
    count_host_cpu : bool
        The clock is simulated (lockstep): host CPU time does not pass on it, so count the cycles
        whose clock time plus measured CPU time would not fit in a period (``host_cpu_overruns``).
    """

    def __init__(self, wheels: Wheels, law: TrackingLaw, geom: Geometry, *, time_scale: float = 1.0,
                 max_failed_reads: int = 3, watchdog_s: float = 0.1, max_time_factor: float = 1.5,
                 true_pose: Callable[[], tuple] | None = None,
                 on_cycle: Callable[[dict], None] | None = None,
                 clock: Clock | None = None, fault_policy=None, count_host_cpu: bool = False):
        if not time_scale > 0:
            raise ValueError(f"time scale must be positive, got {time_scale}")
        self.wheels, self.law, self.geom = wheels, law, geom
        drive_angular_speed(0.0, geom.wheel_radius_m)      # raises for a radius that is not > 0
        self.tau_s = law.reference.tau_s
        self.time_scale = float(time_scale)
        self.max_failed_reads = int(max_failed_reads)
        self.watchdog_s = float(watchdog_s)
        self.max_time_factor = float(max_time_factor)
        self.true_pose = true_pose
        self.on_cycle = on_cycle
        self.clock = WallLoopClock() if clock is None else clock
        self._stamp_ns = self.clock.stamp_ns
        # a lockstep clock can ask for the time after a read while the reply is on its way
        self._before_read = self.clock.ask_after_next_write
        self.count_host_cpu = bool(count_host_cpu)
        self.fault_policy = fault_policy
        self.failed_reads = 0

    # --- helpers -----------------------------------------------------------------------------

    def _read(self) -> WheelReading | None:
        """One state read; None (counted) on a timeout or corrupt reply; aborts on an alert."""
        try:
            st = self.wheels.read_state()
        except ServoError as exc:
            if exc.alert:
                raise LoopAbort(f"servo ID {exc.id} reports a hardware error"
                                f"{': ' + str(exc.hardware_error) if exc.hardware_error else ''};"
                                " stopping", "hardware error", [exc.id]) from exc
            raise LoopAbort(f"servo ID {exc.id} refused the read: {exc}", "servo error", [exc.id]) from exc
        except DxlTimeoutError as exc:
            self._failed_read(exc, exc.ids)
            return None
        except CorruptPacketError as exc:       # the garbled reply names no servo
            self._failed_read(exc, ())
            return None
        self._consecutive = 0
        return st

    def _failed_read(self, exc: SwerveError, ids: Sequence[int]) -> None:
        """Count a failed read; abort (cause ``"no reply"``, naming ``ids``) after too many in a row."""
        self.failed_reads += 1
        self._consecutive += 1
        if self._consecutive > self.max_failed_reads:
            who = f"servo ID {', '.join(map(str, ids))}" if ids else "the bus"
            raise LoopAbort(f"{who} stopped answering ({self._consecutive} failed reads in a row: "
                            f"{exc}); stopping", "no reply", ids) from exc

    def _goals(self, v1_mps: float, delta1_rad: float, delta2_rad: float) -> tuple[list[float], list[float]]:
        """The wheel goals ``(drive_radps (4,), steer_rad (4,))`` for ground speed ``v1_mps`` and the
        steering angles: the robot's goal layout (:func:`wheel_commands`), speeds at the wheel."""
        goals = wheel_command_floats(v1_mps, delta1_rad, delta2_rad)     # [v1] * 4 + [d1, d2, d2, d1]
        r = self.geom.wheel_radius_m        # v / r: what drive_angular_speed divides, on floats
        return [v / r for v in goals[:4]], goals[4:]

    def _touch_bus(self, now: float | None = None) -> None:
        """Before a transaction: abort if the bus was silent longer than the Bus Watchdog
        (the servos have then stopped and ignore goals; a Bulk Write would not tell us).
        ``now``: the clock's time if just read."""
        now = self.clock.now() if now is None else now
        if self._last_tx is not None and (now - self._last_tx) * self.time_scale > self.watchdog_s:
            stall_s = (now - self._last_tx) * self.time_scale       # robot time, as the watchdog counts
            scale = "" if self.time_scale == 1 else f" ({stall_s / self.time_scale * 1e3:.0f} ms wall at " \
                                                     f"{self.time_scale:g}x)"
            raise LoopAbort(f"the loop stalled for {stall_s * 1e3:.0f} ms of robot time{scale}, longer than "
                            f"the servos' Bus Watchdog ({self.watchdog_s * 1e3:.0f} ms of robot time): "
                            "they have stopped", "stalled")
        self._last_tx = now

    def _pose_truth(self) -> tuple[float, float, float]:
        """The true pose ``(x_m, y_m, theta_rad)`` (NaN without one)."""
        if self.true_pose is None:
            return _NO_POSE
        x, y, theta = self.true_pose()
        return float(x), float(y), float(theta)

    def move_to_start(self, delta1: float, delta2: float, timeout_s: float = 5.0,
                      tolerance_rad: float = 0.03) -> None:
        """Steer to the start angles with the wheels stopped; wait until measured within
        ``tolerance_rad`` (robot time ``timeout_s``), keeping the bus (and watchdog) busy."""
        ticker = Ticker(self.tau_s / self.time_scale, self.clock)
        ticker.start()
        self._consecutive = 0
        stopped, goal = self._goals(0.0, delta1, delta2)
        for _ in range(int(np.ceil(timeout_s / self.tau_s))):
            self.wheels.write_goals(stopped, goal)
            st = self._read()
            if st is not None and np.max(np.abs(np.subtract(st.steer_rad, goal))) < tolerance_rad:
                return
            ticker.wait()
        raise LoopAbort(f"steering did not reach the start angles ({delta1:.3f}, {delta2:.3f}) rad "
                        f"within {timeout_s} s", "start")

    # --- the loop ----------------------------------------------------------------------------

    def run(self, start_state) -> LoopResult:
        """Track the law's reference from ``start_state`` (5,); stops the wheels at the end.

        Returns a :class:`LoopResult`; on a :class:`LoopAbort` the wheels are stopped and the
        result carries it in ``aborted`` (the caller decides the exit status). Ctrl-C stops
        the wheels and propagates.
        """
        law, geom, tau = self.law, self.geom, self.tau_s
        s0 = np.asarray(start_state, dtype=float)
        odo = Odometry(geom, s0[:3])
        d1, d2 = s0[3:5].tolist()       # commanded steering angles, rad
        law.reset()
        ticker = Ticker(tau / self.time_scale, self.clock)
        self._consecutive = 0
        rows: list[tuple] = []
        aborted = None
        self._last_tx = None
        t_prev_meas = None
        meas = None
        k = 0
        cpu_s: list[float] = []          # per cycle: thread CPU from the end of one log write to the next
        busy_s: list[float] = []         # per cycle: clock time from its wake-up to its wait
        cpu_end = [0.0]                  # thread CPU at the end of the last log write
        k_base = 0                       # slots run before the last recovery from a servo fault
        with collector_paused():         # a full GC pass would cost ~2 periods
            ticker.start()
            try:
                t_max = self.max_time_factor * law.reference.tf_s
                cpu_end[0] = time.thread_time()
                while True:
                    t = (k_base + k) * tau
                    if t > t_max:
                        raise LoopAbort(f"the robot could not follow the reference: after {t:.1f} s the "
                                        f"reference clock stands at {law.reference_time_s:.1f} of "
                                        f"{law.reference.tf_s:.1f} s; stopping", "diverged")
                    self._touch_bus()
                    self._before_read()
                    try:
                        st = self._read()
                    except LoopAbort as exc:
                        if not self._recovered(exc, d1, d2):
                            raise
                        k_base += k      # resume at the same trajectory time, on a new schedule
                        k = 0
                        ticker.start()
                        self._last_tx = t_prev_meas = None
                        odo = Odometry(geom, odo.pose)   # a rebooted servo's wheel angle starts over
                        continue
                    t_meas = self.clock.now()     # the reply's time on the loop's clock
                    truth = self._pose_truth()    # the true pose at that time (emulator only)
                    flags = 0
                    if st is None:
                        flags |= _STALE
                    else:
                        dt = tau if t_prev_meas is None else (t_meas - t_prev_meas) * self.time_scale
                        t_prev_meas = t_meas
                        odo.update(dt, st.drive_radps, st.steer_rad, st.drive_rad)
                        meas = st
                    pose = odo.pose_floats
                    state = [*pose, d1, d2]
                    out = law.step(t, state)
                    if out.finished:
                        break
                    v1, w1, w2 = out.inputs
                    d1, d2 = out.delta1_rad, out.delta2_rad
                    drive, steer = self._goals(v1, d1, d2)
                    self._touch_bus(t_meas)
                    self.wheels.write_goals(drive, steer)
                    period = ticker.stats.periods_s[-1] * self.time_scale if ticker.stats.periods_s else np.nan
                    if ticker.stats.overruns and rows and ticker.stats.overruns > rows[-1][-1]:
                        flags |= _OVERRUN
                    # the law's diagnostics become arrays off the cycle's chain (at the end, in the log)
                    rows.append((t, state, truth, (v1, w1, w2), out, ticker.stats.overruns))
                    log_args = None
                    if self.on_cycle is not None:
                        log_args = (k_base + k, t, period, drive, steer, v1, w1, w2, meas, pose,
                                    out.diagnostics[4], truth, flags, self._stamp_ns())

                    def finish_cycle(log_args=log_args):
                        # the log's record is built and written while a lockstep emulator runs
                        # the physics and serves the next read (the clock's defer)
                        if log_args is not None:
                            self.on_cycle(self._cycle(*log_args))
                        now = time.thread_time()
                        cpu_s.append(now - cpu_end[0])
                        cpu_end[0] = now

                    k = ticker.wait(finish_cycle)
                    busy_s.append(ticker.last_busy_s)
            except LoopAbort as exc:
                aborted = exc
                log.error("%s", exc)
            finally:
                try:
                    self.clock.run_deferred()   # the last cycle's log, if no write has run it
                finally:
                    self._stop_quietly()
        cpu_overruns = sum(busy + cpu > ticker.period_s for busy, cpu in zip(busy_s, cpu_s))
        return self._result(rows, ticker, aborted, cpu_s, cpu_overruns)

    def _recovered(self, exc: LoopAbort, d1: float, d2: float) -> bool:
        """Let the fault policy handle a servo's hardware error; True when the run may resume."""
        if self.fault_policy is None or exc.cause != "hardware error":
            return False
        return bool(self.fault_policy.recover(exc, self.wheels, lambda: self.move_to_start(d1, d2)))

    def _stop_quietly(self) -> None:
        try:
            self.wheels.stop()
        except Exception as exc:  # noqa: BLE001 - the bus may be the thing that failed
            log.warning("could not command zero wheel speed: %s", exc)

    @staticmethod
    def _cycle(k, t, period, drive, steer, v1, w1, w2, meas, pose, sd, truth, flags, stamp_ns) -> dict:
        """The ``on_cycle`` dict: :class:`tools.logs.record.CycleRecord` fields, float64 arrays.

        ``pose`` and ``truth``: 3 floats each; ``sd``: the reference state, 5 floats."""
        if meas is None:
            meas_drive = meas_steer = np.full(4, np.nan)
            meas_current = np.full(8, np.nan)
        else:
            meas_drive, meas_steer = np.array(meas.drive_radps), np.array(meas.steer_rad)
            meas_current = np.array([*meas.drive_current_a, *meas.steer_current_a])
        sd = np.array(sd, float)
        return dict(
            cycle=k, t_s=t, stamp_ns=stamp_ns, period_s=period,
            cmd_drive_radps=np.array(drive, float), cmd_steer_rad=np.array(steer, float),
            cmd_v1_mps=float(v1), cmd_omega_radps=np.array([w1, w2]),
            meas_drive_radps=meas_drive, meas_steer_rad=meas_steer, meas_current_a=meas_current,
            est_pose=np.array(pose, float), ref_pose=sd[:3], ref_delta=sd[3:5], true_pose=np.array(truth, float),
            flags=flags)

    def _result(self, rows, ticker: Ticker, aborted, cpu_s=(), cpu_overruns=0) -> LoopResult:
        traj = self.law.reference.trajectory
        cpu_ms = np.asarray(cpu_s) * 1e3
        timing = dataclasses.replace(
            ticker.stats.timing(), loop_period_target_ms=self.tau_s * 1e3 / self.time_scale,
            host_cpu_p50_ms=float(np.percentile(cpu_ms, 50)) if cpu_ms.size else None,
            host_cpu_p99_ms=float(np.percentile(cpu_ms, 99)) if cpu_ms.size else None,
            host_cpu_overruns=cpu_overruns if self.count_host_cpu else None)
        common = dict(timing=timing, cycles=len(rows), failed_reads=self.failed_reads,
                      time_scale=self.time_scale, aborted=aborted)
        if not rows:
            return LoopResult(*(np.empty((0,)) for _ in range(5)), tracking=None, **common)
        cols = list(zip(*rows))
        t = np.array(cols[0])
        est = np.array(cols[1])
        truth = np.array(cols[2])
        use_truth = bool(np.all(np.isfinite(truth)))
        states = est.copy()
        if use_truth:
            states[:, :3] = truth
        # the law's diagnostics: (error, u, ud, raw, desired_state) per cycle
        err, u, ud, raw, desired = (np.array(c, dtype=float) for c in zip(*(o.diagnostics for o in cols[4])))
        ref_t = np.array([o.reference_time_s for o in cols[4]])
        res = SimResult(t, states, np.array(cols[3]), raw, ref_t, desired, err, u - ud, traj.tf_s)
        settled = bool(np.any(t >= traj.tf_s / 4))
        if not settled:  # stopped before tf/4: the settled-error keys are undefined, not 0
            res.tf_s = 0.0
        tracking = tracking_errors(
            metrics(res, traj.Q, traj.R, self.tau_s), "true_pose" if use_truth else "odometry",
            settled, np.hypot(*(est[:, :2] - truth[:, :2]).T) if use_truth else None)
        return LoopResult(t, est, truth, desired, np.array(cols[3]), tracking=tracking, **common)
