"""Build the emulated bus from parsed configs: servos with motors and firmware, optionally the body.

::

    from swerve.driver.robot_config import load_robot_config
    from swerve.emulator.physics.params import load_config
    from swerve.emulator.robot_emulator import build_emulator

    robot = load_robot_config(path)                       # parsed once, by the caller
    with build_emulator(robot, load_config(), time_scale=0) as emu:   # 0: frozen clock
        ...                                               # open emu.port with driver.bus.Bus
        emu.advance(0.016)                                # 16 ms of simulated time, 2 kHz steps
        x, y, theta = emu.pose                            # true pose, never through the bus

The physics (:mod:`emulator.physics`) advances in fixed steps of ``1 / physics.rate_hz``
simulated seconds, run by the clock object (:mod:`emulator.clock`) in the bus thread between
requests. With a robot config whose eight servos are all on the bus, the servos also move one
:class:`RobotWorld` (the body); otherwise each servo turns a free shaft.

The true pose leaves the emulator through one channel, its observers (called under the bus lock
after each run of physics steps): :class:`StatusFile` writes the JSON status file,
:class:`~swerve.emulator.process.EmulatorProcess` copies it into shared memory.
"""
from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import time
from pathlib import Path
from typing import Iterable, Mapping, Sequence

import numpy as np

from swerve.core.atomic import write_text
from swerve.core.options import parse_key_values
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import RobotConfig
from swerve.driver.span_codec import items_struct
from swerve.emulator.adapter import AdapterSettings, UsbAdapter
from swerve.emulator.clock import DEFAULT_REPLY_LATENCY_S, LockstepPhysicsClock, clock_for
from swerve.emulator.lockstep_socket import ControlServer
from swerve.emulator.faults import Faults
from swerve.emulator.physics.params import PhysicsConfig, SensorParams, load_config
from swerve.emulator.physics.robot import RobotGeometry, RobotPhysics
from swerve.emulator.physics.servo_model import ServoModel, wheel_servo
from swerve.emulator.server import DEFAULT_BAUD, DEFAULT_MODEL, Emulator, LinkSettings, make_servos
from swerve.emulator.servo import VirtualServo

log = logging.getLogger(__name__)

#: Keys of the ``noise`` spec and the SensorParams fields they set.
NOISE_KEYS = {"position": "position_noise_std_pulse", "current": "current_noise_std_a",
              "voltage": "voltage_noise_std_v"}
#: Clock rate of a register-only bus (Realtime Tick and Bus Watchdog), Hz.
FROZEN_RATE_HZ = 1000.0

#: Control-table items ServoModel.step reads (its docstring); all lie below address 120.
_INPUTS = ("torque_enable", "operating_mode", "drive_mode", "goal_pwm", "goal_current", "goal_velocity",
           "goal_position", "profile_acceleration", "profile_velocity", "velocity_i_gain",
           "velocity_p_gain", "position_d_gain", "position_i_gain", "position_p_gain",
           "feedforward_1st_gain", "feedforward_2nd_gain", "pwm_limit", "current_limit",
           "velocity_limit", "max_position_limit", "min_position_limit", "moving_threshold",
           "homing_offset", "bus_watchdog", "temperature_limit", "max_voltage_limit", "min_voltage_limit")


