"""One tracking run, end to end: config → trajectory → gains → bus → loop → log → summary.

Shared by ``swerve run`` and ``swerve demo``. The emulator, when asked for, is started here and
is only ever a port: the driver, the wheel set and the loop are the same code as on the robot.
"""
from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swerve.configs import ConfigChoice
from swerve.controller.gain_schedule import synthesize
from swerve.controller.gains_io import load_gains
from swerve.controller.overlay_cache import OverlayCache
from swerve.controller.reference import build_reference
from swerve.controller.riccati import finite_horizon_lqr
from swerve.controller.riccati_cache import RiccatiCache
from swerve.core.user_cache import user_cache_dir
from swerve.controller.tracking import TrackingLaw
from swerve.controller.trajectory import load_trajectory
from swerve.core.errors import ConfigError
from swerve.driver.bus import Bus, ExchangeSettings
from swerve.driver.robot_config import BUS_WATCHDOG_MAX_S
from swerve.driver.wheelset import WheelSet
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.process import EmulatorProcess
from swerve.emulator.timing import Lockstep, scaled
from swerve.tools.logs.bag import RunLogWriter
from swerve.tools.logs.layout_cache import LayoutCache
from swerve.tools.logs.record import CycleRecord
from swerve.tools.recovery import policy
from swerve.tools.run.geometry import geometry_and_limits, locate_and_load
from swerve.tools.run.lockstep import LOCKSTEP_TIMEOUT_MARGIN_S, LockstepLoopClock
from swerve.tools.run.loop import LoopResult, TrackingLoop
from swerve.tools.run.summary import EmulatorStats, LiveStats, RunSummary
from swerve.tools.signals import shielded_exit

log = logging.getLogger(__name__)

#: Bus timeout slack when the other end is the emulator (a Python process on a shared CPU), s.
EMULATOR_TIMEOUT_MARGIN_S = 0.05
#: Seed of the emulator's fault and noise generators in lockstep when none is given.
LOCKSTEP_SEED = 0
#: Physics rate of the emulated robot in tracking runs, Hz: low enough that the
#: clock keeps up at time scale 5 (configs/emulator.yaml's 2 kHz is for servo step tests).
EMULATOR_PHYSICS_RATE_HZ = 1000.0


@dataclass(frozen=True)
class RunRequest:
    """What to run. ``config``: the ``--config`` value (``None``: the look-up of
    :func:`swerve.configs.locate_robot_file`); ``gains`` ``None``: synthesise (Riccati)."""

    trajectory: str
    gains: str | Path | None = None
    config: str | Path | ConfigChoice | None = None
    port: str | None = None
    emulate: bool = False
    lockstep: bool = False                  # robot time owned by the emulator (needs emulate or control)
    control: str | Path | None = None       # lockstep: control socket of an emulator already serving ``port``
    time_scale: float | None = 1.0          # lockstep: pacing, None = as fast as possible
    log: Path | None = None
    fast_read: bool = False
    faults: str | None = None
    noise: str | None = None                # with emulate: sensor noise, e.g. "position=0.5"
    progress: bool = False
    start_timeout_s: float = 5.0
    timeout_margin_s: float | None = None   # None: driver default, or EMULATOR_TIMEOUT_MARGIN_S
    physics_rate_hz: float | None = None    # emulator physics rate; None: EMULATOR_PHYSICS_RATE_HZ
    emulator_config: str | Path | None = None   # emulator physics: "ideal", "realistic" or a file
    adapter_latency_ms: int | None = None   # with emulate: the USB adapter's latency timer; None: the robot file's
    emulated_robot: str | Path | None = None    # with emulate: the robot file the emulator is built from
                                                # (the truth); None: ``config`` (a calibrated file runs a true robot)
    start: tuple | None = None              # start state (5,), m and rad; None: the trajectory's
    on_servo_fault: str = "stop"            # swerve.tools.recovery.policy: "stop" or "recover"
    live: str | None = None                 # "[HOST:]PORT" of a live view (swerve.tools.live)


def prepare_law(trajectory: str, gains_path, geom, limits, progress: bool = False):
    """``(trajectory, TrackingLaw)``: load the trajectory, load or synthesise (Riccati) its gains."""
    traj = load_trajectory(trajectory, geom, limits)
    gains = load_gains(gains_path) if gains_path is not None else None
    return traj, law_for(traj, gains, geom, limits, progress)


