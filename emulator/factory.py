"""Build the emulated bus from parsed configs: servos with motors and firmware, optionally the body.

::

    from swerve.driver.robot_config import load_robot_config
    from swerve.emulator.physics.params import load_config
    from swerve.emulator.factory import build_emulator
    from swerve.emulator.body_settings import BodySettings
    from swerve.emulator.timing import Frozen

    robot = load_robot_config(path)                       # parsed once, by the caller
    with build_emulator(robot, load_config(), timing=Frozen(), body=BodySettings()) as emu:
        ...                                               # open emu.port with driver.bus.Bus
        emu.advance(0.016)                                # 16 ms of simulated time, 2 kHz steps
        x, y, theta = emu.pose                            # true pose, never through the bus

The physics (:mod:`emulator.physics`) advances in fixed steps of ``1 / physics.rate_hz``
simulated seconds, run by the clock (:mod:`emulator.clock`, built by the ``timing`` passed in,
:mod:`emulator.timing`) in the bus thread between requests. With a :class:`BodySettings`, the
servos also move one :class:`~swerve.emulator.physics.robot_world.RobotWorld`; otherwise each
servo turns a free shaft.

The true pose leaves the emulator through one channel, its observers (called under the bus lock
after each run of physics steps): :class:`~swerve.emulator.status_file.StatusFile` writes the JSON
status file, :class:`~swerve.emulator.process.EmulatorProcess` copies it into shared memory.
"""
from __future__ import annotations

import dataclasses
import math
import os
from typing import Iterable, Mapping

import numpy as np

from swerve.configs import locate_robot_file, shipped
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import RobotConfig, load_robot_config
from swerve.emulator.adapter import AdapterSettings, UsbAdapter
from swerve.emulator.faults import Faults
from swerve.emulator.physics.params import PhysicsConfig, load_config
from swerve.emulator.physics.robot import RobotGeometry, RobotPhysics
from swerve.emulator.physics.robot_world import RobotWorld
from swerve.emulator.physics.servo_adapter import ServoDynamics
from swerve.emulator.physics.servo_model import wheel_servo
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.sensor_noise import parse_noise
from swerve.emulator.server import DEFAULT_BAUD, DEFAULT_IDS, DEFAULT_MODEL, Emulator, LinkSettings
from swerve.emulator.servo import make_servos
from swerve.emulator.status_file import StatusFile
from swerve.emulator.timing import Timing, WallTime

#: Clock rate of a register-only bus (Realtime Tick and Bus Watchdog), Hz.
FROZEN_RATE_HZ = 1000.0