class _ServoDynamics:
    """Adapter between one :class:`VirtualServo` and its :class:`ServoModel` (the ``dynamics``).

    Speed, not semantics: ``memory.view()`` decodes an item per access. This adapter decodes the
    ~24 input items in one pass from the stored bytes below the first output item
    (:meth:`ServoMemory.stored_bytes`), and only when those bytes changed.
    """

    def __init__(self, model: ServoModel, servo: VirtualServo):
        self.model = model
        self._servo = servo
        self._memory = servo.memory
        names, fmt = items_struct(servo.table, _INPUTS)    # address order, gaps as pad bytes, from byte 0
        self._names = list(names)
        self._end = fmt.size
        self._unpack = fmt.unpack_from
        self._raw = b""
        self._items: dict[str, int] = {}

    def inputs(self) -> dict[str, int]:
        """The input items (raw, signed where signed), decoded afresh only if their bytes changed
        (then a new dict: an unchanged one is the same object)."""
        raw = self._memory.stored_bytes(self._end)
        if raw != self._raw:
            self._raw = raw
            self._items = dict(zip(self._names, self._unpack(raw)))
        return self._items

    def advance(self, dt_s: float, table: Mapping[str, int]) -> None:
        """One physics step under the servo's current input items."""
        self.advance_many(dt_s, 1, table)
        bits = self.take_hardware_error()
        if bits:                                    # the physics tripped a protection: latch it
            self._servo.raise_hardware_error(bits)

    def advance_many(self, dt_s: float, n: int, table: Mapping[str, int],
                     traces: Mapping[ServoModel, tuple] | None = None) -> int:
        """Up to ``n`` physics steps under the current input items (:meth:`ServoModel.run`; read
        from the stored bytes, not from the item view ``table``); stops after a step that raised
        a Hardware Error bit (:meth:`take_hardware_error`, for the caller to latch).
        ``traces[model]``: the ``(speeds, positions)`` lists the model appends to per step, if
        present. Returns the steps run."""
        speeds, positions = traces.get(self.model, (None, None)) if traces else (None, None)
        items, same = self.current_inputs()
        return self.model.run(dt_s, items, n, same_inputs=same, speeds=speeds, positions=positions)

    def current_inputs(self) -> tuple[dict[str, int], bool]:
        """``(items, same)``: :meth:`inputs`, and whether they are the mapping of the last call."""
        items = self._items
        return self.inputs(), self._items is items

    def take_hardware_error(self) -> int:
        """Hardware Error bits the physics raised since the last call (then cleared)."""
        return self.model.take_hardware_error() if self.model.pending_hardware_error else 0

    @property
    def batchable(self) -> bool:
        """True if steps may run several at a time, servo after servo: no sensor noise, whose
        draws from the shared generator would then come in another order."""
        s = self.model.sensors
        return not (s.position_noise_std_pulse or s.current_noise_std_a or s.voltage_noise_std_v)

    def outputs(self) -> dict[str, int]:
        """Present items as of the last step (at rest before the first)."""
        return self.model.outputs()

    def reboot(self) -> None:
        self.model.reboot()
        self._raw = b""

    def clear_multi_turn(self) -> None:
        self.model.clear_multi_turn()


class RobotWorld:
    """The robot body of the emulator: moved by the servos' shafts after each step."""

    def __init__(self, physics: RobotPhysics):
        self.physics = physics

    @property
    def pose(self) -> tuple[float, float, float]:
        return self.physics.body.pose

    def step(self, dt_s: float) -> None:
        self.physics.step_body(dt_s)

    def traces(self) -> dict[ServoModel, tuple] | None:
        """Empty per-step trace lists for a run of several steps, servo after servo
        (:meth:`RobotPhysics.traces`), or ``None`` if the body must step between the servos."""
        return self.physics.traces()

    def step_many(self, dt_s: float, n: int, traces: Mapping[ServoModel, tuple]) -> None:
        """``n`` body steps from the servos' recorded ``traces`` (:meth:`RobotPhysics.step_body_many`)."""
        self.physics.step_body_many(dt_s, n, traces)

    def run_coupled(self, servos: Sequence[VirtualServo], dt_s: float, n: int) -> int:
        """Up to ``n`` steps of the ``servos`` (their timers, Bus Watchdog and physics) and the
        body in one compiled call (:meth:`RobotPhysics.run_coupled`), where the servos and the
        body must step together (tyre contact) and the compiled kernel exists; the same result as
        ``n`` times each servo's :meth:`VirtualServo.advance` then :meth:`step`. Runs up to the
        next watchdog trip or physics-raised Hardware Error. Returns the steps run (0: this world
        cannot, step tick by tick)."""
        physics = self.physics
        dynamics = [s.dynamics for s in servos]
        if n < 2 or not physics.coupled() or len(servos) != len(physics.servos) or not all(
                isinstance(d, _ServoDynamics) and d.batchable for d in dynamics):
            return 0
        most = n
        for s in servos:
            most = min(most, s.begin_steps(dt_s, most))
        ran = physics.run_coupled(dt_s, most, {d.model: d.current_inputs() for d in dynamics})
        for s, d in zip(servos, dynamics):
            s.end_steps(dt_s, ran, d.take_hardware_error())
        return ran


