"""Eight servos on one robot body: the emulator's whole physical world.

``RobotPhysics.step(dt, tables)`` advances every servo with its raw control-table items, then the
body from the drive-wheel ground speeds and the steering angles (``configs/robot.yaml``).

The body is the least-squares kinematic fit (:class:`RobotBody`) or, with ``contact.enabled``,
the tyre-force model (:class:`ContactBody`) whose reactions load the drive shafts. Build
tolerances (``tolerances``) change the true wheels, never ``robot.yaml``; with a ``supply``
internal resistance the bus voltage sags under the servos' current.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from swerve.driver.robot_config import DEFAULT_PATH, WheelConfig, load_robot_config

from . import units as u
from . import coupled
from .coupled_arrays import CoupledArrays
from .body import RobotBody
from .contact import ContactBody
from .params import PhysicsConfig
from .servo_model import ServoModel, wheel_servo


@dataclass(frozen=True)
class RobotGeometry:
    """The parts of ``configs/robot.yaml`` the physics needs."""

    model: str
    wheel_radius_m: float
    wheels: tuple[WheelConfig, ...]


def load_robot_geometry(path: str | Path = DEFAULT_PATH) -> RobotGeometry:
    """Wheel positions, IDs, direction signs and steering centres, read and checked by
    :func:`driver.robot_config.load_robot_config` (the one parser of ``robot.yaml``).

    Raises
    ------
    ConfigError
        On a missing or malformed key (the message names it).
    """
    cfg = load_robot_config(path)
    return RobotGeometry(cfg.model, cfg.wheel_radius_m, cfg.wheels)


class RobotPhysics:
    """Eight :class:`ServoModel` (4 drive, 4 steering) coupled to a :class:`RobotBody`.

    Parameters
    ----------
    cfg : PhysicsConfig
        ``configs/emulator.yaml``.
    geometry : RobotGeometry
        ``configs/robot.yaml``.
    rng : numpy.random.Generator, optional
        Shared noise source.
    """

    def __init__(self, cfg: PhysicsConfig, geometry: RobotGeometry, rng: np.random.Generator | None = None):
        self.geometry = geometry
        rng = rng if rng is not None else np.random.default_rng()
        self.cfg = cfg
        n = len(geometry.wheels)
        tol = cfg.tolerances
        self.wheel_radius_m = geometry.wheel_radius_m * np.asarray(tol.wheel_radius_scale or (1.0,) * n)
        self.steer_zero_offset_rad = np.asarray(tol.steer_zero_offset_rad or (0.0,) * n)
        encoder_offsets = tol.encoder_offset_pulse or (0.0,) * n
        self.servos: dict[int, ServoModel] = {}
        wheel_inertia = cfg.body.total_mass_kg / n * geometry.wheel_radius_m ** 2
        for w, enc in zip(geometry.wheels, encoder_offsets):
            self.servos[w.drive_id] = wheel_servo(cfg, geometry.model, steering=False, rng=rng)
            if cfg.body.load_enabled and not cfg.contact.enabled:   # the mass, reflected onto each shaft
                self.servos[w.drive_id].external_load(0.0, wheel_inertia)
            steer = self.servos[w.steer_id] = wheel_servo(cfg, geometry.model, steering=True, rng=rng)
            steer.encoder_offset_pulse = enc
            # reads its centre with the wheel straight; a µpulse inside the count, clear of round-off
            steer.set_shaft_angle((w.center_pulse - enc + (1e-6 if enc else 0.0)) * u.RAD_PER_PULSE)
        xy = [(w.x_m, w.y_m) for w in geometry.wheels]
        self.body: RobotBody | ContactBody = (ContactBody(xy, cfg.body.total_mass_kg, cfg.contact)
                                              if cfg.contact.enabled else RobotBody(xy))
        self._wheel_steer_rad: list[float] | None = None    # wheel angles behind the backlash
        self._wheel_servos = [(w, self.servos[w.drive_id], self.servos[w.steer_id], r, off) for w, r, off in
                              zip(geometry.wheels, self.wheel_radius_m.tolist(), self.steer_zero_offset_rad.tolist())]
        # per wheel, for _wheel_rows: drive direction, steering direction, steering centre (pulse) as
        # floats (the same products as with the ints, without a conversion per step), radius, offset
        self._wheel_frames = [(float(w.drive_direction), float(w.steer_direction), float(w.center_pulse), r, off)
                              for w, _, _, r, off in self._wheel_servos]
        self._drive_models = [d for _, d, _, _, _ in self._wheel_servos]
        self._coupled: CoupledArrays | None = None    # built by the first run_coupled
        self._steer_models = [s for _, _, s, _, _ in self._wheel_servos]
        self.bus_voltage_v = cfg.supply_voltage_v

    def wheel_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Ground speeds (m/s, signed, forward positive) and steering angles (rad), shape (4,) each."""
        speeds, steer = self._wheel_state()
        return np.array(speeds), np.array(steer)

    def _wheel_state(self) -> tuple[list[float], list[float]]:
        """:meth:`wheel_state` as lists of Python floats (per physics step: no NumPy overhead)."""
        speeds, steer = self._wheel_rows([[drive.velocity_radps] for _, drive, _, _, _ in self._wheel_servos],
                                         [[steer.true_position_pulse] for _, _, steer, _, _ in self._wheel_servos])
        return [v for v, in speeds], [d for d, in steer]

    def _wheel_rows(self, drive_radps: list[list[float]], steer_pulse: list[list[float]]
                    ) -> tuple[list[list[float]], list[list[float]]]:
        """Per wheel, the ground speeds (m/s) and wheel angles (rad) of consecutive steps from the
        drive servo's :attr:`ServoModel.velocity_radps` and the steering servo's
        :attr:`ServoModel.true_position_pulse` at those steps (the backlash state advances)."""
        speeds, steer = [], []
        rad_per_pulse = u.RAD_PER_PULSE
        half = 0.5 * self.cfg.tolerances.steer_backlash_rad
        state, wheels = self._wheel_steer_rad, []
        for k, ((direction, sd, center, r, off), vs, pulses) in enumerate(zip(self._wheel_frames, drive_radps,
                                                                               steer_pulse)):
            speeds.append([direction * v * r for v in vs])
            horn = [sd * (p - center) * rad_per_pulse - off for p in pulses]
            if half > 0.0 and horn:
                wheel = state[k] if state is not None else horn[0]
                # the wheel stays where it is until the horn takes up the free play on either side
                for j, h in enumerate(horn):
                    horn[j] = wheel = min(max(wheel, h - half), h + half)
                wheels.append(wheel)
            steer.append(horn)
        if wheels:
            self._wheel_steer_rad = wheels
        return speeds, steer

    def traces(self) -> dict[ServoModel, tuple[list | None, list | None]] | None:
        """Empty trace lists ``{model: (speeds, positions)}`` for :meth:`ServoModel.run` (drive
        servos record speeds, steering servos positions) when the servos may run several steps
        each before the body follows: with the kinematic body and a stiff supply nothing flows
        back from the body into the servos. ``None`` otherwise (tyre forces, supply sag)."""
        if isinstance(self.body, ContactBody) or self.cfg.supply.enabled:
            return None
        out: dict[ServoModel, tuple[list | None, list | None]] = {d: ([], None) for d in self._drive_models}
        for s in self._steer_models:
            out[s] = (None, [])
        return out

    def step_body_many(self, dt_s: float, n: int, traces: Mapping[ServoModel, tuple]) -> tuple[float, float, float]:
        """``n`` body steps of ``dt_s`` after the servos ran them, from their ``traces``
        (:meth:`traces`, filled by :meth:`ServoModel.run`); the same as :meth:`step_body` after
        each servo step. Returns the pose."""
        drive = [traces[d][0] for d in self._drive_models]
        steer = [traces[s][1] for s in self._steer_models]
        for t in drive + steer:
            if len(t) != n:
                raise ValueError(f"every wheel servo must have recorded {n} steps")
        speeds, angles = self._wheel_rows(drive, steer)
        return self.body.step_many(dt_s, zip(zip(*speeds), zip(*angles)))

    def step(self, dt_s: float, tables: Mapping[int, Mapping[str, int]]) -> dict[int, dict[str, int]]:
        """Advance all servos (raw ``tables`` by ID) and the body by ``dt_s``; return present items by ID."""
        out = {sid: self.servos[sid].step(dt_s, tables[sid]) for sid in self.servos}
        self.step_body(dt_s)
        return out

    def step_body(self, dt_s: float) -> tuple[float, float, float]:
        """Advance only the body from the servos' present shaft states (servos stepped elsewhere,
        e.g. by the emulator's servo loop); return the pose. With tyre contact the reactions
        become the drive shafts' loads, and with a supply resistance the bus voltage sags, both
        seen by the servos from their next step."""
        pose = self.body.step(dt_s, *self._wheel_state())
        if isinstance(self.body, ContactBody):
            for (w, s, _, r, _), f in zip(self._wheel_servos, self.body.force_long_list_n):
                s.external_load(w.drive_direction * s.frame_sign * r * f)
        sup = self.cfg.supply
        if sup.enabled:
            current = 0.0                   # added in servo order (the builtin sum compensates from 3.12)
            for s in self.servos.values():
                current += s.supply_current_a
            current += sup.idle_current_a * len(self.servos)
            self.bus_voltage_v = self.cfg.supply_voltage_v - sup.internal_resistance_ohm * current
            for s in self.servos.values():
                s.set_supply_voltage(self.bus_voltage_v)
        return pose


    def prepare(self, dt_s: float) -> None:
        """Compute the servos' discretisations for steps of ``dt_s`` now (:meth:`ServoModel.discretise`),
        and load the compiled :func:`.coupled.robot_ticks` if :meth:`run_coupled` will run (from the
        kernel cache, or compiled the first time): done at the first step, either would stall the
        bus. The servos' own kernel is not loaded: the robot's clocks step its servos through the
        robot's kernel (``Emulator.step``, servo after servo, would load it at its first use)."""
        for m in self.servos.values():
            m.discretise(dt_s)
        if self.coupled():
            coupled.ROBOT_TICKS.load()

    def coupled(self) -> bool:
        """Whether :meth:`run_coupled` runs here: no position noise, and the compiled
        :func:`.coupled.robot_ticks` (numba)."""
        return (coupled.ROBOT_TICKS is not None
                and not any(s.sensors.position_noise_std_pulse for s in self.servos.values()))

    def run_coupled(self, dt_s: float, n: int, runs: Mapping[ServoModel, tuple[Mapping[str, int], bool]]) -> int:
        """Up to ``n`` steps of every servo and the body (:func:`.coupled.robot_ticks`): the same
        as ``n`` times :meth:`ServoModel.advance` of every servo then :meth:`step_body`, in
        one compiled call; stops after a step in which a servo's protection raised a Hardware
        Error bit (:attr:`ServoModel.pending_hardware_error`). ``runs[model]``: its raw input
        items and whether they are those of its last run (``same_inputs``). Needs :meth:`coupled`.
        Returns the steps run."""
        arrays = self._coupled
        if arrays is None:
            models = list(self.servos.values())
            rows = {m: k for k, m in enumerate(models)}
            sup = self.cfg.supply
            arrays = self._coupled = CoupledArrays(
                models, [(rows[d], rows[s]) for _, d, s, _, _ in self._wheel_servos], self._wheel_frames, self.body,
                (0.5 * self.cfg.tolerances.steer_backlash_rad, float(self.cfg.supply_voltage_v),
                 float(sup.internal_resistance_ohm), sup.idle_current_a * len(models)), sup.enabled)
        ran, self._wheel_steer_rad = arrays.run(dt_s, n, runs, self._wheel_steer_rad)
        if self.cfg.supply.enabled:
            self.bus_voltage_v = arrays.bus_voltage_v()
        return ran