def build_emulator(robot: RobotConfig | None = None, physics: PhysicsConfig | None = None, *,
                   ids: Iterable[int] | None = None, model: str | None = None, baud: int | None = None,
                   timing: Timing = WallTime(), rate_hz: float | None = None, body: BodySettings | None = None,
                   noise: str | Mapping[str, float] | None = None, faults: Faults | str | None = None,
                   status_file: str | os.PathLike | None = None, status_hz: float = 20.0, limit_error=None,
                   adapter_latency_ms: int | None = None, link: LinkSettings = LinkSettings()) -> Emulator:
    """The emulated bus, built from already-parsed configs (nothing is read from disk here).

    Parameters
    ----------
    robot : RobotConfig, optional
        IDs, model, link baud and geometry (``driver.robot_config``); ``ids``/``model``/``baud``
        override it (default IDs 1-8, xh430-w210, 1 Mbps without one).
    physics : PhysicsConfig, optional
        ``configs/emulator.yaml``. Given: every servo runs its motor and firmware loops.
        ``None``: a register-only bus (Present* items stay put).
    timing : Timing
        How simulated time runs (:mod:`swerve.emulator.timing`): ``Frozen()`` (step with
        ``emu.advance(dt_s)``), ``WallTime(scale)`` (default real time) or ``Lockstep()`` (a
        client moves robot time through ``emu.control``).
    rate_hz : float, optional
        Clock rate (physics: >= 1000, default ``physics.rate_hz``; register-only: 1000).
    body : BodySettings, optional
        The robot body, moved by the servos (needs ``robot`` and ``physics``, and every robot
        servo on the bus: :func:`~swerve.emulator.body_settings.robot_on_bus`). ``None``: each servo turns a free shaft.
    noise : str or mapping, optional
        Sensor noise overriding the config (:func:`~swerve.emulator.sensor_noise.parse_noise`),
        e.g. ``"position=0.5,seed=1"``.
    faults : Faults or str, optional
        Fault injection (:mod:`emulator.faults`).
    status_file : path, optional
        JSON status (:func:`~swerve.emulator.status_file.status`) rewritten atomically at
        ``status_hz`` wall Hz (needs a body).
    limit_error : ErrorNumber, optional
        Error for a value beyond a limit item (default Data Limit Error).
    adapter_latency_ms : int, optional
        The USB-serial adapter's latency timer, ms (1..255; :mod:`swerve.emulator.adapter`),
        overriding the robot file's ``link.adapter_latency_ms``. Neither: no adapter (the host
        reads the cable directly).
    link : LinkSettings
        How the bus behaves on the line (symlink ``path``, ``wire_timing``, ...).

    Returns
    -------
    Emulator
        Not started: use it as a context manager (or call ``start()``); ``emu.port`` is the pty.
    """
    robot_ids = sorted(robot.drive_ids + robot.steer_ids) if robot is not None else None
    ids = sorted(ids) if ids is not None else (robot_ids or list(DEFAULT_IDS))
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
    if adapter_latency_ms is None and robot is not None:
        adapter_latency_ms = robot.link.adapter_latency_ms
    adapter = None if adapter_latency_ms is None else UsbAdapter(AdapterSettings(adapter_latency_ms))
    if body is not None and (robot is None or physics is None):
        raise ConfigError("the robot body needs a robot config and a physics config")
    if status_file is not None and body is None:
        raise ConfigError("a status file needs the robot body (all the robot's servos on the bus)")
    extra = {} if limit_error is None else {"limit_error": limit_error}
    if physics is None:
        if noise is not None:
            raise ConfigError("sensor noise needs physics")
        servos = make_servos(ids, model, baud, **extra)
        clock, control = timing.build(rate_hz or FROZEN_RATE_HZ)
        return Emulator(servos, link=link, clock=clock, faults=faults, control=control, adapter=adapter)

    rate_hz = float(rate_hz or physics.rate_hz)
    if rate_hz < 1000:
        raise ConfigError(f"physics rate must be >= 1000 Hz, got {rate_hz:g}")
    sensors, seed = parse_noise(noise, physics.sensors)
    load = physics.body
    if body is not None and body.wheel_load is not None:
        load = dataclasses.replace(physics.body, load_enabled=bool(body.wheel_load))
    physics = dataclasses.replace(physics, sensors=sensors, body=load)
    rng = np.random.default_rng(seed)
    world = None
    if body is not None:
        missing = set(robot_ids) - set(ids)
        if missing:
            raise ConfigError(f"the robot's servos {sorted(missing)} are not on the emulated bus")
        robot_physics = RobotPhysics(physics, RobotGeometry(robot.model, robot.wheel_radius_m, robot.wheels), rng)
        robot_physics.body.x_m, robot_physics.body.y_m, robot_physics.body.theta_rad = (
            float(v) for v in body.start_pose)
        models = dict(robot_physics.servos)
        world = RobotWorld(robot_physics)
    else:
        centers = {w.steer_id: w.center_pulse for w in robot.wheels} if robot is not None else {}
        models = {i: wheel_servo(physics, model, steering=i in centers, center_pulse=centers.get(i), rng=rng)
                  for i in ids}            # steering shafts start at their centre
    if world is not None:               # discretisations and kernels: made later they would stall the bus
        world.physics.prepare(1.0 / rate_hz)
    else:
        for m in models.values():
            m.prepare(1.0 / rate_hz)
    servos = make_servos(ids, model, baud, **extra,
                         dynamics=lambda s: ServoDynamics(models[s.id], s) if s.id in models else None)
    for s in servos:                    # present items from the physics, not the table defaults
        if s.dynamics is not None:
            s.memory.stale = True
    clock, control = timing.build(rate_hz)
    emu = Emulator(servos, link=link, clock=clock, faults=faults, world=world, control=control, adapter=adapter)
    if status_file is not None:
        writer = StatusFile(status_file, status_hz)
        writer.write(emu, strict=True)      # an unwritable path is an error before anything is served
        emu.observers.append(writer)
    return emu


def robot_emulator(robot_config: str | os.PathLike | None = None, emulator_config: str | os.PathLike | None = None,
                   **kwargs) -> Emulator:
    """:func:`build_emulator` from file paths (each parsed once here): the robot file located by
    :func:`swerve.configs.locate_robot_file` and ``configs/emulator.yaml`` by default; the robot
    body (:class:`BodySettings`) unless ``body`` says otherwise."""
    robot = load_robot_config(locate_robot_file(robot_config).path)
    physics = load_config(emulator_config or shipped("emulator.yaml"))
    kwargs.setdefault("body", BodySettings())
    return build_emulator(robot, physics, **kwargs)


__all__ = ["build_emulator", "robot_emulator"]