def law_for(traj, gains, geom, limits, progress: bool = False, lqr=finite_horizon_lqr):
    """The :class:`TrackingLaw` of the loaded trajectory ``traj`` with the loaded gain schedule
    ``gains``, or with gains synthesised now for ``None`` by the Riccati solver ``lqr``
    (:func:`finite_horizon_lqr`, or a :class:`RiccatiCache`'s ``solve``)."""
    if gains is not None:           # the reference must use the schedule's chained frames
        ref = build_reference(traj, geom, limits, gains.meta.get("frames", "rotating"))
    else:
        ref, gains = synthesize(traj, "riccati", geom, limits, progress=progress, lqr=lqr)
    return TrackingLaw(ref, gains, limits)


def wall_clock_guards(cfg, time_scale: float):
    """``cfg`` with the host-failure guards stretched to their 1x wall-clock length.

    The Bus Watchdog and the failed-read limit detect a dead host or bus; what they must ride
    out is the host's scheduling, which happens in wall time. Under ``--time-scale S`` (the
    emulator; S = 1 on the robot) they are multiplied by S, so a 20 ms hiccup of a loaded
    machine at 5x is not taken for a dead controller. The watchdog is capped at the item's
    2.54 s.
    """
    if time_scale <= 1.0:
        return cfg
    return dataclasses.replace(
        cfg, bus_watchdog_s=min(BUS_WATCHDOG_MAX_S, cfg.bus_watchdog_s * time_scale),
        max_consecutive_timeouts=math.ceil(cfg.max_consecutive_timeouts * time_scale))


@dataclass(frozen=True)
class RunResult:
    """A finished (or stopped) run: its typed ``summary`` and the loop's per-cycle ``loop`` result."""

    summary: RunSummary
    loop: LoopResult

    @property
    def aborted(self):
        """The :class:`~swerve.tools.run.loop.LoopAbort` that stopped the run, or None."""
        return self.loop.aborted


