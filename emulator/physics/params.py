"""Configuration dataclasses for the physics and their YAML loader (``configs/emulator.yaml``).

The file is read by :mod:`swerve.configs.loader`: malformed input raises
:class:`~swerve.core.errors.ConfigError` ``FILE:LINE: KEY: problem``; a key no parser reads
gives a :class:`~swerve.configs.loader.ConfigWarning`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from swerve.configs import shipped
from swerve.core.errors import ConfigError
from swerve.configs.loader import Document, Section, document, read_yaml
from swerve.driver.control_table import REFERENCE_MODEL, table_for

#: The shipped physics config.
DEFAULT_PATH = shipped("emulator.yaml")
#: Plausibility bounds (a larger value is a typo or a wrong unit).
MOTOR_VALUE_MAX = 1e3
PULSE_MAX = 1e6
NOISE_STD_MAX = 1e3
MASS_MAX_KG = 1e3
SUPPLY_MAX_V = 48.0

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


def _motor(sec: Section) -> MotorParams:
    names = ("resistance_ohm", "inductance_h", "back_emf_v_s_per_rad", "torque_nm_per_a",
             "inertia_kg_m2")
    kw = {n: sec.number(n, positive=True, max=MOTOR_VALUE_MAX) for n in names}
    kw["friction_nm_s_per_rad"] = sec.number("friction_nm_s_per_rad", nonneg=True, max=MOTOR_VALUE_MAX)
    sec.check_unknown()
    return MotorParams(**kw)


def parse_config(doc: Mapping[str, Any] | Document, where: str = "emulator config") -> PhysicsConfig:
    """Build a :class:`PhysicsConfig` from a :class:`~swerve.configs.loader.Document` or from
    already-parsed YAML data (named ``where`` in errors).

    Raises
    ------
    ConfigError
        On a missing or malformed key: ``FILE:LINE: KEY: problem``.
    """
    doc = doc if isinstance(doc, Document) else document(doc, where)
    top = doc.root()
    phys = top.section("physics")
    rate = phys.number("rate_hz", min=1000.0, max=1e6)
    motors = top.section("motors")
    gears = top.section("gear_ratios")
    gear_ratios = {str(k).lower(): gears.number(k, positive=True, max=1e4) for k in gears.keys()}
    fw = top.section("firmware", required=False)
    bes = top.section("bessel", required=False)
    d = FirmwareParams()
    firmware = FirmwareParams(
        gain_time_base_s=fw.number("gain_time_base_s", d.gain_time_base_s, positive=True, max=1.0),
        anti_windup_gain=fw.number("anti_windup_gain", d.anti_windup_gain, nonneg=True, max=1e3),
        current_loop_time_constant_s=fw.number("current_loop_time_constant_s",
                                               d.current_loop_time_constant_s, positive=True, max=1.0),
        in_position_window_pulse=fw.number("in_position_window_pulse", d.in_position_window_pulse,
                                           nonneg=True, max=PULSE_MAX),
        following_error_pulse=fw.number("following_error_pulse", d.following_error_pulse,
                                        positive=True, max=PULSE_MAX),
        bessel_cutoff_radps=bes.number("cutoff_radps", d.bessel_cutoff_radps, positive=True, max=1e5),
        bessel_norm=bes.choice("norm", BESSEL_NORMS, d.bessel_norm),
        bessel_placement=bes.choice("placement", BESSEL_PLACEMENTS, d.bessel_placement),
    )
    sen = top.section("sensors", required=False)
    sensors = SensorParams(**{k: sen.number(k, 0.0, nonneg=True, max=NOISE_STD_MAX)
                              for k in ("position_noise_std_pulse", "current_noise_std_a",
                                        "voltage_noise_std_v")})
    th = top.section("thermal", required=False)
    td = ThermalParams()
    thermal = ThermalParams(
        ambient_c=th.number("ambient_c", td.ambient_c, min=-50.0, max=150.0),
        thermal_resistance_k_per_w=th.number("thermal_resistance_k_per_w", td.thermal_resistance_k_per_w,
                                             positive=True, max=1e3),
        time_constant_s=th.number("time_constant_s", td.time_constant_s, positive=True, max=1e6),
    )
    bo = top.section("body", required=False)
    bd = BodyParams()
    body = BodyParams(mass_kg=bo.number("mass_kg", bd.mass_kg, positive=True, max=MASS_MAX_KG),
                      payload_kg=bo.number("payload_kg", bd.payload_kg, nonneg=True, max=MASS_MAX_KG),
                      load_enabled=bo.boolean("load_enabled", bd.load_enabled))
    gains_sec = top.section("paper_spec_gains", required=False)
    table = table_for(REFERENCE_MODEL)
    gains = {}
    for k in gains_sec.keys():
        if str(k) not in table or not str(k).endswith("_gain"):
            gains_sec.fail(f"not a gain register of {table.model}", k)
        lo, hi = table[str(k)].raw_bounds()
        gains[str(k)] = gains_sec.integer(k, min=lo, max=hi)
    cfg = PhysicsConfig(
        rate_hz=rate,
        supply_voltage_v=phys.number("supply_voltage_v", positive=True, max=SUPPLY_MAX_V),
        drive_motor=_motor(motors.section("drive")),
        steering_motor=_motor(motors.section("steering")),
        gear_ratios=gear_ratios, firmware=firmware, sensors=sensors, thermal=thermal,
        body=body, paper_spec_gains=gains, **_realism_sections(top))
    for sec in (top, phys, motors, fw, bes, sen, th, bo):
        sec.check_unknown()
    return cfg


def _friction(sec: Section) -> GearFrictionParams:
    d = GearFrictionParams()
    f = GearFrictionParams(
        coulomb_nm=sec.number("coulomb_nm", d.coulomb_nm, nonneg=True, max=MOTOR_VALUE_MAX),
        static_nm=sec.number("static_nm", d.static_nm, nonneg=True, max=MOTOR_VALUE_MAX),
        stribeck_speed_radps=sec.number("stribeck_speed_radps", d.stribeck_speed_radps, positive=True,
                                        max=MOTOR_VALUE_MAX),
        viscous_nm_s_per_rad=sec.number("viscous_nm_s_per_rad", d.viscous_nm_s_per_rad, nonneg=True,
                                        max=MOTOR_VALUE_MAX))
    if f.static_nm and f.static_nm < f.coulomb_nm:
        sec.fail(f"must be >= coulomb_nm ({f.coulomb_nm:g}), got {f.static_nm:g}", "static_nm")
    sec.check_unknown()
    return f


def _realism_sections(top: Section) -> dict[str, Any]:
    """The optional sections that make the world disagree with the controller's model
    (``gearbox_friction``, ``supply``, ``contact``, ``tolerances``, ``protection``)."""
    gf = top.section("gearbox_friction", required=False)
    sup = top.section("supply", required=False)
    con = top.section("contact", required=False)
    tol = top.section("tolerances", required=False)
    pro = top.section("protection", required=False)
    cd, pd = ContactParams(), ProtectionParams()
    out = dict(
        drive_friction=_friction(gf.section("drive", required=False)),
        steering_friction=_friction(gf.section("steering", required=False)),
        supply=SupplyParams(
            internal_resistance_ohm=sup.number("internal_resistance_ohm", 0.0, nonneg=True, max=1e3),
            idle_current_a=sup.number("idle_current_a", 0.0, nonneg=True, max=1e3)),
        contact=ContactParams(
            enabled=con.boolean("enabled", cd.enabled),
            friction_coefficient=con.number("friction_coefficient", cd.friction_coefficient, positive=True,
                                            max=10.0),
            slip_stiffness_n_s_per_m=con.number("slip_stiffness_n_s_per_m", cd.slip_stiffness_n_s_per_m,
                                                positive=True, max=1e9),
            lateral_stiffness_ratio=con.number("lateral_stiffness_ratio", cd.lateral_stiffness_ratio,
                                               positive=True, max=1e3),
            yaw_inertia_kg_m2=con.number("yaw_inertia_kg_m2", cd.yaw_inertia_kg_m2, nonneg=True, max=1e3),
            gravity_mps2=con.number("gravity_mps2", cd.gravity_mps2, positive=True, max=100.0)),
        tolerances=ToleranceParams(
            wheel_radius_scale=tol.numbers("wheel_radius_scale", 4, None, min=0.5, max=2.0) or (),
            steer_zero_offset_rad=tol.numbers("steer_zero_offset_rad", 4, None, min=-0.5, max=0.5) or (),
            steer_backlash_rad=tol.number("steer_backlash_rad", 0.0, nonneg=True, max=0.5),
            encoder_offset_pulse=tol.numbers("encoder_offset_pulse", 4, None, min=-PULSE_MAX, max=PULSE_MAX) or ()),
        protection=ProtectionParams(
            enabled=pro.boolean("enabled", pd.enabled),
            overload_current_a=pro.number("overload_current_a", pd.overload_current_a, positive=True, max=1e3),
            overload_time_s=pro.number("overload_time_s", pd.overload_time_s, positive=True, max=1e6)),
    )
    for sec in (gf, sup, con, tol, pro):
        sec.check_unknown()
    return out


def load_config(path: str | Path = DEFAULT_PATH) -> PhysicsConfig:
    """Read and validate an emulator config (default: the shipped ``emulator.yaml``).

    Raises
    ------
    ConfigError
        If the file is missing, binary, not YAML, or has a malformed key (``FILE:LINE: KEY: problem``).
    """
    return parse_config(read_yaml(path, what="emulator config"))