def status(emu: Emulator) -> dict:
    """The status-file document of a robot emulator (call under ``emu.lock``).

    ``{"t_s", "pose": [x_m, y_m, theta_rad], "twist": [vx_mps, vy_mps, omega_radps] (body
    frame), "wheels": [{"name", "speed_mps", "steer_rad", "slip_mps"} x 4], "slip_rms_mps",
    "clock": ClockStats.as_dict()}``. Wheel speeds and angles are the true shaft states in
    the wheel frame (direction signs and steering centre applied).
    """
    physics = emu.world.physics
    body = physics.body
    speeds, steer = physics.wheel_state()
    slip = np.asarray(body.residual_mps, float)
    return {
        "t_s": emu.sim_time_s,
        "pose": list(body.pose),
        "twist": [float(v) for v in body.twist],
        "wheels": [{"name": w.name, "speed_mps": float(v), "steer_rad": float(d), "slip_mps": float(s)}
                   for w, v, d, s in zip(physics.geometry.wheels, speeds, steer, slip)],
        "slip_rms_mps": float(np.sqrt(np.mean(slip ** 2))) if slip.size else 0.0,
        "clock": emu.clock_stats.as_dict(),
    }


class StatusFile:
    """Observer writing :func:`status` to ``path`` atomically (temp file + ``os.replace``), at most
    ``hz`` times per wall second, and every time while the emulator is not serving (at start and
    close)."""

    def __init__(self, path: str | os.PathLike, hz: float = 20.0):
        if not hz > 0:
            raise ConfigError(f"status_hz must be > 0, got {hz:g}")
        self.path = Path(path)
        self.period_s = 1.0 / hz
        self._next_t = 0.0

    def __call__(self, emu: Emulator) -> None:
        now = time.monotonic()
        if now >= self._next_t or not emu.running:
            self._next_t = now + self.period_s
            self.write(emu)

    def write(self, emu: Emulator, strict: bool = False) -> None:
        """Write the file now; a failure raises with ``strict`` (at start), else is logged."""
        try:
            write_text(self.path, json.dumps(status(emu)) + "\n", fsync=False, mkdir=False)
        except OSError as exc:
            if strict:
                raise
            log.warning("status file: %s", exc)


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


