"""One Dynamixel X servo: firmware loops + DC motor + gearbox + sensors behind raw table integers.

:meth:`ServoModel.step` is the only place raw control-table integers meet SI values. The emulator
calls it once per physics tick with the servo's current RAM/EEPROM items (snake_case names, signed
where the item is signed) and writes the returned items back into the table.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from . import units as u
from .bessel import BesselFilter
from .firmware import AntiWindupPI, PositionGains, ProfileGenerator, VelocityGains
from .motor import GearedMotor
from .params import (FirmwareParams, GearFrictionParams, MotorParams, PhysicsConfig, ProtectionParams,
                     SensorParams, ThermalParams)
from .protection import Protection

PULSE_PER_S_PER_VEL_UNIT = u.RADPS_PER_VEL_UNIT / u.RAD_PER_PULSE      # 15.63 pulse/s
VEL_UNIT_PER_S_PER_ACC_UNIT = u.RADPS2_PER_ACC_UNIT / u.RADPS_PER_VEL_UNIT
PULSE_PER_S2_PER_ACC_UNIT = u.RADPS2_PER_ACC_UNIT / u.RAD_PER_PULSE
GOAL_KEYS = ("goal_velocity", "goal_position", "goal_pwm", "goal_current")
OUTPUT_KEYS = ("present_pwm", "present_current", "present_velocity", "present_position",
               "velocity_trajectory", "position_trajectory", "present_input_voltage",
               "present_temperature", "moving", "moving_status")


class ServoModel:
    """Physics and firmware of one servo.

    Parameters
    ----------
    params : MotorParams
        Motor-side constants (paper Table 1, drive or steering variant).
    gear_ratio : float
        Gear reduction (XH430-W210: 212.6).
    supply_voltage_v : float
        Bus supply, V.
    firmware, sensors, thermal : dataclasses from :mod:`.params`
        Fixed firmware constants, sensor noise, winding thermal model.
    rng : numpy.random.Generator, optional
        Noise source; required only when a noise standard deviation is non-zero.
    friction : GearFrictionParams, optional
        Gearbox friction (output side); default none.
    protection : ProtectionParams, optional
        Firmware protection raised from the physics (:mod:`.protection`); default off.
    """

    def __init__(self, params: MotorParams, gear_ratio: float, supply_voltage_v: float,
                 firmware: FirmwareParams = FirmwareParams(), sensors: SensorParams = SensorParams(),
                 thermal: ThermalParams = ThermalParams(), rng: np.random.Generator | None = None,
                 friction: GearFrictionParams | None = None, protection: ProtectionParams | None = None):
        self.motor = GearedMotor(params, gear_ratio, friction)
        self.protection = Protection(protection) if protection is not None and protection.enabled else None
        self.pending_hardware_error = 0  # bits detected by the protection, not yet taken by the servo
        self.encoder_offset_pulse = 0.0  # encoder reading minus the true output angle, pulse
        self.supply_voltage_v = float(supply_voltage_v)
        self.fw = firmware
        self.sensors = sensors
        self.thermal = thermal
        self.rng = rng if rng is not None else np.random.default_rng()
        self.profile = ProfileGenerator()
        self.loop = AntiWindupPI(firmware.gain_time_base_s, firmware.anti_windup_gain)
        self.velocity_filter = BesselFilter(firmware.bessel_cutoff_radps, firmware.bessel_norm)
        self.reference_filter = BesselFilter(firmware.bessel_cutoff_radps, firmware.bessel_norm)
        self.temperature_c = thermal.ambient_c
        self._heat_dt, self._heat_decay = 0.0, 1.0     # exp(-dt / time constant) for the last dt
        self.duty = 0.0                 # applied duty in the servo's frame, -1..1
        self._wrap_pulse = 0            # multiple of 4096 removed when Present Position is re-wrapped
        self._prev_key: tuple | None = None        # (mode, torque on, drive mode) of the last step
        self._prev_goal_position: int | None = None
        self._last: tuple | None = None            # what outputs() needs from the last step
        self._measure_filtered = firmware.bessel_placement == "velocity_feedback"
        self._hold_position: float | None = None
        self._started = False
        self._sign = 1
        self._homing = 0
        self._goal_pulse = 0.0          # goal after limits / watchdog hold, pulse
        self._gains: dict[tuple, object] = {}   # raw gain items -> converted gains
        self._plan: _InputPlan | None = None     # what the firmware derives from the input items
        self._plan_table: Mapping[str, int] | None = None

    # ---- body coupling -------------------------------------------------------------------------
    def external_load(self, torque_nm: float = 0.0, inertia_kg_m2: float | None = None) -> None:
        """Set the load on the output shaft: an opposing torque (N·m) and optionally an inertia (kg·m²)."""
        self.motor.load_torque_nm = float(torque_nm)
        if inertia_kg_m2 is not None:
            self.motor.load_inertia_kg_m2 = float(inertia_kg_m2)

    @property
    def shaft_angle_rad(self) -> float:
        """True continuous output-shaft angle, rad (physical frame, not Drive Mode reversed)."""
        return self.motor.output_angle_rad

    @property
    def shaft_speed_radps(self) -> float:
        """True output-shaft speed, rad/s (physical frame)."""
        return self.motor.output_speed_radps

    @property
    def position_pulse(self) -> float:
        """Continuous (unquantised) position in Present Position's frame, pulse."""
        return (self._sign * (self.motor.output_angle_rad / u.RAD_PER_PULSE + self.encoder_offset_pulse)
                - self._wrap_pulse + self._homing)

    @property
    def true_position_pulse(self) -> float:
        """:attr:`position_pulse` without the encoder offset: where the shaft really is, pulse."""
        return self.position_pulse - self._sign * self.encoder_offset_pulse

    @property
    def frame_sign(self) -> int:
        """+1, or -1 when Drive Mode bit 0 reverses the servo's frame against the shaft's."""
        return self._sign

    @property
    def velocity_radps(self) -> float:
        """True output speed in the servo's frame (Drive Mode direction applied), rad/s."""
        return self._sign * self.motor.output_speed_radps

    @property
    def supply_current_a(self) -> float:
        """Current drawn from the supply by the bridge (duty × armature current), A."""
        return self._sign * self.duty * self.motor.current_a

    def take_hardware_error(self) -> int:
        """Hardware Error Status bits the protection detected since the last call (then cleared)."""
        bits, self.pending_hardware_error = self.pending_hardware_error, 0
        return bits

    def prepare(self, dt_s: float) -> None:
        """Compute the discretisations for steps of ``dt_s`` now (motor driven and coasting,
        Bessel filters): SciPy's first ``expm`` takes ~9 ms, which in a running emulator would
        stall the bus when torque first goes on."""
        self.motor.prepare(dt_s)
        self.velocity_filter.prepare(dt_s)
        self.reference_filter.prepare(dt_s)

    def set_shaft_angle(self, angle_rad: float) -> None:
        """Place the output shaft at ``angle_rad`` (physical frame) at rest; for initial conditions."""
        self.motor.angle_rad = angle_rad * self.motor.gear_ratio
        self.motor.speed_radps = self.motor.current_a = 0.0
        self._started = False

    def clear_multi_turn(self) -> None:
        """Clear instruction (0x10): Present Position back within one turn (+ Homing Offset)."""
        self._rewrap(self._encoder_pulse(self._sign))
        self._last = None

    def reboot(self) -> None:
        """Reboot / power cycle: firmware state cleared, Present Position re-wrapped; the shaft stays put."""
        self.loop.reset()
        self.profile = ProfileGenerator()
        self._prev_key = self._prev_goal_position = None
        self._hold_position = None
        self.duty = 0.0
        self._last = None
        self._rewrap(self._encoder_pulse(self._sign))
        self.pending_hardware_error = 0
        if self.protection is not None:
            self.protection.reset()

    # ---- sensors -------------------------------------------------------------------------------
    def _encoder_pulse(self, sign: int) -> int:
        x = sign * (self.motor.output_angle_rad / u.RAD_PER_PULSE + self.encoder_offset_pulse)
        if self.sensors.position_noise_std_pulse:
            x += self.rng.normal(0.0, self.sensors.position_noise_std_pulse)
        return math.floor(x)

    def _rewrap(self, raw_pulse: int) -> None:
        self._wrap_pulse = u.PULSES_PER_REV * (raw_pulse // u.PULSES_PER_REV)

    # ---- one tick ------------------------------------------------------------------------------
    def step(self, dt_s: float, table: Mapping[str, int]) -> dict[str, int]:
        """Advance ``dt_s`` seconds under the control-table items in ``table``; return present items.

        The same as :meth:`advance` followed by :meth:`outputs`.

        Parameters
        ----------
        dt_s : float
            Physics step, s (e.g. 0.0005 at 2 kHz).
        table : Mapping[str, int]
            Raw items: torque_enable, operating_mode, drive_mode, goal_pwm, goal_current,
            goal_velocity, goal_position, profile_acceleration, profile_velocity, velocity_i_gain,
            velocity_p_gain, position_d_gain, position_i_gain, position_p_gain,
            feedforward_1st_gain, feedforward_2nd_gain, pwm_limit, current_limit, velocity_limit,
            max_position_limit, min_position_limit, moving_threshold, homing_offset, bus_watchdog.

        Returns
        -------
        dict[str, int]
            Raw present_pwm, present_current, present_velocity, present_position,
            velocity_trajectory, position_trajectory, present_input_voltage,
            present_temperature, moving, moving_status.
        """
        self.advance(dt_s, table)
        return self.outputs()

    def advance(self, dt_s: float, table: Mapping[str, int], *, same_inputs: bool = False) -> None:
        """Advance ``dt_s`` seconds under the raw items ``table`` (see :meth:`step`); no outputs.

        The emulator calls this every physics tick and :meth:`outputs` only when the bus reads,
        so the present items cost nothing between reads. ``same_inputs=True`` promises that
        ``table`` is the mapping of the last call, unchanged: what the firmware derives from the
        items (limits, gains, profile bounds) is then reused instead of derived again.
        """
        plan = self._plan
        if not same_inputs or plan is None or table is not self._plan_table:
            plan = self._plan = _InputPlan(table, self.motor.params.resistance_ohm, self._cached_gains)
            self._plan_table = table
        sign = self._sign = plan.sign
        self._homing = homing = plan.homing
        mode = plan.mode
        torque = plan.torque
        motor = self.motor
        # encoder (inline :meth:`_encoder_pulse`: the same arithmetic)
        x = sign * (motor.angle_rad / motor.gear_ratio / u.RAD_PER_PULSE + self.encoder_offset_pulse)
        if self.sensors.position_noise_std_pulse:
            x += self.rng.normal(0.0, self.sensors.position_noise_std_pulse)
        raw = math.floor(x)
        vf = self.velocity_filter
        if not self._started:
            vf.reset(raw)
            self._started = True
        key = plan.key
        switched = key != self._prev_key
        if switched and torque and mode == u.MODE_POSITION:
            self._rewrap(raw)           # Present Position re-wrapped to one turn (+ Homing Offset)
        present = raw - self._wrap_pulse + homing
        vf.step(dt_s, float(raw))
        if self._measure_filtered:
            v_meas = vf.dy / PULSE_PER_S_PER_VEL_UNIT
        else:                           # ideal estimator: the true speed (README: placement choice)
            v_meas = sign * motor.output_speed_radps / u.RADPS_PER_VEL_UNIT
        if switched:
            self.loop.reset()
            self._hold_position = None
            if mode in u.POSITION_MODES:
                self.profile.reset(float(present))
                self.reference_filter.reset(float(present))
            else:
                self.profile.reset(0.0, v_meas if torque else 0.0)
                self.reference_filter.reset(v_meas if torque else 0.0)
        voltage = self._control(dt_s, plan, mode, present, v_meas, sign, switched) if torque else None
        if voltage is None:
            self.loop.reset()
            self.duty = 0.0
            self.profile.reset(float(present) if mode in u.POSITION_MODES else 0.0)
        motor.step(dt_s, voltage)
        self._heat(dt_s)
        if self.protection is not None:
            self.pending_hardware_error |= self.protection.update(
                dt_s, motor.current_a, self.temperature_c, self.supply_voltage_v, table)
        self._prev_key = key
        self._prev_goal_position = plan.goal_position
        self._last = (table, mode, torque, present, v_meas, sign)

    def outputs(self) -> dict[str, int]:
        """Raw present items (see :meth:`step`) after the last :meth:`advance`; sensor noise on
        current and voltage is drawn per call. Before the first step: the servo at rest."""
        if self._last is None:
            return {"present_position": math.floor(self.position_pulse),
                    "present_input_voltage": round(self.supply_voltage_v / u.VOLT_PER_UNIT),
                    "present_temperature": round(self.temperature_c)}
        return self._outputs(*self._last)

    def _control(self, dt_s: float, plan: "_InputPlan", mode: int, present: int,
                 v_meas: float, sign: int, switched: bool) -> float | None:
        """Run the firmware for ``mode``; return the armature voltage (physical frame), V."""
        pwm_lim = plan.pwm_lim
        p = self.motor.params
        w_m = sign * self.motor.speed_radps        # motor speed in the servo frame
        i_ref = None
        if mode == u.MODE_PWM:
            counts = plan.pwm_counts
        elif mode == u.MODE_CURRENT:
            i_ref = plan.current_ref
        elif mode == u.MODE_VELOCITY:
            self.profile.step_velocity(dt_s, plan.velocity_goal, plan.velocity_a_max)
            ref = self.profile.velocity
            if self.fw.bessel_placement == "reference":
                ref = self.reference_filter.step(dt_s, ref)
            g = plan.velocity_gains
            counts = self.loop.update(dt_s, ref - v_meas, g.kp, g.ki, 0.0, pwm_lim)
        elif mode in u.POSITION_MODES:
            counts = self._position_loop(dt_s, plan, mode, present, v_meas, pwm_lim, plan.tripped, switched)
            if mode == u.MODE_CURRENT_POSITION:
                goal_i = plan.position_current_limit
                i_ref, counts = max(-goal_i, min(goal_i, counts)), None
        else:
            return None
        if i_ref is not None:           # inner current loop: ideal inverse model + P on the error
            i_a = i_ref * u.AMP_PER_CURRENT_UNIT
            v = (p.resistance_ohm * i_a + p.back_emf_v_s_per_rad * w_m
                 + p.inductance_h / self.fw.current_loop_time_constant_s * (i_a - sign * self.motor.current_a))
            counts = max(-pwm_lim, min(pwm_lim, v / self.supply_voltage_v * u.PWM_FULL_SCALE))
        v = counts / u.PWM_FULL_SCALE * self.supply_voltage_v
        # Current Limit (38): keep |v - Ke w| <= R I_lim, the steady armature current bound.
        margin = plan.current_margin_v
        emf = p.back_emf_v_s_per_rad * w_m
        v = max(emf - margin, min(emf + margin, v))
        v = max(-self.supply_voltage_v, min(self.supply_voltage_v, v))
        self.duty = v / self.supply_voltage_v
        return sign * v

    def _position_loop(self, dt_s: float, plan: "_InputPlan", mode: int, present: int,
                       v_meas: float, pwm_lim: float, tripped: bool, switched: bool) -> float:
        goal = plan.position_goal
        self._goal_pulse = goal
        new_goal = switched or plan.goal_position != self._prev_goal_position
        if tripped:
            if self._hold_position is None:
                self._hold_position, new_goal = float(present), True
            goal = self._goal_pulse = self._hold_position
        v_max, a_max = plan.position_v_max, plan.position_a_max
        if new_goal:                    # a new profile starts whenever the goal changes
            self.profile.start_position(goal, v_max, a_max)
        self.profile.step_position(dt_s, goal, v_max, a_max)
        ref = self.profile.position
        if self.fw.bessel_placement == "reference":
            ref = self.reference_filter.step(dt_s, ref)
        g = plan.position_gains
        tick = self.fw.gain_time_base_s
        v_traj = self.profile.velocity * tick                  # pulse per tick
        a_traj = self.profile.acceleration * tick * tick       # pulse per tick²
        v_err = v_traj - v_meas * PULSE_PER_S_PER_VEL_UNIT * tick
        extra = g.kd * v_err + g.ff1 * v_traj + g.ff2 * a_traj
        return self.loop.update(dt_s, ref - present, g.kp, g.ki, extra, pwm_lim)

    def _cached_gains(self, key: tuple, convert):
        """Converted gains for raw gain items ``key[1:]`` (building the dataclass every tick is slow)."""
        g = self._gains.get(key)
        if g is None:
            if len(self._gains) >= 64:  # a tuning sweep: keep the cache small
                self._gains.clear()
            g = self._gains[key] = convert(*key[1:])
        return g

    def _heat(self, dt_s: float) -> None:
        th = self.thermal
        if dt_s != self._heat_dt:
            self._heat_dt, self._heat_decay = dt_s, math.exp(-dt_s / th.time_constant_s)
        power = self.motor.current_a ** 2 * self.motor.params.resistance_ohm
        steady = th.ambient_c + th.thermal_resistance_k_per_w * power
        self.temperature_c = steady + (self.temperature_c - steady) * self._heat_decay

    def _outputs(self, t: Mapping[str, int], mode: int, torque: bool, present: int, v_meas: float,
                 sign: int) -> dict[str, int]:
        s = self.sensors
        current = sign * self.motor.current_a
        volts = self.supply_voltage_v
        if s.current_noise_std_a:
            current += self.rng.normal(0.0, s.current_noise_std_a)
        if s.voltage_noise_std_v:
            volts += self.rng.normal(0.0, s.voltage_noise_std_v)
        vel = round(v_meas)
        position_mode = mode in u.POSITION_MODES
        if position_mode:
            v_traj = self.profile.velocity / PULSE_PER_S_PER_VEL_UNIT
            p_traj = self.profile.position
        else:
            v_traj, p_traj = (self.profile.velocity if mode == u.MODE_VELOCITY else 0.0), float(present)
        ongoing = torque and self.profile.ongoing
        status = (_profile_bits(self.profile.profile_type) if torque and position_mode else 0)
        if ongoing:
            status |= u.PROFILE_ONGOING
        if torque and position_mode:
            if not ongoing and abs(self._goal_pulse - present) <= self.fw.in_position_window_pulse:
                status |= u.IN_POSITION
            if abs(self.profile.position - present) > self.fw.following_error_pulse:
                status |= u.FOLLOWING_ERROR
        return {
            "present_pwm": round(self.duty * u.PWM_FULL_SCALE) if torque else 0,
            "present_current": round(current / u.AMP_PER_CURRENT_UNIT),
            "present_velocity": vel,
            "present_position": present,
            "velocity_trajectory": round(v_traj),
            "position_trajectory": round(p_traj),
            "present_input_voltage": round(volts / u.VOLT_PER_UNIT),
            "present_temperature": round(self.temperature_c),
            "moving": int(abs(vel) > t["moving_threshold"] or ongoing and position_mode),
            "moving_status": status,
        }


class _InputPlan:
    """What the firmware derives from one set of raw input items (limits, gains, profile bounds);
    derived once per change of the items, not per tick. Same arithmetic as deriving it per tick."""

    __slots__ = ("sign", "homing", "mode", "torque", "key", "goal_position", "tripped", "pwm_lim",
                 "current_margin_v", "pwm_counts", "current_ref", "velocity_goal", "velocity_a_max",
                 "velocity_gains", "position_goal", "position_v_max", "position_a_max", "position_gains",
                 "position_current_limit")

    def __init__(self, t: Mapping[str, int], resistance_ohm: float, gains):
        self.sign = -1 if t["drive_mode"] & 1 else 1
        self.homing = t["homing_offset"]
        self.mode = mode = t["operating_mode"]
        self.torque = t["torque_enable"] != 0
        self.key = (mode, self.torque, t["drive_mode"])
        self.goal_position = t["goal_position"]
        self.pwm_lim = pwm_lim = float(min(abs(t["goal_pwm"]), t["pwm_limit"]))
        i_lim_units = float(t["current_limit"])
        self.tripped = tripped = t["bus_watchdog"] == u.WATCHDOG_TRIPPED
        self.current_margin_v = resistance_ohm * i_lim_units * u.AMP_PER_CURRENT_UNIT
        self.pwm_counts = self.current_ref = self.velocity_goal = self.velocity_a_max = None
        self.velocity_gains = self.position_goal = self.position_v_max = self.position_a_max = None
        self.position_gains = self.position_current_limit = None
        if mode == u.MODE_PWM:
            self.pwm_counts = 0.0 if tripped else max(-pwm_lim, min(pwm_lim, float(t["goal_pwm"])))
        elif mode == u.MODE_CURRENT:
            self.current_ref = 0.0 if tripped else max(-i_lim_units, min(i_lim_units, float(t["goal_current"])))
        elif mode == u.MODE_VELOCITY:
            vlim = float(t["velocity_limit"])
            self.velocity_goal = 0.0 if tripped else max(-vlim, min(vlim, float(t["goal_velocity"])))
            pa = t["profile_acceleration"]
            self.velocity_a_max = math.inf if pa == 0 or tripped else pa * VEL_UNIT_PER_S_PER_ACC_UNIT
            self.velocity_gains = gains(("v", t["velocity_p_gain"], t["velocity_i_gain"]), VelocityGains.from_table)
        elif mode in u.POSITION_MODES:
            goal = float(t["goal_position"])
            if mode == u.MODE_POSITION:
                goal = max(float(t["min_position_limit"]), min(float(t["max_position_limit"]), goal))
            self.position_goal = goal
            vlim = float(t["velocity_limit"])
            pv, pa = min(t["profile_velocity"], vlim), t["profile_acceleration"]
            self.position_v_max = math.inf if pv == 0 or tripped else pv * PULSE_PER_S_PER_VEL_UNIT
            self.position_a_max = math.inf if pa == 0 or tripped else pa * PULSE_PER_S2_PER_ACC_UNIT
            self.position_gains = gains(("p", t["position_p_gain"], t["position_i_gain"], t["position_d_gain"],
                                         t["feedforward_1st_gain"], t["feedforward_2nd_gain"]),
                                        PositionGains.from_table)
            if mode == u.MODE_CURRENT_POSITION:
                self.position_current_limit = float(min(abs(t["goal_current"]), t["current_limit"]))


def _profile_bits(profile_type: int) -> int:
    """Moving Status bits 5:4 for a profile type (0 none .. 3 trapezoidal)."""
    return (profile_type & 0x3) << 4


def wheel_servo(cfg: PhysicsConfig, model: str, *, steering: bool, center_pulse: int | None = None,
                sensors: SensorParams | None = None, rng: np.random.Generator | None = None,
                ideal: bool = False) -> ServoModel:
    """The :class:`ServoModel` of one wheel module's servo, built from ``configs/emulator.yaml``.

    ``steering`` picks the steering or drive motor of ``cfg``; ``model`` (e.g. ``"xh430-w210"``)
    the gear ratio. A steering servo with ``center_pulse`` starts at rest at that raw position.
    ``sensors`` overrides ``cfg.sensors``; ``ideal`` drops sensor noise, gearbox friction and
    protection and uses the default thermal model (for gain design). ``rng`` is the shared noise source.
    """
    params = cfg.steering_motor if steering else cfg.drive_motor
    if ideal:
        servo = ServoModel(params, cfg.gear_ratio(model), cfg.supply_voltage_v, cfg.firmware, rng=rng)
    else:
        servo = ServoModel(params, cfg.gear_ratio(model), cfg.supply_voltage_v, cfg.firmware,
                           cfg.sensors if sensors is None else sensors, cfg.thermal, rng,
                           friction=cfg.steering_friction if steering else cfg.drive_friction,
                           protection=cfg.protection)
    if steering and center_pulse is not None:
        servo.set_shaft_angle(center_pulse * u.RAD_PER_PULSE)
    return servo
