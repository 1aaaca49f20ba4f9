"""One Dynamixel X servo: firmware loops + DC motor + gearbox + sensors behind raw table integers.

:meth:`ServoModel.step` is the only place raw control-table integers meet SI values. The emulator
calls it once per physics tick with the servo's current RAM/EEPROM items (snake_case names, signed
where the item is signed) and writes the returned items back into the table.
"""
from __future__ import annotations

import math
import operator
from typing import Mapping, Protocol

import numpy as np

from . import bessel, firmware
from . import units as u
from .bessel import BesselFilter, bessel_coefficients, bessel_reset, bessel_step
from .firmware import (AntiWindupPI, PositionGains, ProfileGenerator, VelocityGains, pi_step, position_profile_step,
                       profile_type, velocity_profile_step)
from .jit import compiled, jitable
from . import motor as motor_module
from . import protection as protection_module
from .motor import GearedMotor, electrical_decay, friction_step, friction_terms
from .params import (FirmwareParams, GearFrictionParams, MotorParams, PhysicsConfig, ProtectionParams,
                     SensorParams, ThermalParams)
from .protection import Protection, limits, protection_step

PULSE_PER_S_PER_VEL_UNIT = u.RADPS_PER_VEL_UNIT / u.RAD_PER_PULSE      # 15.63 pulse/s
VEL_UNIT_PER_S_PER_ACC_UNIT = u.RADPS2_PER_ACC_UNIT / u.RADPS_PER_VEL_UNIT
PULSE_PER_S2_PER_ACC_UNIT = u.RADPS2_PER_ACC_UNIT / u.RAD_PER_PULSE
# The constants the present items use, as plain numbers (an IntEnum compares slower)
_POSITION_MODES = tuple(int(m) for m in u.POSITION_MODES)
_MODE_VELOCITY = int(u.MODE_VELOCITY)
_PROFILE_ONGOING, _IN_POSITION, _FOLLOWING_ERROR = u.PROFILE_ONGOING, u.IN_POSITION, u.FOLLOWING_ERROR
_PWM_FULL_SCALE, _AMP_PER_CURRENT_UNIT, _VOLT_PER_UNIT = u.PWM_FULL_SCALE, u.AMP_PER_CURRENT_UNIT, u.VOLT_PER_UNIT
#: The items of a servo with torque off (what :meth:`ServoModel.prepare` runs the kernel on once).
IDLE_ITEMS = {"torque_enable": 0, "operating_mode": u.MODE_PWM, "drive_mode": 0, "homing_offset": 0,
               "goal_position": 0, "goal_pwm": 0, "pwm_limit": 0, "current_limit": 0, "bus_watchdog": 0}
GOAL_KEYS = ("goal_velocity", "goal_position", "goal_pwm", "goal_current")
OUTPUT_KEYS = ("present_pwm", "present_current", "present_velocity", "present_position",
               "velocity_trajectory", "position_trajectory", "present_input_voltage",
               "present_temperature", "moving", "moving_status")


class StateHolder(Protocol):
    """What keeps a servo's newest state outside the model for a while (the compiled robot's
    arrays, :class:`.coupled_arrays.CoupledArrays`): ``dirty`` while it holds state newer than
    the model's, and ``store_back()`` puts it into the models (then it is not dirty)."""

    dirty: bool

    def store_back(self) -> None:
        """Store the held state into the models."""