def build_emulator(robot: RobotConfig | None = None, physics: PhysicsConfig | None = None, *,
                   ids: Iterable[int] | None = None, model: str | None = None, baud: int | None = None,
                   body: bool | None = None, time_scale: float = 1.0, rate_hz: float | None = None,
                   noise: str | Mapping[str, float] | None = None, wheel_load: bool | None = None,
                   start_pose: tuple[float, float, float] = (0.0, 0.0, 0.0),
                   faults: Faults | str | None = None, status_file: str | os.PathLike | None = None,
                   status_hz: float = 20.0, limit_error=None, lockstep: bool = False,
                   control_path: str | os.PathLike | None = None,
                   reply_latency_s: float = DEFAULT_REPLY_LATENCY_S,
                   adapter_latency_ms: int | None = None, **link: object) -> Emulator:
    """The emulated bus, built from already-parsed configs (nothing is read from disk here).

    Parameters
    ----------
    robot : RobotConfig, optional
        IDs, model, link baud and geometry (``driver.robot_config``); ``ids``/``model``/``baud``
        override it (default IDs 1-8, xh430-w210, 1 Mbps without one).
    physics : PhysicsConfig, optional
        ``configs/emulator.yaml``. Given: every servo runs its motor and firmware loops.
        ``None``: a register-only bus (Present* items stay put).
    body : bool, optional
        Add the robot body (needs ``robot`` and ``physics``; raises if a robot servo is missing).
        Default: when all of the robot's servos are on the bus.
    time_scale : float
        Simulated seconds per wall second; 0: frozen clock (step with ``emu.advance(dt_s)``).
    rate_hz : float, optional
        Clock rate (physics: >= 1000, default ``physics.rate_hz``; register-only: 1000).
    noise : str or mapping, optional
        Sensor noise overriding the config (:func:`parse_noise`), e.g. ``"position=0.5,seed=1"``.
    wheel_load : bool, optional
        Reflect the robot's mass onto the drive shafts (with a body); default ``body.load_enabled``.
    start_pose : (x_m, y_m, theta_rad)
        Initial true pose of the body.
    faults : Faults or str, optional
        Fault injection (:mod:`emulator.faults`).
    status_file : path, optional
        JSON status (:func:`status`) rewritten atomically at ``status_hz`` wall Hz (needs a body).
    lockstep : bool
        Robot time advances only when a client asks, through the control channel (a Unix socket
        at ``control_path``, a temporary one by default; ``emu.control.path``); every exchange is
        charged at its wire time plus ``reply_latency_s`` per answering servo
        (:class:`~swerve.emulator.clock.LockstepPhysicsClock`). ``time_scale`` is then ignored.
    adapter_latency_ms : int, optional
        The USB-serial adapter's latency timer, ms (1..255; :mod:`swerve.emulator.adapter`),
        overriding the robot file's ``link.adapter_latency_ms``. Neither: no adapter (the host
        reads the cable directly).
    **link
        :class:`~swerve.emulator.server.LinkSettings` fields (``path``, ``wire_timing``, ...).

    Returns
    -------
    Emulator
        Not started: use it as a context manager (or call ``start()``); ``emu.port`` is the pty.
    """
    robot_ids = sorted(robot.drive_ids + robot.steer_ids) if robot is not None else None
    ids = sorted(ids) if ids is not None else (robot_ids or list(range(1, 9)))
    if not (math.isfinite(time_scale) and time_scale >= 0):
        raise ConfigError(f"time scale must be a finite number >= 0, got {time_scale}")
    if rate_hz is not None and not (math.isfinite(rate_hz) and rate_hz > 0):
        raise ConfigError(f"clock rate must be a finite number > 0 Hz, got {rate_hz}")
    if isinstance(faults, str):
        faults = Faults.parse(faults)
    if faults is not None:
        stray = sorted((faults.vanished | set(faults.pending_hw_errors)) - set(ids))
        if stray:
            raise ConfigError(f"--faults names servo ID {', '.join(map(str, stray))}, not on the emulated bus "
                              f"(IDs {', '.join(map(str, ids))})")
    model = model or (robot.model if robot is not None else DEFAULT_MODEL)
    baud = int(baud or (robot.link.baud if robot is not None else DEFAULT_BAUD))
    settings = LinkSettings(baud=baud, **link)
    if adapter_latency_ms is None and robot is not None:
        adapter_latency_ms = robot.link.adapter_latency_ms
    adapter = None if adapter_latency_ms is None else UsbAdapter(AdapterSettings(adapter_latency_ms))
    if body is None:
        body = physics is not None and robot_ids is not None and set(robot_ids) <= set(ids)
    if body and (robot is None or physics is None):
        raise ConfigError("the robot body needs a robot config and a physics config")
    if status_file is not None and not body:
        raise ConfigError("a status file needs the robot body (all the robot's servos on the bus)")
    extra = {} if limit_error is None else {"limit_error": limit_error}
    if physics is None:
        if noise is not None:
            raise ConfigError("sensor noise needs physics")
        servos = make_servos(ids, model, baud, **extra)
        clock, control = _clock(lockstep, time_scale, rate_hz or FROZEN_RATE_HZ, control_path, reply_latency_s)
        return Emulator(servos, link=settings, clock=clock, faults=faults, control=control, adapter=adapter)

    rate_hz = float(rate_hz or physics.rate_hz)
    if rate_hz < 1000:
        raise ConfigError(f"physics rate must be >= 1000 Hz, got {rate_hz:g}")
    sensors, seed = parse_noise(noise, physics.sensors)
    load = physics.body if wheel_load is None else dataclasses.replace(physics.body, load_enabled=bool(wheel_load))
    physics = dataclasses.replace(physics, sensors=sensors, body=load)
    rng = np.random.default_rng(seed)
    world = None
    if body:
        missing = set(robot_ids) - set(ids)
        if missing:
            raise ConfigError(f"the robot's servos {sorted(missing)} are not on the emulated bus")
        robot_physics = RobotPhysics(physics, RobotGeometry(robot.model, robot.wheel_radius_m, robot.wheels), rng)
        robot_physics.body.x_m, robot_physics.body.y_m, robot_physics.body.theta_rad = (float(v) for v in start_pose)
        models = dict(robot_physics.servos)
        world = RobotWorld(robot_physics)
    else:
        centers = {w.steer_id: w.center_pulse for w in robot.wheels} if robot is not None else {}
        models = {i: wheel_servo(physics, model, steering=i in centers, center_pulse=centers.get(i), rng=rng)
                  for i in ids}            # steering shafts start at their centre
    for m in models.values():           # SciPy's first expm would stall the bus at torque-on
        m.prepare(1.0 / rate_hz)
    if world is not None:
        world.physics.prepare(1.0 / rate_hz)
    servos = make_servos(ids, model, baud, **extra,
                         dynamics=lambda s: _ServoDynamics(models[s.id], s) if s.id in models else None)
    for s in servos:                    # present items from the physics, not the table defaults
        if s.dynamics is not None:
            s.memory.stale = True
    clock, control = _clock(lockstep, time_scale, rate_hz, control_path, reply_latency_s)
    emu = Emulator(servos, link=settings, clock=clock, faults=faults, world=world, control=control,
                   adapter=adapter)
    if status_file is not None:
        writer = StatusFile(status_file, status_hz)
        writer.write(emu, strict=True)      # an unwritable path is an error before anything is served
        emu.observers.append(writer)
    return emu