def run_tracking(req: RunRequest, on_config=None, on_cycle=None) -> RunResult:
    """Run one trajectory; returns a :class:`RunResult` (``aborted`` set on a stop).

    ``on_config``: called with the :class:`swerve.configs.ConfigChoice` once the robot file
    is known (``swerve run`` prints it first). ``on_cycle``: called after each cycle's goals
    were written with the cycle's fields (as the log gets them) and the run's lockstep clock
    (None on the wall clock), e.g. to inject a fault at a chosen robot time with ``clock.fault``.
    """
    if req.lockstep and not (req.emulate or (req.control and req.port)):
        raise ConfigError("lockstep needs the emulator (--emulate); a real bus runs on the wall clock")
    if req.control and not req.lockstep:
        raise ConfigError("a lockstep control socket needs lockstep")
    if not req.lockstep and not (req.time_scale and req.time_scale > 0):
        raise ConfigError(f"time scale must be positive, got {req.time_scale}")
    choice, cfg = locate_and_load(req.config)
    if on_config is not None:
        on_config(choice)
    cfg_path = choice.path
    loop_scale = 1.0 if req.lockstep else req.time_scale     # robot s per loop-clock s
    cfg = wall_clock_guards(cfg, loop_scale)
    geom, limits = geometry_and_limits(cfg)
    traj = load_trajectory(req.trajectory, geom, limits)
    gains = load_gains(req.gains) if req.gains is not None else None   # bad input fails before any start
    start = traj.start_state(geom) if req.start is None else np.asarray(req.start, dtype=float)

    rate_hz = req.physics_rate_hz or EMULATOR_PHYSICS_RATE_HZ
    with contextlib.ExitStack() as stack:
        emu = None
        if req.emulate:     # launched first: the child starts while the gains are synthesised
            physics = resolve_emulator_config(req.emulator_config or "ideal")
            if req.lockstep:
                emu = EmulatorProcess(req.emulated_robot or cfg_path, physics, timing=Lockstep(),
                                      faults=_seeded(req.faults), noise=_seeded(req.noise) or f"seed={LOCKSTEP_SEED}",
                                      body=BodySettings(start_pose=tuple(start[:3])), rate_hz=rate_hz,
                                      adapter_latency_ms=req.adapter_latency_ms)
            else:
                emu = EmulatorProcess(req.emulated_robot or cfg_path, physics, timing=scaled(req.time_scale),
                                      faults=req.faults, noise=req.noise, body=BodySettings(start_pose=tuple(start[:3])),
                                      rate_hz=rate_hz, adapter_latency_ms=req.adapter_latency_ms)
            stack.callback(emu.close)
            emu.launch()
        # the Riccati solution of an input already seen comes from the user's cache, bit for bit
        law = law_for(traj, gains, geom, limits, req.progress, lqr=RiccatiCache(user_cache_dir()).solve)
        # the overlay's poses on the ideal model, of a law and start already seen from the user's cache
        sim = OverlayCache(user_cache_dir()).poses(law, start) if req.log is not None else None
        # built (rosbags' writer; the layouts probed, or from the user's cache) while the emulator
        # starts, opened once it serves
        log_writer = _log_writer(req, cfg, traj, choice) if req.log is not None else None
        true_pose = clock = None
        if req.lockstep:
            if emu is not None:
                emu.start()
                port, control = emu.port, emu.control_path
            else:                                 # an emulator someone else started
                port, control = req.port, str(req.control)
            clock = stack.enter_context(LockstepLoopClock(control, req.time_scale))
            true_pose = clock.pose
        elif emu is not None:
            emu.start()
            port = emu.port
            true_pose = lambda: emu.pose  # noqa: E731
        else:
            port = req.port or cfg.link.port
        # Return Delay starts at the servos' factory value; WheelSet.configure() sets the bus's.
        # The emulator is a Python process on a possibly loaded machine: give its replies slack.
        margin = req.timeout_margin_s if req.timeout_margin_s is not None else (
            LOCKSTEP_TIMEOUT_MARGIN_S if req.lockstep else EMULATOR_TIMEOUT_MARGIN_S if req.emulate else None)
        setup = ExchangeSettings(retries=1, **({} if margin is None else {"timeout_margin_s": margin}))
        fault_policy = policy(req.on_servo_fault, clock=clock, timeout_margin_s=setup.timeout_margin_s)
        # In the loop every read is the same 10-byte block: a missed reply is the next cycle's
        # job (no retry), and its deadline must fit in a cycle (half the wall period at most).
        loop_margin = setup.timeout_margin_s if req.lockstep else \
            min(setup.timeout_margin_s, 0.5 * traj.tau_s / req.time_scale)
        bus = stack.enter_context(Bus(port, cfg.link.baud, default_model=cfg.model, timeout_margin_s=loop_margin))
        if clock is not None:
            clock.attach(bus)
        # its exit stops the wheels and turns the torque off: a stop signal waits for it
        wheels = stack.enter_context(shielded_exit(WheelSet(bus, cfg, fast=req.fast_read)))
        with bus.exchanging(setup):
            wheels.configure()
        callbacks = []
        if log_writer is not None:       # the first file of the run: the bus is open and set up
            req.log.parent.mkdir(parents=True, exist_ok=True)
            callbacks.append(_log_callback(stack.enter_context(shielded_exit(log_writer)), sim))
        live = None
        if req.live is not None:
            from swerve.tools.live import RUN_TOPICS, LivePublisher, parse_live

            topics = RUN_TOPICS + (("/true_pose",) if req.emulate else ())   # what the cycles carry
            live = stack.enter_context(LivePublisher(*parse_live(req.live), wheels=[w.name for w in cfg.wheels],
                                                     topics=topics))
            log.warning("live view on %s", live.url)
            callbacks.append(live.on_cycle)
        if on_cycle is not None:
            callbacks.append(lambda fields: on_cycle(fields, clock))
        loop = TrackingLoop(wheels, law, geom, time_scale=loop_scale,
                            max_failed_reads=cfg.max_consecutive_timeouts,
                            watchdog_s=cfg.bus_watchdog_s, true_pose=true_pose, on_cycle=_chain(callbacks),
                            fault_policy=fault_policy, clock=clock, count_host_cpu=req.lockstep)
        wheels.enable()
        loop.move_to_start(start[3], start[4], timeout_s=req.start_timeout_s)
        if clock is not None:
            clock.align(1.0 / rate_hz)       # deadlines on the physics step grid
        robot0, wall0 = (clock.now() if clock is not None else None), time.monotonic()
        started_unix_s, cpu0 = time.time(), time.process_time()
        result = loop.run(start)
        wall_s, cpu_s = time.monotonic() - wall0, time.process_time() - cpu0
        robot_s = clock.now() - robot0 if clock is not None else wall_s * loop_scale
        bus_counts = dict(bus_stray_replies=bus.stray_replies, bus_corrupt_frames=bus.corrupt_frames)
        counters = clock.counters() if clock is not None else None
        live_stats = None if live is None else LiveStats(live.url, live.published, live.dropped)
    emulator = None
    if req.emulate and emu.final_stats:
        bus_stats, clock_stats = emu.final_stats["bus"], emu.final_stats["clock"]
        emulator = EmulatorStats(bus_stats.get("replies_dropped", 0),
                                 None if req.lockstep else clock_stats.get("achieved_scale"),
                                 clock_stats.get("lost_sim_s"), clock_stats.get("real_time_factor"),
                                 emu.final_stats.get("serve_cpu_s"))
    elif counters is not None:
        emulator = EmulatorStats(counters.get("replies_dropped", 0), None, 0.0)
    aborted = result.aborted
    summary = RunSummary(
        trajectory=traj.name, port="emulator" if req.emulate or req.lockstep else port, config=str(cfg_path),
        config_source=choice.source, time_scale=req.time_scale if req.lockstep else result.time_scale,
        completed=result.completed,
        cycles=result.cycles, failed_reads=result.failed_reads, timing=result.timing,
        tracking=result.tracking, abort_cause=None if aborted is None else aborted.cause,
        abort_message=None if aborted is None else str(aborted), **bus_counts,
        log=None if req.log is None else str(req.log), emulator=emulator,
        clock="lockstep" if req.lockstep else "wall", wall_time_s=wall_s,
        real_time_factor=robot_s / wall_s if wall_s > 0 else None,
        loop_cpu_s=cpu_s, loop_started_unix_s=started_unix_s,
        servo_faults=fault_policy.summary(), live=live_stats)
    return RunResult(summary, result)