class _Held:
    """A part of :class:`ServoModel`'s state (see :attr:`ServoModel.holder`): reading or setting
    it first stores back the newer state a holder keeps, so every reader sees the true state.
    The value is the instance's attribute of the name with a trailing ``_`` (``motor_``)."""

    __slots__ = ("slot",)

    def __set_name__(self, owner, name: str) -> None:
        self.slot = f"{name}_"

    def __get__(self, model, owner=None):
        if model is None:
            return self
        holder = model.holder
        if holder is not None and holder.dirty:
            holder.store_back()
        return getattr(model, self.slot)

    def __set__(self, model, value) -> None:
        holder = model.holder
        if holder is not None and holder.dirty:
            holder.store_back()
        setattr(model, self.slot, value)


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

    Notes
    -----
    The state a run of ticks changes (the motor, filters, profile, loop, protection, temperature,
    duty, supply and what the present items need) may be held for a while by a
    :class:`StateHolder` (:attr:`holder`: the compiled robot's arrays keep it from one run to
    the next): each of those attributes stores it back when read or set, so a reader always
    sees the true state. Fetch them from the model when needed: an object kept from before a
    run (``motor = model.motor``) is not brought up to date.
    """

    motor = _Held()
    velocity_filter = _Held()
    reference_filter = _Held()
    profile = _Held()
    loop = _Held()
    protection = _Held()
    temperature_c = _Held()
    duty = _Held()
    supply_voltage_v = _Held()
    _hold_position = _Held()
    _goal_pulse = _Held()
    _wrap_pulse = _Held()
    _started = _Held()
    _last = _Held()
    _prev_key = _Held()
    _prev_goal_position = _Held()

    def __init__(self, params: MotorParams, gear_ratio: float, supply_voltage_v: float,
                 firmware: FirmwareParams = FirmwareParams(), sensors: SensorParams = SensorParams(),
                 thermal: ThermalParams = ThermalParams(), rng: np.random.Generator | None = None,
                 friction: GearFrictionParams | None = None, protection: ProtectionParams | None = None):
        #: The :class:`StateHolder` that may keep this model's newest state (``None``: the model holds it).
        self.holder: StateHolder | None = None
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
        self._plant: tuple | None = None            # run()'s constants per step and inertia (_derive_plant)
        self._inputs: tuple | None = None           # run()'s constants per input items (_derive_inputs)
        self._input_array: tuple | None = None      # (_inputs, the same as a float64 array) for the kernel
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
        self._plan_base: tuple | None = None    # the plan's items but the goals (_PLAN_ITEMS)
        self._traces = np.empty(0), np.empty(0)     # the compiled kernel's speed / position buffers
        #: Counts the changes of the state :meth:`kernel_state` returns: every method that changes
        #: it adds one (a copy of the state, e.g. :class:`.coupled_arrays.CoupledArrays`, is current
        #: while the count is the one it was taken at). The state is not to be set from outside.
        self.state_version = 0

    # ---- body coupling -------------------------------------------------------------------------
    def external_load(self, torque_nm: float = 0.0, inertia_kg_m2: float | None = None) -> None:
        """Set the load on the output shaft: an opposing torque (N·m) and optionally an inertia (kg·m²)."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        motor = self.motor_
        motor.load_torque_nm = float(torque_nm)
        if inertia_kg_m2 is not None:
            motor.load_inertia_kg_m2 = float(inertia_kg_m2)

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
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        return (self._sign * (self.motor_.output_angle_rad / u.RAD_PER_PULSE + self.encoder_offset_pulse)
                - self._wrap_pulse_ + self._homing)

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
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        return self._sign * self.motor_.output_speed_radps

    @property
    def supply_current_a(self) -> float:
        """Current drawn from the supply by the bridge (duty × armature current), A."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        return self._sign * self.duty_ * self.motor_.current_a

    def set_supply_voltage(self, volts: float) -> None:
        """The bus voltage at the servo's terminals from now on, V (what :attr:`supply_voltage_v`
        = ``volts`` does, with one check of the :attr:`holder`)."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        self.supply_voltage_v_ = volts

    def take_hardware_error(self) -> int:
        """Hardware Error Status bits the protection detected since the last call (then cleared)."""
        bits, self.pending_hardware_error = self.pending_hardware_error, 0
        return bits

    def discretise(self, dt_s: float) -> None:
        """Compute the discretisations for steps of ``dt_s`` now (motor driven and coasting,
        Bessel filters): the first exact ``expm`` takes milliseconds, which in a running emulator
        would stall the bus when torque first goes on."""
        self.motor.prepare(dt_s)
        self.velocity_filter.prepare(dt_s)
        self.reference_filter.prepare(dt_s)

    def prepare(self, dt_s: float) -> None:
        """:meth:`discretise`, and load the compiled tick kernel (:mod:`.jit`; ~0.4 s with numba's
        import, a few seconds the first time it compiles) by running it once on a spare model."""
        self.discretise(dt_s)
        if _COMPILED_TICKS is not None and not _COMPILED_TICKS.signatures:
            spare = ServoModel(self.motor.params, self.motor.gear_ratio, self.supply_voltage_v, self.fw)
            spare.run(dt_s, IDLE_ITEMS, 1, speeds=[], positions=[])

    def set_shaft_angle(self, angle_rad: float) -> None:
        """Place the output shaft at ``angle_rad`` (physical frame) at rest; for initial conditions."""
        self.motor.angle_rad = angle_rad * self.motor.gear_ratio
        self.motor.speed_radps = self.motor.current_a = 0.0
        self._started = False
        self.state_version += 1

    def clear_multi_turn(self) -> None:
        """Clear instruction (0x10): Present Position back within one turn (+ Homing Offset)."""
        self._rewrap(self._encoder_pulse(self._sign))
        self._last = None
        self.state_version += 1

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
        self.state_version += 1

    # ---- sensors -------------------------------------------------------------------------------
    def _encoder_pulse(self, sign: int) -> int:
        x = sign * (self.motor.output_angle_rad / u.RAD_PER_PULSE + self.encoder_offset_pulse)
        if self.sensors.position_noise_std_pulse:
            x += self.rng.normal(0.0, self.sensors.position_noise_std_pulse)
        return math.floor(x)

    def _rewrap(self, raw_pulse: int) -> None:
        self._wrap_pulse = wrapped_pulse(raw_pulse)

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
        One tick of :meth:`run`.
        """
        self.run(dt_s, table, 1, same_inputs=same_inputs)

    def run(self, dt_s: float, table: Mapping[str, int], n: int = 1, *, same_inputs: bool = False,
            speeds: list | None = None, positions: list | None = None) -> int:
        """Advance up to ``n`` ticks of ``dt_s`` seconds under the unchanging raw items ``table``.

        The same arithmetic, in the same order, as ``n`` calls of :meth:`advance`: the ticks run
        in :func:`servo_ticks` on the state taken from the model, which is stored back at the end.
        Stops early after a tick in which the protection raised a Hardware Error bit
        (:attr:`pending_hardware_error`), so the caller can latch it before the next tick.
        ``speeds`` / ``positions``, if given, get one entry per tick: :attr:`velocity_radps`
        (rad/s) / :attr:`true_position_pulse` (pulse) after the tick (what the body needs).
        Returns the ticks run (1..n).

        Without position noise the ticks run in the compiled kernel when numba is installed
        (:mod:`.jit`), gearbox friction, a held shaft and the protection included; otherwise, and
        with ``SWERVE_NO_JIT=1``, in the same function as plain Python.
        """
        if n < 1:
            return 0
        plan, plant, inputs = self.begin_run(dt_s, table, same_inputs)
        noisy = bool(self.sensors.position_noise_std_pulse)
        record_speeds, record_positions = speeds is not None, positions is not None
        if _COMPILED_TICKS is not None and not noisy:
            kernel, plant_coef, input_coef = _COMPILED_TICKS, plant[3], self._input_row(inputs)
            if len(self._traces[0]) < n:
                self._traces = np.empty(n), np.empty(n)
            speed_trace, position_trace = self._traces
        else:                           # the same function as Python, with the objects it calls per tick
            kernel, plant_coef, input_coef = servo_ticks, plant[2], inputs[1]
            speed_trace = [0.0] * n if record_speeds else None
            position_trace = [0.0] * n if record_positions else None
        switched, new_goal = self.run_flags(plan)
        f, i = self.kernel_state()
        motor = self.motor_             # fresh: kernel_state stored any held state back
        out = kernel(n, dt_s, plant_coef, input_coef, plan.homing, record_speeds, speed_trace, record_positions,
                     position_trace, self.rng if noisy else None, motor.blocked, *f[:10], i[0], i[1], f[10], f[11],
                     f[12], i[2], i[3], switched, new_goal, i[4], f[13], f[14], i[5], f[15], f[16], i[6],
                     float(self.encoder_offset_pulse), self.supply_voltage_v_, motor.load_torque_nm)
        ran = out[0]
        if record_speeds:
            speeds.extend(speed_trace[:ran].tolist() if kernel is _COMPILED_TICKS else speed_trace[:ran])
        if record_positions:
            positions.extend(position_trace[:ran].tolist() if kernel is _COMPILED_TICKS else position_trace[:ran])
        floats = (*out[2:12], out[14], out[15], out[16], out[20], out[21], out[23], out[24])
        ints = (out[12], out[13], out[17], out[18], out[19], out[22], out[25])
        self.finish_run(table, plan.record(), out[1], floats, ints, out[26], out[27])
        return ran

    def begin_run(self, dt_s: float, table: Mapping[str, int], same_inputs: bool) -> tuple:
        """Before a run of ticks under ``table`` (:meth:`run`): ``(plan, plant, inputs)``, what the
        firmware derives from the items and the discretised plant, each kept while unchanged
        (``plant``: ``[2]`` floats, ``[3]`` float64 array or None; ``inputs``: ``[1]`` floats)."""
        plan = self._plan
        inputs = self._inputs
        motor = self.motor_             # its constants and load inertia: no held state, no store-back
        if not same_inputs or plan is None or table is not self._plan_table:
            self._plan_table = table
            try:
                base = _PLAN_ITEMS(table)
            except KeyError:            # a partial table: the defaults fill in (always derived afresh)
                base = None
            if base is not None and base == self._plan_base and inputs is not None and inputs[0] is plan:
                plan.set_goals(table)   # only the goals changed: the rest of the plan and inputs stand
                inputs = self._inputs = (plan, _with_goals(inputs[1], plan))
            else:
                plan = self._plan = _InputPlan(table, motor.params.resistance_ohm, self._cached_gains)
                self._plan_base = base
        if inputs is None or inputs[0] is not plan:
            inputs = self._inputs = self._derive_inputs(plan)
        plant = self._plant
        if plant is None or plant[0] != dt_s or plant[1] != motor.load_inertia_kg_m2:
            plant = self._plant = self._derive_plant(dt_s)
        self._sign, self._homing = plan.sign, plan.homing
        return plan, plant, inputs

    def run_flags(self, plan: "_InputPlan") -> tuple[bool, bool]:
        """``(switched, new_goal)`` of :func:`servo_ticks` for a run under ``plan``: the mode (or
        torque, Drive Mode) changed since the last run, the goal position did."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        switched = plan.key != self._prev_key_
        return switched, switched or plan.goal_position != self._prev_goal_position_

    def kernel_state(self) -> tuple[tuple, tuple]:
        """The state :func:`servo_ticks` takes, as ``(floats, ints)`` in the columns of
        :data:`.coupled.FLOATS` (current A, speed rad/s and angle rad of the motor, the two
        Bessel filters, the profile's position, velocity and acceleration, the integral,
        temperature °C, duty, held goal, goal pulse, friction torque N·m, overload timer s) and
        :data:`.coupled.INTS` (profile ongoing and type, wrap pulse, started, holding, stuck,
        reported protection bits)."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        motor, vf, rf, prof = self.motor_, self.velocity_filter_, self.reference_filter_, self.profile_
        hold, protection = self._hold_position_, self.protection_
        return ((motor.current_a, motor.speed_radps, motor.angle_rad, vf.y, vf.dy, rf.y, rf.dy, prof.position,
                 prof.velocity, prof.acceleration, self.loop_.integral, self.temperature_c_, self.duty_,
                 0.0 if hold is None else hold, self._goal_pulse_, motor.friction_torque_nm,
                 0.0 if protection is None else protection.overload_timer_s),
                (prof.ongoing, prof.profile_type, self._wrap_pulse_, self._started_, hold is not None, motor.stuck,
                 0 if protection is None else protection.raised))

    def fresh(self) -> None:
        """Store back the :attr:`holder`'s newer state, if any: after it, a method reads and sets
        the held attributes by their stored names (``motor_`` for :attr:`motor`: a plain
        attribute, not the checking descriptor), one check for all of them."""
        holder = self.holder
        if holder is not None and holder.dirty:
            holder.store_back()

    def finish_run(self, table: Mapping[str, int], record: tuple, bits: int, floats, ints, present: int,
                   v_meas: float) -> None:
        """After a run of ticks under ``table`` and the plan whose :meth:`_InputPlan.record` is
        ``record`` (taken when the run began): store the state :func:`servo_ticks`
        left (``floats``, ``ints``: as :meth:`kernel_state` orders them), the last Present
        Position (pulse) and measured velocity (velocity units), and note the Hardware Error
        ``bits`` it raised. The caller holds the newest state: no :attr:`holder` is dirty."""
        motor, vf, rf, prof, loop = self.motor_, self.velocity_filter_, self.reference_filter_, self.profile_, self.loop_
        (motor.current_a, motor.speed_radps, motor.angle_rad, vf.y, vf.dy, rf.y, rf.dy, prof.position, prof.velocity,
         prof.acceleration, loop.integral, self.temperature_c_, self.duty_, hold, self._goal_pulse_,
         motor.friction_torque_nm, overload_s) = floats
        ongoing, prof.profile_type, self._wrap_pulse_, started, holding, stuck, raised = ints
        prof.ongoing, self._started_, motor.stuck = bool(ongoing), bool(started), bool(stuck)
        protection = self.protection_
        if protection is not None:
            protection.overload_timer_s, protection.raised = overload_s, raised
        if bits:
            self.pending_hardware_error |= bits
        self._hold_position_ = hold if holding else None
        key, goal_position, mode, torque, sign = record
        self._prev_key_, self._prev_goal_position_ = key, goal_position
        self._last_ = (table, mode, torque, present, v_meas, sign)
        self.state_version += 1

    def _input_row(self, inputs: tuple) -> np.ndarray:
        """``inputs[1]`` (:meth:`_derive_inputs`) as a float64 array, made once per ``inputs``."""
        cached = self._input_array
        if cached is None or cached[0] is not inputs:
            cached = self._input_array = (inputs, np.array(inputs[1]))
        return cached[1]

    def _derive_inputs(self, plan: "_InputPlan") -> tuple:
        """:func:`servo_ticks`'s ``inputs`` for the input items ``plan``: mode flags (1.0 / 0.0),
        limits, gains, goals, as ``(plan, floats)`` (:meth:`_input_row`: the float64 array)."""
        v_a_max = kp = ki = kd = ff1 = ff2 = p_v_max = p_a_max = 0.0    # (unused in the other modes)
        v_goal, position_goal = _goal_coefficients(plan)
        if plan.velocity_mode:
            v_a_max = plan.velocity_a_max
            kp, ki = plan.velocity_gains.kp, plan.velocity_gains.ki
        elif plan.position_mode:
            g = plan.position_gains
            kp, ki, kd, ff1, ff2 = g.kp, g.ki, g.kd, g.ff1, g.ff2
            p_v_max, p_a_max = plan.position_v_max, plan.position_a_max
        flags = (plan.velocity_mode, plan.position_mode, plan.pwm_mode, plan.firmware_mode, plan.rewrap_on_switch,
                 plan.current_position_mode, plan.tripped, self.fw.bessel_placement == "reference",
                 self._measure_filtered, bool(kd or ff1 or ff2), plan.torque)
        unused = 0.0
        coef = (*map(float, map(bool, flags)), float(plan.sign), plan.pwm_lim, plan.current_margin_v,
                v_goal, v_a_max, kp, ki, kd, ff1, ff2, p_v_max, p_a_max, position_goal,
                unused if plan.position_current_limit is None else plan.position_current_limit,
                unused if plan.pwm_counts is None else plan.pwm_counts,
                unused if plan.current_ref is None else plan.current_ref, *plan.limits)
        return plan, coef

    def _derive_plant(self, dt_s: float) -> tuple:
        """:func:`servo_ticks`'s ``plant`` for steps of ``dt_s`` at the present load inertia: the
        discrete filter, motor (driven, coasting) and thermal coefficients and the firmware's
        constants, as ``(dt_s, inertia, floats, float64 array or None without the compiled kernel)``."""
        motor, fw, th = self.motor, self.fw, self.thermal
        p = motor.params
        friction = (0.0, 0.0, 1.0, 0.0) if motor.friction is None else friction_terms(motor.friction)
        overload = (1.0, 1.0) if self.protection is None else (self.protection.params.overload_current_a,
                                                                self.protection.params.overload_time_s)
        vf = self.velocity_filter
        if dt_s != vf._dt_s:
            vf.prepare(dt_s)
        ((fa00, fa01), (fa10, fa11)), (fb0, fb1) = vf._coef
        (((a00, a01, _), (a10, a11, _), (a20, a21, _)),
         ((b00, b01), (b10, b11), (b20, b21))) = motor.coefficients(dt_s, False)
        ((c00, c01), (c10, c11)), ((cb0,), (cb1,)) = motor.coefficients(dt_s, True)
        coef = tuple(map(float, (
            motor.gear_ratio, p.back_emf_v_s_per_rad, p.resistance_ohm, fw.gain_time_base_s, dt_s / self.loop.tick_s,
            self.loop.ka, p.inductance_h / fw.current_loop_time_constant_s,
            fa00, fa01, fa10, fa11, fb0, fb1, *bessel_coefficients(vf.cutoff_radps, vf.norm),
            a00, a01, a10, a11, a20, a21, b00, b01, b10, b11, b20, b21, c00, c01, c10, c11, cb0, cb1,
            math.exp(-dt_s / th.time_constant_s), th.ambient_c, th.thermal_resistance_k_per_w,
            self.sensors.position_noise_std_pulse, motor.friction is not None, motor.gear_ratio * p.torque_nm_per_a,
            electrical_decay(p, dt_s), *friction, self.protection is not None, *overload)))
        return dt_s, motor.load_inertia_kg_m2, coef, None if _COMPILED_TICKS is None else np.array(coef)

    def reading(self) -> tuple[float | None, float | None] | None:
        """Draw the sensor noise of a new reading of the present items: ``(current A, voltage V)``,
        each ``None`` where that noise is off; ``None`` before the first step (nothing drawn, the
        servo at rest). The draws :meth:`outputs` makes when it is given no reading, in its order."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        if self._last_ is None:
            return None
        s = self.sensors
        return (self.rng.normal(0.0, s.current_noise_std_a) if s.current_noise_std_a else None,
                self.rng.normal(0.0, s.voltage_noise_std_v) if s.voltage_noise_std_v else None)

    def motion(self, reading: tuple[float | None, float | None]) -> tuple[int, int, int]:
        """Raw Present Current, Velocity and Position of ``reading`` (from :meth:`reading`, not
        ``None``): the same integers :meth:`outputs` gives for it."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        _t, _mode, _torque, present, v_meas, sign = self._last_
        current = sign * self.motor_.current_a
        if reading[0] is not None:
            current += reading[0]
        return round(current / _AMP_PER_CURRENT_UNIT), round(v_meas), present

    def outputs(self, reading: tuple[float | None, float | None] | None = None) -> dict[str, int]:
        """Raw present items (see :meth:`step`) after the last :meth:`advance`, of ``reading``
        (:meth:`reading`'s noise draws; ``None``: a new reading, drawn here). Before the first
        step: the servo at rest."""
        if self.holder is not None:     # a held model: its newest state may be in the holder
            self.fresh()
        last = self._last_
        if last is None:
            return {"present_position": math.floor(self.position_pulse),
                    "present_input_voltage": round(self.supply_voltage_v / u.VOLT_PER_UNIT),
                    "present_temperature": round(self.temperature_c)}
        if reading is None:
            reading = self.reading()
        t, mode, torque, present, v_meas, sign = last
        current_raw, vel, _ = self.motion(reading)
        volts = self.supply_voltage_v_
        if reading[1] is not None:
            volts += reading[1]
        profile = self.profile_
        position_mode = mode in _POSITION_MODES
        if position_mode:
            v_traj = profile.velocity / PULSE_PER_S_PER_VEL_UNIT
            p_traj = profile.position
        else:
            v_traj, p_traj = (profile.velocity if mode == _MODE_VELOCITY else 0.0), float(present)
        ongoing = torque and profile.ongoing
        status = 0
        if torque and position_mode:
            status = _profile_bits(profile.profile_type)
            if ongoing:
                status |= _PROFILE_ONGOING
            elif abs(self._goal_pulse_ - present) <= self.fw.in_position_window_pulse:
                status |= _IN_POSITION
            if abs(profile.position - present) > self.fw.following_error_pulse:
                status |= _FOLLOWING_ERROR
        elif ongoing:
            status = _PROFILE_ONGOING
        return {
            "present_pwm": round(self.duty_ * _PWM_FULL_SCALE) if torque else 0,
            "present_current": current_raw,
            "present_velocity": vel,
            "present_position": present,
            "velocity_trajectory": round(v_traj),
            "position_trajectory": round(p_traj),
            "present_input_voltage": round(volts / _VOLT_PER_UNIT),
            "present_temperature": round(self.temperature_c_),
            "moving": int(abs(vel) > t["moving_threshold"] or ongoing and position_mode),
            "moving_status": status,
        }

    def _cached_gains(self, key: tuple, convert):
        """Converted gains for raw gain items ``key[1:]`` (building the dataclass every tick is slow)."""
        g = self._gains.get(key)
        if g is None:
            if len(self._gains) >= 64:  # a tuning sweep: keep the cache small
                self._gains.clear()
            g = self._gains[key] = convert(*key[1:])
        return g


class _InputPlan:
    """What the firmware derives from one set of raw input items (limits, gains, profile bounds);
    derived once per change of the items, not per tick. Same arithmetic as deriving it per tick."""

    __slots__ = ("sign", "homing", "mode", "torque", "key", "goal_position", "tripped", "pwm_lim",
                 "current_margin_v", "pwm_counts", "current_ref", "velocity_goal", "velocity_a_max",
                 "velocity_gains", "position_goal", "position_v_max", "position_a_max", "position_gains",
                 "position_current_limit", "position_mode", "velocity_mode", "pwm_mode", "current_position_mode",
                 "firmware_mode", "rewrap_on_switch", "limits")

    def __init__(self, t: Mapping[str, int], resistance_ohm: float, gains):
        self.sign = -1 if t["drive_mode"] & 1 else 1
        self.homing = t["homing_offset"]
        self.mode = mode = t["operating_mode"]
        self.torque = t["torque_enable"] != 0
        self.key = (mode, self.torque, t["drive_mode"])
        self.position_mode = mode in u.POSITION_MODES
        self.velocity_mode = mode == u.MODE_VELOCITY
        self.pwm_mode = mode == u.MODE_PWM
        self.current_position_mode = mode == u.MODE_CURRENT_POSITION
        # torque on in a mode the firmware runs loops for; Position mode re-wraps when it starts
        self.firmware_mode = self.torque and (self.position_mode or self.velocity_mode or self.pwm_mode
                                              or mode == u.MODE_CURRENT)
        self.rewrap_on_switch = self.torque and mode == u.MODE_POSITION
        self.limits = limits(t)
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
            pa = t["profile_acceleration"]
            self.velocity_a_max = math.inf if pa == 0 or tripped else pa * VEL_UNIT_PER_S_PER_ACC_UNIT
            self.velocity_gains = gains(("v", t["velocity_p_gain"], t["velocity_i_gain"]), VelocityGains.from_table)
        elif mode in u.POSITION_MODES:
            vlim = float(t["velocity_limit"])
            pv, pa = min(t["profile_velocity"], vlim), t["profile_acceleration"]
            self.position_v_max = math.inf if pv == 0 or tripped else pv * PULSE_PER_S_PER_VEL_UNIT
            self.position_a_max = math.inf if pa == 0 or tripped else pa * PULSE_PER_S2_PER_ACC_UNIT
            self.position_gains = gains(("p", t["position_p_gain"], t["position_i_gain"], t["position_d_gain"],
                                         t["feedforward_1st_gain"], t["feedforward_2nd_gain"]),
                                        PositionGains.from_table)
            if mode == u.MODE_CURRENT_POSITION:
                self.position_current_limit = float(min(abs(t["goal_current"]), t["current_limit"]))
        self.set_goals(t)

    def record(self) -> tuple:
        """``(key, goal_position, mode, torque, sign)`` as they are now (:meth:`set_goals` changes
        the goal in place): what :meth:`ServoModel.finish_run` keeps of a run's plan."""
        return self.key, self.goal_position, self.mode, self.torque, self.sign

    def set_goals(self, t: Mapping[str, int]) -> None:
        """Goal Position and Goal Velocity from the items ``t`` (limited as the mode does); the
        rest of the plan must be that of ``t`` (a new goal changes nothing else)."""
        self.goal_position = t["goal_position"]
        mode = self.mode
        if self.velocity_mode:
            vlim = float(t["velocity_limit"])
            self.velocity_goal = 0.0 if self.tripped else max(-vlim, min(vlim, float(t["goal_velocity"])))
        elif self.position_mode:
            goal = float(t["goal_position"])
            if mode == u.MODE_POSITION:
                goal = max(float(t["min_position_limit"]), min(float(t["max_position_limit"]), goal))
            self.position_goal = goal


#: Every item :class:`_InputPlan` reads but Goal Position and Goal Velocity: a plan whose items
#: differ from new ones only in those two is brought up to date by :meth:`_InputPlan.set_goals`.
_PLAN_ITEMS = operator.itemgetter(
    "drive_mode", "homing_offset", "operating_mode", "torque_enable", "temperature_limit", "min_voltage_limit",
    "max_voltage_limit", "goal_pwm", "pwm_limit", "current_limit", "bus_watchdog", "goal_current",
    "velocity_limit", "profile_acceleration", "velocity_p_gain", "velocity_i_gain", "min_position_limit",
    "max_position_limit", "profile_velocity", "position_p_gain", "position_i_gain", "position_d_gain",
    "feedforward_1st_gain", "feedforward_2nd_gain")
#: Columns of the goals in :func:`servo_ticks`'s ``inputs`` (:meth:`ServoModel._derive_inputs`).
_V_GOAL_COLUMN, _POSITION_GOAL_COLUMN = 14, 23


def _goal_coefficients(plan: _InputPlan) -> tuple[float, float]:
    """The velocity goal (velocity units) and position goal (pulse) columns of a plan's inputs
    (0.0 in the modes that do not use them)."""
    return (plan.velocity_goal if plan.velocity_mode else 0.0,
            0.0 if plan.position_goal is None else plan.position_goal)


def _with_goals(coef: tuple, plan: _InputPlan) -> tuple:
    """``coef`` (:meth:`ServoModel._derive_inputs` of a plan that differs from ``plan`` only in
    its goals) with ``plan``'s goals."""
    v_goal, position_goal = _goal_coefficients(plan)
    return (*coef[:_V_GOAL_COLUMN], v_goal, *coef[_V_GOAL_COLUMN + 1:_POSITION_GOAL_COLUMN], position_goal,
            *coef[_POSITION_GOAL_COLUMN + 1:])


def _profile_bits(profile_type: int) -> int:
    """Moving Status bits 5:4 for a profile type (0 none .. 3 trapezoidal)."""
    return (profile_type & 0x3) << 4


@jitable
def wrapped_pulse(raw_pulse: int) -> int:
    """The multiple of 4096 pulses removed when Present Position is re-wrapped to one turn."""
    return u.PULSES_PER_REV * (raw_pulse // u.PULSES_PER_REV)


@jitable
def servo_ticks(n, dt_s, plant, inputs, homing, record_speeds, speeds, record_positions, positions, rng, blocked,
                i_a_, w, th, fy, fdy, ry, rdy, ppos, pvel, pacc, pongoing, ptype, integral,
                temp, duty, wrap, started, switched, new_goal, holding, hold, goal_pulse, stuck, friction_torque,
                overload_s, raised, enc_off, supply, load_torque_nm):
    """Up to ``n`` ticks of one servo (:meth:`ServoModel.run`): state in, state out, on plain numbers.

    ``plant`` / ``inputs``: the constants of :meth:`ServoModel._derive_plant` /
    :meth:`ServoModel._derive_inputs` (tuples, or float64 arrays when compiled); ``homing``:
    Homing Offset, pulse. ``speeds`` / ``positions``: buffers of ``n``
    entries that get the output speed (rad/s) / true position (pulse) after each tick when
    ``record_speeds`` / ``record_positions``. ``rng`` (position noise) is ``None`` unless the
    configuration needs it (compiled, always). ``blocked``: the shaft is held (a stall test).
    The state: motor current (A), speed and angle (motor side, rad/s,
    rad); velocity and reference filter states; profile position, velocity, acceleration, ongoing
    and type; PI integral; winding temperature (°C); duty; the wrap of Present Position (pulse);
    whether the encoder was read before; whether the mode / the goal changed before this run;
    the watchdog's held goal (``holding``, ``hold``); the goal after limits (pulse); the gearbox's
    stick state and friction torque (N·m, :func:`.motor.friction_step`); the protection's overload
    timer (s) and reported bits (:func:`.protection.protection_step`). Then the encoder offset
    (pulse), supply (V) and load torque (output side, N·m) of the run.

    Returns ``(ran, hardware_error_bits)``, the new state in the order of the arguments (without
    ``switched`` and ``new_goal``), then the last Present Position (pulse) and measured velocity
    (velocity units).
    """
    (gear, ke, r_arm, tick, ticks, ka, l_over_tc, fa00, fa01, fa10, fa11, fb0, fb1, bessel_a1, bessel_a0,
     a00, a01, a10, a11, a20, a21, b00, b01, b10, b11, b20, b21, c00, c01, c10, c11, cb0, cb1,
     decay, ambient, r_th, noise, has_friction, gear_km, decay_e, coulomb, breakaway, stribeck, viscous, protect,
     overload_a, overload_time_s) = plant
    (velocity_mode, position_mode, pwm_mode, firmware_mode, rewrap_on_switch, current_position, tripped,
     reference_filter, measure_filtered, d_or_ff, torque, fsign, pwm_lim, margin, v_goal, v_a_max, kp, ki, kd, ff1,
     ff2, p_v_max, p_a_max, position_goal, position_current_limit, pwm_counts, current_ref, temperature_limit,
     min_voltage, max_voltage) = inputs
    own_step = has_friction != 0.0 or blocked     # the motor's friction step, else its linear one inline
    neg_supply = -supply
    tau = load_torque_nm / gear
    # the load's terms of the motor step, the same every tick of the run
    b01_tau, b11_tau, b21_tau, cb0_tau, cb1_tau = b01 * tau, b11 * tau, b21 * tau, cb0 * tau, cb1 * tau
    rad_per_pulse, radps_per_vel_unit = u.RAD_PER_PULSE, u.RADPS_PER_VEL_UNIT
    pulse_per_vel_unit, pwm_full_scale = PULSE_PER_S_PER_VEL_UNIT, float(u.PWM_FULL_SCALE)
    # (the int sign and counts as floats: the same products, without int-float conversions per tick)
    sign_off = fsign * enc_off
    wrap_f, homing_f = float(wrap), float(homing)
    # encoder before noise (:meth:`ServoModel._encoder_pulse`: the same arithmetic), then after each tick
    x = fsign * (th / gear / rad_per_pulse + enc_off)
    # the inner current loop runs in Current and Current-based Position modes
    current_loop = current_position or not (velocity_mode or position_mode or pwm_mode)
    present = bits = ran = 0
    v_meas = voltage = i_ref = counts = 0.0
    for ran in range(1, n + 1):
        if rng is not None:
            raw = math.floor(x + rng.normal(0.0, noise))
        else:
            raw = math.floor(x)
        if not started:
            fy, fdy = bessel_reset(raw, 0.0, bessel_a1, bessel_a0)
            started = True
        if switched and rewrap_on_switch:   # Present Position re-wrapped to one turn (+ Homing Offset)
            wrap = wrapped_pulse(raw)
            wrap_f = float(wrap)
        present = raw - wrap + homing
        fy, fdy = bessel_step(fy, fdy, raw, fa00, fa01, fa10, fa11, fb0, fb1)
        if measure_filtered:
            v_meas = fdy / pulse_per_vel_unit
        else:                       # ideal estimator: the true speed (README: placement choice)
            v_meas = fsign * (w / gear) / radps_per_vel_unit
        if switched:
            integral = 0.0
            holding = False
            pacc, pongoing = 0.0, False
            if position_mode:
                ppos, pvel = float(present), 0.0
                ry, rdy = bessel_reset(float(present), 0.0, bessel_a1, bessel_a0)
            else:
                ppos, pvel = 0.0, v_meas if torque else 0.0
                ry, rdy = bessel_reset(v_meas if torque else 0.0, 0.0, bessel_a1, bessel_a0)
        if firmware_mode:           # the firmware's loops (e-Manual: operating modes); else the bridge is open
            w_m = fsign * w         # motor speed in the servo frame
            if velocity_mode:
                ppos, pvel, pacc, pongoing = velocity_profile_step(ppos, pvel, dt_s, v_goal, v_a_max)
                ref = pvel
                if reference_filter:
                    ry, rdy = bessel_step(ry, rdy, pvel, fa00, fa01, fa10, fa11, fb0, fb1)
                    ref = ry
                counts, integral = pi_step(integral, ticks, ka, ref - v_meas, kp, ki, 0.0, pwm_lim)
            elif position_mode:
                goal = goal_pulse = position_goal
                if tripped:
                    if not holding:
                        holding, hold, new_goal = True, float(present), True
                    goal = goal_pulse = hold
                if new_goal:        # a new profile starts whenever the goal changes
                    ptype = profile_type(ppos, goal, p_v_max, p_a_max)
                    pongoing = True
                ppos, pvel, pacc, pongoing = position_profile_step(ppos, pvel, pongoing, dt_s, goal,
                                                                   p_v_max, p_a_max)
                ref = ppos
                if reference_filter:
                    ry, rdy = bessel_step(ry, rdy, ppos, fa00, fa01, fa10, fa11, fb0, fb1)
                    ref = ry
                if d_or_ff:
                    v_traj = pvel * tick                   # pulse per tick
                    a_traj = pacc * tick * tick            # pulse per tick²
                    v_err = v_traj - v_meas * pulse_per_vel_unit * tick
                    extra = kd * v_err + ff1 * v_traj + ff2 * a_traj
                else:   # kd = ff1 = ff2 = 0: that sum is ±0.0, and kp e + I + ±0.0 equals kp e + I + 0.0
                    extra = 0.0     # (the integral is never -0.0, so kp e + I is not either)
                counts, integral = pi_step(integral, ticks, ka, ref - present, kp, ki, extra, pwm_lim)
                if current_position:
                    i_ref = max(-position_current_limit, min(position_current_limit, counts))
            elif pwm_mode:
                counts = pwm_counts
            else:
                i_ref = current_ref
            if current_loop:        # inner current loop: ideal inverse model + P on the error
                i_a = i_ref * u.AMP_PER_CURRENT_UNIT
                v = r_arm * i_a + ke * w_m + l_over_tc * (i_a - fsign * i_a_)
                counts = max(-pwm_lim, min(pwm_lim, v / supply * pwm_full_scale))
            v = counts / pwm_full_scale * supply
            # Current Limit (38): keep |v - Ke w| <= R I_lim, the steady armature current bound.
            # (max(lo, min(hi, v)) written out: the same result, without two calls)
            emf = ke * w_m
            hi = emf + margin
            v = v if v < hi else hi
            lo = emf - margin
            v = v if v > lo else lo
            v = v if v < supply else supply
            v = v if v > neg_supply else neg_supply
            duty = v / supply
            voltage = fsign * v
        else:
            integral = 0.0
            duty = 0.0
            ppos, pvel, pacc, pongoing = float(present) if position_mode else 0.0, 0.0, 0.0, False
        if own_step:                # gearbox friction or a held shaft (:meth:`GearedMotor.step`)
            applied = voltage if firmware_mode else 0.0
            i_a_, w, th, stuck, friction_torque = friction_step(
                firmware_mode, applied, i_a_, w, th, load_torque_nm, blocked, stuck,
                friction_torque, gear, gear_km, decay_e, r_arm, coulomb, breakaway, stribeck, viscous, a00, a01,
                a10, a11, a20, a21, b00, b01, b10, b11, b20, b21, c00, c01, c10, c11, cb0, cb1)
        elif not firmware_mode:     # bridge open (:meth:`GearedMotor._step_linear`)
            i_a_, w, th = 0.0, c00 * w + c01 * th + cb0_tau, c10 * w + c11 * th + cb1_tau
        else:
            i_a_, w, th = (a00 * i_a_ + a01 * w + b00 * voltage + b01_tau,
                           a10 * i_a_ + a11 * w + b10 * voltage + b11_tau,
                           a20 * i_a_ + a21 * w + th + b20 * voltage + b21_tau)
        x = fsign * (th / gear / rad_per_pulse + enc_off)
        # winding temperature: first order towards ambient + R_th * I² R (I·I, not I ** 2: Python's
        # ** is libm's pow, which is not always the correctly rounded I·I compiled code computes)
        steady = ambient + r_th * (i_a_ * i_a_ * r_arm)
        temp = steady + (temp - steady) * decay
        switched = new_goal = False
        if record_speeds:
            speeds[ran - 1] = fsign * (w / gear)
        if record_positions:
            positions[ran - 1] = (x - wrap_f + homing_f) - sign_off
        if protect:
            bits, overload_s, raised = protection_step(dt_s, i_a_, temp, supply, overload_s, raised, overload_a,
                                                       overload_time_s, temperature_limit, min_voltage, max_voltage)
            if bits:
                break
    return (ran, bits, i_a_, w, th, fy, fdy, ry, rdy, ppos, pvel, pacc, pongoing, ptype, integral, temp, duty,
            wrap, started, holding, hold, goal_pulse, stuck, friction_torque, overload_s, raised, present, v_meas)


#: :func:`servo_ticks` compiled (:mod:`.jit`), or ``None`` without numba or with ``SWERVE_NO_JIT`` set.
#: Source files of the :func:`.jit.jitable` helpers :func:`servo_ticks` calls (the kernel's cache stamp).
KERNEL_SOURCES = (firmware.__file__, bessel.__file__, u.__file__, motor_module.__file__, protection_module.__file__)
_COMPILED_TICKS = compiled(servo_ticks, depends=KERNEL_SOURCES)


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