def _clock(lockstep: bool, time_scale: float, rate_hz: float, control_path, reply_latency_s: float):
    """``(clock, control channel or None)`` for :func:`build_emulator`."""
    if not lockstep:
        return clock_for(time_scale, rate_hz), None
    clock = LockstepPhysicsClock(rate_hz, reply_latency_s)
    try:
        return clock, ControlServer(control_path)
    except OSError as exc:
        raise ConfigError(f"cannot open the lockstep control socket: {exc}") from None


def robot_emulator(robot_config: str | os.PathLike | None = None, emulator_config: str | os.PathLike | None = None,
                   **kwargs) -> Emulator:
    """:func:`build_emulator` from file paths (each parsed once here): the robot file located by
    :func:`swerve.configs.locate_robot_file` and ``configs/emulator.yaml`` by default."""
    from swerve.configs import locate_robot_file, shipped
    from swerve.driver.robot_config import load_robot_config

    robot = load_robot_config(locate_robot_file(robot_config).path)
    physics = load_config(emulator_config or shipped("emulator.yaml"))
    return build_emulator(robot, physics, **kwargs)


def read_status(path: str | os.PathLike) -> dict:
    """Read a status file written by :class:`StatusFile` (another process may be writing it)."""
    return json.loads(Path(path).read_text())


__all__ = ["build_emulator", "robot_emulator", "RobotWorld", "StatusFile", "status", "read_status", "parse_noise"]
