"""The emulated robot: eight servos with physics on one body, behind the Protocol 2.0 pty bus.

::

    from swerve.emulator.robot_emulator import robot_emulator

    with robot_emulator(time_scale=0) as emu:         # 0: no clock, step with emu.advance()
        ...                                           # open emu.port with driver.bus.Bus
        emu.advance(0.016)                            # 16 ms of simulated time, 2 kHz steps
        x, y, theta = emu.pose                        # true pose, never through the bus

    with robot_emulator(time_scale=5, status_file="/tmp/pose.json") as emu:
        ...                                           # physics runs on its own clock, 5x real time

The physics (:mod:`emulator.physics`) advances in fixed steps of ``1 / physics.rate_hz``
simulated seconds. With ``time_scale = S > 0`` the bus thread runs the steps that wall time
demands (``S * rate_hz`` steps per wall second) whenever no request is pending, taking the bus
lock per step; a request waits for one step at most, and physics never competes with the bus
for the interpreter lock. If the CPU cannot keep up, it runs the owed steps
back to back; beyond :data:`MAX_BACKLOG_WALL_S` of backlog it drops simulated time and counts
it in :class:`ClockStats` (``lost_sim_s``, ``fell_behind``) instead of slowing down silently.

The status file (JSON, rewritten atomically with ``os.replace`` at ``status_hz`` of wall time)
lets another process read the true pose without touching the bus; see :meth:`RobotEmulator.status`.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from swerve.configs.options import parse_key_values
from swerve.driver.errors import ConfigError
from swerve.emulator.faults import Faults
from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import PhysicsConfig, SensorParams, load_config
from swerve.emulator.physics.robot import RobotPhysics, load_robot_geometry
from swerve.emulator.physics.servo_model import ServoModel
from swerve.emulator.server import Emulator
from swerve.emulator.servo import VirtualServo

log = logging.getLogger(__name__)

#: Longest the clock runs steps before re-reading the wall clock and its backlog, s.
MAX_BATCH_WALL_S = 2e-3
#: Pause after a step when a bus transaction waits for the lock, s.
HAND_OVER_S = 5e-5
#: Shortest wait of the clock when it is ahead (batches steps at high time scales), s.
MIN_SLEEP_S = 1e-3
#: Backlog (wall seconds of demanded steps) beyond which simulated time is dropped and counted.
MAX_BACKLOG_WALL_S = 0.5
#: GIL hand-over interval while the clock runs, s. CPython's default (5 ms) lets the busy bus
#: thread delay a client in the same process (tests) by up to 5 ms per hand-over.
SWITCH_INTERVAL_S = 2e-4
#: Keys of the ``noise`` spec and the SensorParams fields they set.
NOISE_KEYS = {"position": "position_noise_std_pulse", "current": "current_noise_std_a",
              "voltage": "voltage_noise_std_v"}

#: Control-table items ServoModel.step reads (its docstring); all lie below address 120.
_INPUTS = ("torque_enable", "operating_mode", "drive_mode", "goal_pwm", "goal_current", "goal_velocity",
           "goal_position", "profile_acceleration", "profile_velocity", "velocity_i_gain",
           "velocity_p_gain", "position_d_gain", "position_i_gain", "position_p_gain",
           "feedforward_1st_gain", "feedforward_2nd_gain", "pwm_limit", "current_limit",
           "velocity_limit", "max_position_limit", "min_position_limit", "moving_threshold",
           "homing_offset", "bus_watchdog", "temperature_limit", "max_voltage_limit", "min_voltage_limit")


class _ServoDynamics:
    """Adapter between one :class:`VirtualServo` and its :class:`ServoModel` (the ``dynamics``).

    Speed, not semantics: the emulator's ``memory.view()`` decodes an item per access. This
    adapter decodes the ~24 input items in one pass from the control-table bytes below the first
    output item, and only when those bytes changed.
    """

    def __init__(self, model: ServoModel, servo: VirtualServo):
        self.model = model
        self._servo = servo
        self._memory = servo.memory
        regs = [servo.table[n] for n in _INPUTS]
        self._end = max(r.address + r.size for r in regs)
        self._layout = [(r.name, r.address, r.address + r.size, r.signed) for r in regs]
        self._raw = b""
        self._items: dict[str, int] = {}

    def _input_bytes(self) -> bytes:
        # ServoMemory keeps the table in ``_bytes``; read() gives the same bytes 20x slower
        # (it resolves indirect data per address; nothing below address 120 is indirect).
        raw = getattr(self._memory, "_bytes", None)
        return bytes(raw[:self._end]) if raw is not None else self._memory.read(0, self._end)

    def inputs(self) -> dict[str, int]:
        """The input items (raw, signed where signed), decoded afresh only if their bytes changed."""
        raw = self._input_bytes()
        if raw != self._raw:
            self._raw = raw
            self._items = {n: int.from_bytes(raw[a:b], "little", signed=s) for n, a, b, s in self._layout}
        return self._items

    def advance(self, dt_s: float, table: Mapping[str, int]) -> None:
        """One physics step under the servo's current input items."""
        self.model.advance(dt_s, self.inputs())
        if self.model.pending_hardware_error:       # the physics tripped a protection: latch it
            self._servo.raise_hardware_error(self.model.take_hardware_error())

    def outputs(self) -> dict[str, int]:
        """Present items as of the last step (at rest before the first)."""
        return self.model.outputs()

    def reboot(self) -> None:
        self.model.reboot()
        self._raw = b""

    def clear_multi_turn(self) -> None:
        self.model.clear_multi_turn()


