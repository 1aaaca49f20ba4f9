"""Configuration dataclasses for the physics and their YAML loader (``configs/emulator.yaml``).

Malformed input raises :class:`driver.errors.ConfigError` naming the offending key.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import yaml

from swerve.driver.errors import ConfigError

BESSEL_PLACEMENTS = ("velocity_feedback", "reference", "none")
BESSEL_NORMS = ("mag", "phase", "delay")


@dataclass(frozen=True)
class MotorParams:
    """Armature DC motor, motor-side values (paper Table 1). SI units."""

    resistance_ohm: float
    inductance_h: float
    back_emf_v_s_per_rad: float
    torque_nm_per_a: float
    friction_nm_s_per_rad: float
    inertia_kg_m2: float


@dataclass(frozen=True)
class FirmwareParams:
    """Fixed (not user-settable) firmware constants; see README for what is assumed."""

    gain_time_base_s: float = 1.0e-3
    anti_windup_gain: float = 1.0
    current_loop_time_constant_s: float = 1.0e-3
    in_position_window_pulse: float = 10.0
    following_error_pulse: float = 256.0
    bessel_cutoff_radps: float = 32.8
    bessel_norm: str = "mag"
    bessel_placement: str = "velocity_feedback"


@dataclass(frozen=True)
class SensorParams:
    """Optional Gaussian sensor noise (standard deviations; 0 disables)."""

    position_noise_std_pulse: float = 0.0
    current_noise_std_a: float = 0.0
    voltage_noise_std_v: float = 0.0


@dataclass(frozen=True)
class ThermalParams:
    """First-order winding temperature: ``tau dT/dt = R_th * i^2 R - (T - T_amb)``."""

    ambient_c: float = 25.0
    thermal_resistance_k_per_w: float = 8.0
    time_constant_s: float = 300.0


@dataclass(frozen=True)
class BodyParams:
    """Robot mass for the optional wheel load."""

    mass_kg: float = 3.25
    payload_kg: float = 1.5
    load_enabled: bool = True

    @property
    def total_mass_kg(self) -> float:
        """Mass carried by the four wheels, kg."""
        return self.mass_kg + self.payload_kg


@dataclass(frozen=True)
class GearFrictionParams:
    """Gearbox friction at the output shaft (N·m, rad/s); all zero = none (Table 1 viscous only).

    ``τ_f(ω) = sign(ω)·(Tc + (Ts − Tc)·exp(−(ω/ωs)²)) + b·ω`` while slipping; at rest the shaft
    sticks until the driving torque exceeds ``Ts`` (breakaway).
    """

    coulomb_nm: float = 0.0
    static_nm: float = 0.0
    stribeck_speed_radps: float = 1.0
    viscous_nm_s_per_rad: float = 0.0

    @property
    def enabled(self) -> bool:
        """Whether any friction term is non-zero."""
        return bool(self.coulomb_nm or self.static_nm or self.viscous_nm_s_per_rad)

    @property
    def breakaway_nm(self) -> float:
        """Torque needed to start the shaft from rest, N·m."""
        return max(self.static_nm, self.coulomb_nm)


@dataclass(frozen=True)
class SupplyParams:
    """Battery behind the bus: open-circuit voltage is ``physics.supply_voltage_v``."""

    internal_resistance_ohm: float = 0.0
    idle_current_a: float = 0.0          # per servo, drawn whatever the motor does

    @property
    def enabled(self) -> bool:
        """Whether the bus voltage sags under load."""
        return self.internal_resistance_ohm > 0.0


@dataclass(frozen=True)
class ContactParams:
    """Wheel-ground contact: friction-limited tyres instead of the least-squares kinematic fit."""

    enabled: bool = False
    friction_coefficient: float = 0.8
    slip_stiffness_n_s_per_m: float = 300.0      # force per slip speed below saturation
    lateral_stiffness_ratio: float = 1.0         # lateral / longitudinal slip stiffness
    yaw_inertia_kg_m2: float = 0.0               # 0: a uniform square plate through the wheels
    gravity_mps2: float = 9.81


@dataclass(frozen=True)
class ToleranceParams:
    """Build tolerances the robot file does not know (wheel order of ``robot.yaml``)."""

    wheel_radius_scale: tuple[float, ...] = ()       # true radius / nominal, per wheel
    steer_zero_offset_rad: tuple[float, ...] = ()    # true straight-ahead minus nominal centre
    steer_backlash_rad: float = 0.0                  # free play between steering horn and wheel
    encoder_offset_pulse: tuple[float, ...] = ()     # steering encoders: reading minus true angle

    @property
    def enabled(self) -> bool:
        """Whether any tolerance differs from nominal."""
        return (any(s != 1.0 for s in self.wheel_radius_scale) or any(self.steer_zero_offset_rad)
                or self.steer_backlash_rad > 0.0 or any(self.encoder_offset_pulse))


@dataclass(frozen=True)
class ProtectionParams:
    """Firmware protection raised from the physics (Hardware Error Status bits)."""

    enabled: bool = False
    overload_current_a: float = 1.0      # |armature current| above this counts towards Overload
    overload_time_s: float = 1.0         # sustained this long: Overload (bit 5)


@dataclass(frozen=True)
class PhysicsConfig:
    """Everything in ``configs/emulator.yaml``."""

    rate_hz: float
    supply_voltage_v: float
    drive_motor: MotorParams
    steering_motor: MotorParams
    gear_ratios: Mapping[str, float]
    firmware: FirmwareParams = field(default_factory=FirmwareParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    thermal: ThermalParams = field(default_factory=ThermalParams)
    body: BodyParams = field(default_factory=BodyParams)
    paper_spec_gains: Mapping[str, int] = field(default_factory=dict)
    drive_friction: GearFrictionParams = field(default_factory=GearFrictionParams)
    steering_friction: GearFrictionParams = field(default_factory=GearFrictionParams)
    supply: SupplyParams = field(default_factory=SupplyParams)
    contact: ContactParams = field(default_factory=ContactParams)
    tolerances: ToleranceParams = field(default_factory=ToleranceParams)
    protection: ProtectionParams = field(default_factory=ProtectionParams)

    def gear_ratio(self, model: str) -> float:
        """Gear ratio of a servo model name such as ``"xh430-w210"``."""
        try:
            return self.gear_ratios[model.lower()]
        except KeyError:
            raise ConfigError(f"gear_ratios: no entry for servo model {model!r}") from None


def _section(doc: Mapping[str, Any], key: str, required: bool = True) -> Mapping[str, Any]:
    value = doc.get(key)
    if value is None and not required:
        return {}
    if not isinstance(value, Mapping):
        raise ConfigError(f"{key}: expected a mapping, got {type(value).__name__}")
    return value


def _number(sec: Mapping[str, Any], path: str, key: str, *, positive: bool = False,
            default: float | None = None) -> float:
    if key not in sec:
        if default is None:
            raise ConfigError(f"{path}.{key}: missing")
        return default
    value = sec[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{path}.{key}: expected a number, got {value!r}")
    if value < 0 or (positive and value == 0):
        raise ConfigError(f"{path}.{key}: must be {'> 0' if positive else '>= 0'}, got {value!r}")
    return float(value)


def _motor(sec: Mapping[str, Any], path: str) -> MotorParams:
    names = ("resistance_ohm", "inductance_h", "back_emf_v_s_per_rad", "torque_nm_per_a",
             "inertia_kg_m2")
    kw = {n: _number(sec, path, n, positive=True) for n in names}
    kw["friction_nm_s_per_rad"] = _number(sec, path, "friction_nm_s_per_rad")
    return MotorParams(**kw)


def _choice(sec: Mapping[str, Any], path: str, key: str, choices: tuple[str, ...], default: str) -> str:
    value = sec.get(key, default)
    if value not in choices:
        raise ConfigError(f"{path}.{key}: expected one of {choices}, got {value!r}")
    return value


def parse_config(doc: Mapping[str, Any]) -> PhysicsConfig:
    """Build a :class:`PhysicsConfig` from a parsed YAML mapping.

    Raises
    ------
    ConfigError
        On a missing or malformed key; the message starts with the key's dotted path.
    """
    if not isinstance(doc, Mapping):
        raise ConfigError("emulator config: expected a mapping at the top level")
    phys = _section(doc, "physics")
    rate = _number(phys, "physics", "rate_hz", positive=True)
    if rate < 1000:
        raise ConfigError(f"physics.rate_hz: must be >= 1000, got {rate:g}")
    motors = _section(doc, "motors")
    gears = _section(doc, "gear_ratios")
    gear_ratios = {str(k).lower(): _number(gears, "gear_ratios", k, positive=True) for k in gears}
    fw = _section(doc, "firmware", required=False)
    bes = _section(doc, "bessel", required=False)
    d = FirmwareParams()
    firmware = FirmwareParams(
        gain_time_base_s=_number(fw, "firmware", "gain_time_base_s", positive=True, default=d.gain_time_base_s),
        anti_windup_gain=_number(fw, "firmware", "anti_windup_gain", default=d.anti_windup_gain),
        current_loop_time_constant_s=_number(fw, "firmware", "current_loop_time_constant_s",
                                             positive=True, default=d.current_loop_time_constant_s),
        in_position_window_pulse=_number(fw, "firmware", "in_position_window_pulse",
                                         default=d.in_position_window_pulse),
        following_error_pulse=_number(fw, "firmware", "following_error_pulse",
                                      positive=True, default=d.following_error_pulse),
        bessel_cutoff_radps=_number(bes, "bessel", "cutoff_radps", positive=True, default=d.bessel_cutoff_radps),
        bessel_norm=_choice(bes, "bessel", "norm", BESSEL_NORMS, d.bessel_norm),
        bessel_placement=_choice(bes, "bessel", "placement", BESSEL_PLACEMENTS, d.bessel_placement),
    )
    sen = _section(doc, "sensors", required=False)
    sensors = SensorParams(**{k: _number(sen, "sensors", k, default=0.0)
                              for k in ("position_noise_std_pulse", "current_noise_std_a",
                                        "voltage_noise_std_v")})
    th = _section(doc, "thermal", required=False)
    td = ThermalParams()
    thermal = ThermalParams(
        ambient_c=_number(th, "thermal", "ambient_c", default=td.ambient_c),
        thermal_resistance_k_per_w=_number(th, "thermal", "thermal_resistance_k_per_w", positive=True,
                                           default=td.thermal_resistance_k_per_w),
        time_constant_s=_number(th, "thermal", "time_constant_s", positive=True, default=td.time_constant_s),
    )
    bo = _section(doc, "body", required=False)
    load = bo.get("load_enabled", True)
    if not isinstance(load, bool):
        raise ConfigError(f"body.load_enabled: expected true/false, got {load!r}")
    body = BodyParams(mass_kg=_number(bo, "body", "mass_kg", positive=True, default=3.25),
                      payload_kg=_number(bo, "body", "payload_kg", default=1.5), load_enabled=load)
    gains_sec = _section(doc, "paper_spec_gains", required=False)
    gains = {}
    for k, v in gains_sec.items():
        if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 16383:
            raise ConfigError(f"paper_spec_gains.{k}: expected an integer 0..16383, got {v!r}")
        gains[str(k)] = v
    return PhysicsConfig(
        rate_hz=rate,
        supply_voltage_v=_number(phys, "physics", "supply_voltage_v", positive=True),
        drive_motor=_motor(_subsection(motors, "motors", "drive"), "motors.drive"),
        steering_motor=_motor(_subsection(motors, "motors", "steering"), "motors.steering"),
        gear_ratios=gear_ratios, firmware=firmware, sensors=sensors, thermal=thermal,
        body=body, paper_spec_gains=gains, **_realism_sections(doc))


def _flag(sec: Mapping[str, Any], path: str, key: str, default: bool) -> bool:
    value = sec.get(key, default)
    if not isinstance(value, bool):
        raise ConfigError(f"{path}.{key}: expected true/false, got {value!r}")
    return value


def _numbers(sec: Mapping[str, Any], path: str, key: str, n: int, *, signed: bool = False
             ) -> tuple[float, ...]:
    value = sec.get(key, [])
    if not isinstance(value, list) or len(value) not in (0, n) or any(
            isinstance(v, bool) or not isinstance(v, (int, float)) for v in value):
        raise ConfigError(f"{path}.{key}: expected a list of {n} numbers, got {value!r}")
    if not signed and any(v <= 0 for v in value):
        raise ConfigError(f"{path}.{key}: every value must be > 0, got {value!r}")
    return tuple(float(v) for v in value)


def _friction(sec: Mapping[str, Any], path: str) -> GearFrictionParams:
    d = GearFrictionParams()
    f = GearFrictionParams(
        coulomb_nm=_number(sec, path, "coulomb_nm", default=d.coulomb_nm),
        static_nm=_number(sec, path, "static_nm", default=d.static_nm),
        stribeck_speed_radps=_number(sec, path, "stribeck_speed_radps", positive=True,
                                     default=d.stribeck_speed_radps),
        viscous_nm_s_per_rad=_number(sec, path, "viscous_nm_s_per_rad", default=d.viscous_nm_s_per_rad))
    if f.static_nm and f.static_nm < f.coulomb_nm:
        raise ConfigError(f"{path}.static_nm: must be >= coulomb_nm ({f.coulomb_nm:g}), got {f.static_nm:g}")
    return f


def _realism_sections(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The optional sections that make the world disagree with the controller's model
    (``gearbox_friction``, ``supply``, ``contact``, ``tolerances``, ``protection``)."""
    gf = _section(doc, "gearbox_friction", required=False)
    sup = _section(doc, "supply", required=False)
    con = _section(doc, "contact", required=False)
    tol = _section(doc, "tolerances", required=False)
    pro = _section(doc, "protection", required=False)
    cd, pd = ContactParams(), ProtectionParams()
    return dict(
        drive_friction=_friction(_section(gf, "drive", required=False), "gearbox_friction.drive"),
        steering_friction=_friction(_section(gf, "steering", required=False), "gearbox_friction.steering"),
        supply=SupplyParams(
            internal_resistance_ohm=_number(sup, "supply", "internal_resistance_ohm", default=0.0),
            idle_current_a=_number(sup, "supply", "idle_current_a", default=0.0)),
        contact=ContactParams(
            enabled=_flag(con, "contact", "enabled", cd.enabled),
            friction_coefficient=_number(con, "contact", "friction_coefficient", positive=True,
                                         default=cd.friction_coefficient),
            slip_stiffness_n_s_per_m=_number(con, "contact", "slip_stiffness_n_s_per_m", positive=True,
                                             default=cd.slip_stiffness_n_s_per_m),
            lateral_stiffness_ratio=_number(con, "contact", "lateral_stiffness_ratio", positive=True,
                                            default=cd.lateral_stiffness_ratio),
            yaw_inertia_kg_m2=_number(con, "contact", "yaw_inertia_kg_m2", default=cd.yaw_inertia_kg_m2),
            gravity_mps2=_number(con, "contact", "gravity_mps2", positive=True, default=cd.gravity_mps2)),
        tolerances=ToleranceParams(
            wheel_radius_scale=_numbers(tol, "tolerances", "wheel_radius_scale", 4),
            steer_zero_offset_rad=_numbers(tol, "tolerances", "steer_zero_offset_rad", 4, signed=True),
            steer_backlash_rad=_number(tol, "tolerances", "steer_backlash_rad", default=0.0),
            encoder_offset_pulse=_numbers(tol, "tolerances", "encoder_offset_pulse", 4, signed=True)),
        protection=ProtectionParams(
            enabled=_flag(pro, "protection", "enabled", pd.enabled),
            overload_current_a=_number(pro, "protection", "overload_current_a", positive=True,
                                       default=pd.overload_current_a),
            overload_time_s=_number(pro, "protection", "overload_time_s", positive=True,
                                    default=pd.overload_time_s)),
    )


def _subsection(sec: Mapping[str, Any], path: str, key: str) -> Mapping[str, Any]:
    value = sec.get(key)
    if not isinstance(value, Mapping):
        raise ConfigError(f"{path}.{key}: expected a mapping, got {type(value).__name__}")
    return value


def load_config(path: str | Path = "configs/emulator.yaml") -> PhysicsConfig:
    """Read and validate ``configs/emulator.yaml``.

    Raises
    ------
    ConfigError
        If the file is missing, not YAML, or has a malformed key.
    """
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from exc
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML ({exc})") from exc
    return parse_config(doc)
