"""The run summary as typed records: tracking errors, loop timing, and the whole run.

``swerve run`` prints :meth:`RunSummary.to_dict` (flat keys with units in their names, the
keys of ``swerve sim --json`` among them); a field that does not apply (no emulator, no log,
not aborted) is ``None`` and left out of the dict.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass

from swerve.tools.recovery import ServoFaults


@dataclass(frozen=True)
class TrackingErrors:
    """How well a run tracked its reference (:func:`swerve.controller.simulate.metrics`).

    Position errors in m over t >= tf/4 (NaN if the run stopped before tf/4),
    ``final_position_error_m`` at the last cycle; ``max_abs_v1_mps``,
    ``max_abs_steer_rate_radps`` of the applied inputs; ``cost`` the run's chained-coordinate
    LQ cost; ``max_reference_lag_s`` how far the governor held the reference back;
    ``saturated_fraction`` of the cycles; ``duration_s`` of the run. ``error_source`` is
    ``"true_pose"`` (emulator ground truth) or ``"odometry"`` (the robot's estimate);
    ``odometry_vs_true_*_m`` compare the two where the truth is known.
    """

    rms_position_error_m: float
    max_position_error_m: float
    final_position_error_m: float
    max_abs_v1_mps: float
    max_abs_steer_rate_radps: float
    cost: float
    max_reference_lag_s: float
    saturated_fraction: float
    duration_s: float
    error_source: str
    odometry_vs_true_max_m: float | None = None
    odometry_vs_true_final_m: float | None = None


@dataclass(frozen=True)
class LoopTiming:
    """Measured loop periods in the clock's ms (wall, or robot time in lockstep: target, p50,
    p99, max), ``loop_cycles`` timed, ``overruns`` (cycles that ran past the next deadline) and
    the ``missed_slots`` they skipped. Host-measured, so different on every run:
    ``host_cpu_p50_ms``/``host_cpu_p99_ms`` (the loop's CPU time per cycle) and, in lockstep,
    ``host_cpu_overruns`` (cycles whose robot-time bus work plus that CPU time exceeds the period;
    they are counted, not scheduled: the schedule and the log stay deterministic)."""

    loop_period_target_ms: float
    loop_period_p50_ms: float
    loop_period_p99_ms: float
    loop_period_max_ms: float
    loop_cycles: int
    overruns: int
    missed_slots: int
    host_cpu_p50_ms: float | None = None
    host_cpu_p99_ms: float | None = None
    host_cpu_overruns: int | None = None


@dataclass(frozen=True)
class EmulatorStats:
    """What the emulator counted: replies it dropped (fault injection), the time scale it
    achieved (robot s per wall s; wall clock only), the robot time it lost to a slow host, s, and
    its physics' real-time factor (robot s per CPU s of physics steps; host-measured) and the CPU
    its process spent serving the bus, physics included (s; host-measured)."""

    emulator_replies_dropped: int
    emulator_achieved_time_scale: float | None
    emulator_lost_sim_s: float | None
    emulator_physics_real_time_factor: float | None = None
    emulator_cpu_s: float | None = None


@dataclass(frozen=True)
class LiveStats:
    """The live view: its ``live_url`` and the records it ``live_published`` and ``live_dropped``."""

    live_url: str
    live_published: int
    live_dropped: int


@dataclass(frozen=True)
class RunSummary:
    """One tracking run.

    ``trajectory`` name; ``port`` (``"emulator"`` or the serial device); ``config`` the robot
    file and ``config_source`` why it was chosen (``--config``, ``$SWERVE_CONFIG``, ``user``,
    ``shipped``); ``time_scale`` robot s per wall s; ``completed`` (False: stopped, see
    ``abort_cause``/``abort_message``); ``cycles`` run; ``failed_reads`` over the run;
    ``tracking`` (None if no cycle ran); ``timing``; the bus's ``bus_stray_replies`` and
    ``bus_corrupt_frames``; ``log`` directory; ``emulator`` counters (None on the robot);
    ``servo_faults`` how hardware errors were handled; ``live`` the live view (None without).
    ``clock``: ``"wall"`` or ``"lockstep"`` (robot time owned by the emulator; ``time_scale``
    is then the pacing, ``None`` for as fast as possible); ``wall_time_s`` of the loop and
    ``real_time_factor`` (robot s per wall s over the loop) are host-measured, as are
    ``loop_cpu_s`` (the controller process's CPU time over the loop, all its threads) and
    ``loop_started_unix_s`` (the wall-clock time, s since the epoch, at which the loop began its
    first cycle: a benchmark subtracts the time it started the command to get the start-up).
    """

    trajectory: str
    port: str
    config: str
    config_source: str
    time_scale: float | None
    completed: bool
    cycles: int
    failed_reads: int
    timing: LoopTiming
    tracking: TrackingErrors | None = None
    abort_cause: str | None = None
    abort_message: str | None = None
    bus_stray_replies: int = 0
    bus_corrupt_frames: int = 0
    log: str | None = None
    emulator: EmulatorStats | None = None
    servo_faults: ServoFaults | None = None
    live: LiveStats | None = None
    clock: str = "wall"
    wall_time_s: float | None = None
    real_time_factor: float | None = None
    loop_cpu_s: float | None = None
    loop_started_unix_s: float | None = None

    def to_dict(self) -> dict:
        """Flat ``{key: value}`` of every field that applies (nested records inlined)."""
        out: dict = {}
        for f in dataclasses.fields(self):
            val = getattr(self, f.name)
            if dataclasses.is_dataclass(val):
                out.update((k, v) for k, v in dataclasses.asdict(val).items() if v is not None)
            elif val is not None:
                out[f.name] = val
        return out

    def to_json(self) -> str:
        """:meth:`to_dict` as JSON (sorted keys; NaN written as ``NaN``)."""
        return json.dumps(self.to_dict(), indent=2, sort_keys=True)


def tracking_errors(metrics: dict, error_source: str, settled: bool,
                    odometry_vs_true_m=None) -> TrackingErrors:
    """:class:`TrackingErrors` from :func:`swerve.controller.simulate.metrics`'s dict.

    ``settled``: the run reached tf/4 (else the settled-error fields are NaN, not 0);
    ``odometry_vs_true_m``: per-cycle distance (m) of the estimate from the truth, or None.
    """
    m = dict(metrics)
    if not settled:
        m["rms_position_error_m"] = m["max_position_error_m"] = math.nan
    odo = {}
    if odometry_vs_true_m is not None:
        odo = dict(odometry_vs_true_max_m=float(odometry_vs_true_m.max()),
                   odometry_vs_true_final_m=float(odometry_vs_true_m[-1]))
    return TrackingErrors(error_source=error_source, **m, **odo)
