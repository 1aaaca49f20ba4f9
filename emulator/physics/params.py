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
        body=body, paper_spec_gains=gains)


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