def _chain(callbacks):
    """One ``on_cycle`` callback calling each of ``callbacks`` in turn (None for none)."""
    if not callbacks:
        return None
    if len(callbacks) == 1:
        return callbacks[0]

    def on_cycle(fields: dict) -> None:
        for cb in callbacks:
            cb(fields)

    return on_cycle


def _seeded(faults: str | None) -> str | None:
    """A fault or noise spec with ``seed=LOCKSTEP_SEED`` added when it names none (lockstep is
    repeatable)."""
    if not faults or "seed=" in faults:
        return faults
    return f"{faults},seed={LOCKSTEP_SEED}"


def _log_writer(req: RunRequest, cfg, traj, choice) -> RunLogWriter:
    """The run log's writer, not yet open (nothing is written until it is entered)."""
    meta = dict(trajectory=traj.name, trajectory_source=str(traj.source), gains=str(req.gains or "riccati"),
                time_scale=req.time_scale, port="emulator" if req.emulate or req.lockstep else (req.port or cfg.link.port),
                config=str(choice.path), config_source=choice.source,
                started=time.strftime("%Y-%m-%dT%H:%M:%S%z"), tau_s=traj.tau_s,
                tf_s=traj.tf_s)
    wheels = [w.name for w in cfg.wheels]
    # the layouts rosbags' type system gives for these wheels, from the user's cache once seen
    return RunLogWriter(req.log, meta, wheels=wheels, layouts=LayoutCache(user_cache_dir()).layouts(wheels))


def _log_callback(writer: RunLogWriter, sim: np.ndarray):
    """The loop's ``on_cycle`` callback writing each cycle, with the overlay pose ``sim[k]``,
    into the open ``writer``."""

    def on_cycle(fields: dict) -> None:
        k = fields["cycle"]
        sim_pose = sim[k] if k < len(sim) else np.full(3, np.nan)
        writer.write(CycleRecord(sim_pose=sim_pose, **fields))

    return on_cycle