class _HandOverLock:
    """The emulator's one lock, plus who is waiting for it (so the clock can step aside).

    A plain :class:`threading.Lock` is not fair: a clock that releases it and takes it
    again at once starves another thread waiting for it (the status file, fault injection,
    pose readers). The clock checks :attr:`waiting` after each physics step and pauses only
    then, so it loses no time when nobody waits. ``set.add``/``discard`` are atomic.
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


class _BodyClock:
    """The ``world`` of the emulator: moves the body after the servos and counts simulated time."""

    def __init__(self, physics: RobotPhysics):
        self.physics = physics
        self.t_s = 0.0
        self.steps = 0

    def step(self, dt_s: float, servos: object = None) -> None:
        self.physics.step_body(dt_s)
        self.steps += 1
        self.t_s += dt_s


class RobotEmulator(Emulator):
    """An :class:`Emulator` whose servos run :mod:`emulator.physics` and move one robot body.

    Build it with :func:`robot_emulator`. Extra attributes: :attr:`physics` (the
    :class:`RobotPhysics`), :attr:`pose`, :attr:`sim_time_s`, :meth:`status`,
    :attr:`clock_stats`, :attr:`status_file`.
    """

    def __init__(self, physics: RobotPhysics, *, rate_hz: float, status_file: str | os.PathLike | None = None,
                 status_hz: float = 20.0, **kwargs):
        if rate_hz < 1000:
            raise ConfigError(f"physics rate must be >= 1000 Hz, got {rate_hz:g}")
        if status_hz <= 0:
            raise ConfigError(f"status_hz must be > 0, got {status_hz:g}")
        self.physics = physics
        self._body = _BodyClock(physics)
        super().__init__(dynamics=lambda s: (_ServoDynamics(physics.servos[s.id], s)
                                            if s.id in physics.servos else None), world=self._body,
                         clock_hz=rate_hz, **kwargs)
        self._lock = _HandOverLock()      # before any thread starts: every user sees this one
        missing = set(physics.servos) - {s.id for s in self.servos}
        if missing:
            raise ConfigError(f"the robot's servos {sorted(missing)} are not on the emulated bus")
        for servo in self.servos:         # steering shafts start at their centre, not at pulse 0
            if servo.dynamics is not None:
                servo.memory.stale = True
        self.rate_hz = float(rate_hz)
        for model in physics.servos.values():     # SciPy's first expm would stall the bus at torque-on
            model.prepare(1.0 / self.rate_hz)
        self.status_file = None if status_file is None else Path(status_file)
        self.status_hz = float(status_hz)
        self.clock_stats = ClockStats(time_scale=self.time_scale, rate_hz=self.rate_hz)
        self._clock_t0: float | None = None     # wall time of the first physics step
        self._clock_skipped = 0                 # steps dropped when the clock fell behind
        #: Called by the physics clock after each run of steps with ``(sim_time_s, pose)``,
        #: from the bus thread (keep it short; no lock needed).
        self.on_batch: Callable[[float, tuple[float, float, float]], None] | None = None
        self._status_thread: threading.Thread | None = None
        self._status_stop = threading.Event()
        self._previous_switch_s: float | None = None

    # --- true state (never through the bus) ------------------------------------------------------
    @property
    def pose(self) -> tuple[float, float, float]:
        """True body pose ``(x_m, y_m, theta_rad)`` in the world frame (coherent snapshot)."""
        with self.lock:
            return self.physics.body.pose

    @property
    def sim_time_s(self) -> float:
        """Simulated seconds since construction (clock and :meth:`advance` together)."""
        with self.lock:
            return self._body.t_s

    def true_state(self) -> tuple[float, tuple[float, float, float]]:
        """``(sim_time_s, (x_m, y_m, theta_rad))`` read under one lock (a coherent pair)."""
        with self.lock:
            return self._body.t_s, self.physics.body.pose

    def status(self) -> dict:
        """The status-file document: simulated time, pose, twist, wheels, slip, clock health.

        ``{"t_s", "pose": [x_m, y_m, theta_rad], "twist": [vx_mps, vy_mps, omega_radps] (body
        frame), "wheels": [{"name", "speed_mps", "steer_rad", "slip_mps"} x 4], "slip_rms_mps",
        "clock": ClockStats.as_dict()}``. Wheel speeds and angles are the true shaft states in
        the wheel frame (direction signs and steering centre applied).
        """
        with self.lock:
            body = self.physics.body
            speeds, steer = self.physics.wheel_state()
            slip = np.asarray(body.residual_mps, float)
            doc = {
                "t_s": self._body.t_s,
                "pose": list(body.pose),
                "twist": [float(v) for v in body.twist],
                "wheels": [{"name": w.name, "speed_mps": float(v), "steer_rad": float(d), "slip_mps": float(s)}
                           for w, v, d, s in zip(self.physics.geometry.wheels, speeds, steer, slip)],
                "slip_rms_mps": float(np.sqrt(np.mean(slip ** 2))) if slip.size else 0.0,
            }
        doc["clock"] = self.clock_stats.as_dict()
        return doc

    def write_status(self) -> None:
        """Write :meth:`status` to :attr:`status_file` atomically (temp file + ``os.replace``)."""
        if self.status_file is None:
            return
        tmp = self.status_file.with_name(f".{self.status_file.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(self.status()) + "\n")
        os.replace(tmp, self.status_file)

    # --- lifecycle -------------------------------------------------------------------------------
    def start(self) -> "RobotEmulator":
        if self._pty is not None:
            return self
        if self.time_scale > 0:           # process-wide; restored by close()
            self._previous_switch_s = sys.getswitchinterval()
            sys.setswitchinterval(min(self._previous_switch_s, SWITCH_INTERVAL_S))
        super().start()
        if self.status_file is not None:
            self.write_status()
            self._status_stop.clear()
            self._status_thread = threading.Thread(target=self._status_loop, name="emulator-status",
                                                   daemon=True)
            self._status_thread.start()
        return self

    def close(self) -> None:
        if self._status_thread is not None:
            self._status_stop.set()
            self._status_thread.join(timeout=5.0)
            self._status_thread = None
        super().close()
        if self._previous_switch_s is not None:
            sys.setswitchinterval(self._previous_switch_s)
            self._previous_switch_s = None
        if self.status_file is not None:
            try:
                self.write_status()           # the final state, after the clock stopped
            except OSError as exc:
                log.warning("cannot write status file %s: %s", self.status_file, exc)

    def _status_loop(self) -> None:
        period = 1.0 / self.status_hz
        while not self._status_stop.wait(period):
            try:
                self.write_status()
            except OSError as exc:
                log.warning("cannot write status file %s: %s", self.status_file, exc)

    # --- the physics clock, run by the bus thread between requests ---------------------------------
    CLOCK_IN_BUS_THREAD = True

    def _run_clock(self) -> float:
        """Run the physics steps wall time demands (``time_scale * rate_hz`` per wall second).

        Called by the bus thread whenever it is not answering a request, so a request waits for
        one physics step at most and physics never competes with the bus for the interpreter.
        Steps run back to back until caught up, until a request arrives, or for
        :data:`MAX_BATCH_WALL_S`; beyond :data:`MAX_BACKLOG_WALL_S` of backlog, simulated time
        is dropped and counted. Returns the wall seconds until the next step is due (0: more
        is owed now).
        """
        st = self.clock_stats
        now = time.monotonic()
        if self._clock_t0 is None:
            self._clock_t0 = now
        dt = 1.0 / self.rate_hz
        steps_per_wall_s = self.rate_hz * self.time_scale
        st.wall_s = now - self._clock_t0
        backlog = int(st.wall_s * steps_per_wall_s) - self._clock_skipped - st.steps
        if backlog <= 0:
            due = self._clock_t0 + (st.steps + self._clock_skipped + 1) / steps_per_wall_s
            return max(MIN_SLEEP_S, due - now)
        max_backlog = max(1, int(MAX_BACKLOG_WALL_S * steps_per_wall_s))
        if backlog > max_backlog:
            drop = backlog - max_backlog
            self._clock_skipped += drop
            backlog = max_backlog
            st.fell_behind += 1
            st.lost_sim_s += drop * dt
            if st.fell_behind == 1:
                log.warning("physics clock fell behind at time scale %g; dropping simulated time "
                            "(see clock_stats)", self.time_scale)
        st.max_backlog_s = max(st.max_backlog_s, backlog * dt)
        cpu0 = time.thread_time()
        deadline = now + MAX_BATCH_WALL_S
        lock = self._lock
        n = 0
        try:
            while n < backlog:
                with lock:
                    self._tick(dt)
                n += 1
                if self._request_pending():
                    break
                if lock.waiting:
                    time.sleep(HAND_OVER_S)   # let a waiting thread (status, faults) take the lock
                if n & 7 == 0 and time.monotonic() > deadline:
                    break
        except Exception:  # noqa: BLE001 - a physics bug must not kill the bus
            self.stats.dispatch_errors += 1
            log.debug("error in physics tick", exc_info=True)
            n = max(n, 1)
        st.steps += n
        st.batches += 1
        st.backlog_s = (backlog - n) * dt
        st.cpu_s += time.thread_time() - cpu0
        if self.on_batch is not None:
            self.on_batch(self._body.t_s, self.physics.body.pose)
        return 0.0 if n < backlog else MIN_SLEEP_S


def parse_noise(spec: str | Mapping[str, float] | None, base: SensorParams) -> tuple[SensorParams, int | None]:
    """Sensor noise from ``"position=0.5,current=0.003,voltage=0.05,seed=1"`` or a mapping.

    Keys: ``position`` (pulse), ``current`` (A), ``voltage`` (V) standard deviations, ``seed``;
    unnamed fields keep ``base`` (``configs/emulator.yaml: sensors``). Returns ``(params, seed)``.
    """
    if spec is None:
        return base, None
    if isinstance(spec, str):
        items = dict(parse_key_values(spec, "noise", (*NOISE_KEYS, "seed")))
    else:
        items = dict(spec)
    seed = None
    fields = {}
    for key, value in items.items():
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"noise {key}={value!r}: not a number") from None
        if key == "seed":
            seed = int(number)
        elif key in NOISE_KEYS:
            if not (math.isfinite(number) and number >= 0):
                raise ConfigError(f"noise {key}={value!r}: expected a standard deviation >= 0")
            fields[NOISE_KEYS[key]] = number
        else:
            raise ConfigError(f"noise: unknown key {key!r} (keys: {', '.join(NOISE_KEYS)}, seed)")
    return dataclasses.replace(base, **fields), seed


def robot_emulator(robot_config: str | os.PathLike = "configs/robot.yaml",
                   emulator_config: str | os.PathLike = "configs/emulator.yaml", *,
                   time_scale: float = 1.0, status_file: str | os.PathLike | None = None,
                   noise: str | Mapping[str, float] | None = None, faults: Faults | str | None = None,
                   link: str | os.PathLike | None = None, wire_timing: bool = False, baud: int | None = None,
                   start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0), rate_hz: float | None = None,
                   wheel_load: bool | None = None, status_hz: float = 20.0, **emulator_kwargs) -> RobotEmulator:
    """The robot of ``robot_config`` on an emulated bus, with the physics of ``emulator_config``.

    Parameters
    ----------
    robot_config, emulator_config : path
        ``configs/robot.yaml`` (IDs, model, baud, geometry) and ``configs/emulator.yaml`` (physics).
    time_scale : float
        Simulated seconds per wall second; 0 starts no clock (advance with ``emu.advance(dt_s)``).
    status_file : path, optional
        JSON status (:meth:`RobotEmulator.status`) rewritten atomically at ``status_hz`` wall Hz.
    noise : str or mapping, optional
        Sensor noise overriding the config (:func:`parse_noise`), e.g. ``"position=0.5,seed=1"``.
    faults, link, wire_timing, baud
        As for :class:`emulator.Emulator`.
    start_pose : (x_m, y_m, theta_rad)
        Initial true pose of the body.
    rate_hz : float, optional
        Physics rate (>= 1000); default ``physics.rate_hz`` of the config (2 kHz).
    wheel_load : bool, optional
        Reflect the robot's mass onto the drive shafts; default ``body.load_enabled``.
    **emulator_kwargs
        Passed to :class:`emulator.Emulator` (e.g. ``baud_check``).

    Returns
    -------
    RobotEmulator
        Not started: use it as a context manager (or call ``start()``); ``emu.port`` is the pty.
    """
    cfg: PhysicsConfig = load_config(emulator_config)
    sensors, seed = parse_noise(noise, cfg.sensors)
    body = cfg.body if wheel_load is None else dataclasses.replace(cfg.body, load_enabled=bool(wheel_load))
    cfg = dataclasses.replace(cfg, sensors=sensors, body=body)
    geometry = load_robot_geometry(robot_config)
    physics = RobotPhysics(cfg, geometry, np.random.default_rng(seed))
    physics.body.x_m, physics.body.y_m, physics.body.theta_rad = (float(v) for v in start_pose)
    return RobotEmulator(physics, rate_hz=float(rate_hz or cfg.rate_hz), status_file=status_file,
                         status_hz=status_hz, robot_config=robot_config, baud=baud, faults=faults,
                         link=link, wire_timing=wire_timing, time_scale=time_scale, **emulator_kwargs)


def true_pose(emu: RobotEmulator) -> tuple[float, float, float]:
    """The emulated robot's true pose ``(x_m, y_m, theta_rad)`` (same as ``emu.pose``)."""
    return emu.pose


def read_status(path: str | os.PathLike) -> dict:
    """Read a status file written by :class:`RobotEmulator` (another process may be writing it)."""
    return json.loads(Path(path).read_text())


__all__ = ["RobotEmulator", "ClockStats", "robot_emulator", "true_pose", "read_status", "parse_noise"]
