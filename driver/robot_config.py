"""Load and validate ``configs/robot.yaml`` into frozen dataclasses.

The file is read by :mod:`swerve.configs.loader`; every malformed input raises
:class:`ConfigError` with the file, line and key path (e.g.
``robot.yaml:31: wheels[2].drive_id: duplicate servo ID 3 (also wheels[0].drive_id)``); keys no
parser reads give a :class:`~swerve.configs.loader.ConfigWarning`. Units are SI unless a key says
otherwise (``center_pulse`` is raw Present Position).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

from swerve.configs.loader import Bound, Document, Section, document, read_yaml
from swerve.driver.adapter_latency import ADAPTER_LATENCY_MAX_MS, ADAPTER_LATENCY_MIN_MS
from swerve.driver.control_table import (BAUD_RATES_BPS, CONFIG_DIR, POSITION_MODES, REFERENCE_MODEL,
                                         ControlTable, OperatingMode, Reg, table_for)
from swerve.driver.errors import SwerveError

DEFAULT_PATH = CONFIG_DIR / "robot.yaml"
_REF = table_for(REFERENCE_MODEL)
#: Largest Bus Watchdog the item (98) holds: 127 units of 20 ms, s.
BUS_WATCHDOG_MAX_S = _REF[Reg.BUS_WATCHDOG].to_si(_REF[Reg.BUS_WATCHDOG].max)
#: Largest Return Delay Time (9): 254 units of 2 us, us.
RETURN_DELAY_MAX_US = _REF[Reg.RETURN_DELAY_TIME].to_si(_REF[Reg.RETURN_DELAY_TIME].max) * 1e6
#: ``operating_mode:`` names in the file -> Operating Mode (11) values.
MODE_NAMES = {m.name.lower(): m for m in OperatingMode}
#: Plausibility bounds of the geometry and speed keys (a larger value is a typo or wrong unit).
OFFSET_MAX_M = 5.0
WHEEL_RADIUS_MAX_M = 1.0
SPEED_MAX_MPS = 10.0
#: Smallest wheel offset from the centroid and smallest wheel, m: a wheel module is larger than this.
OFFSET_MIN_M = 0.02
WHEEL_RADIUS_MIN_M = 0.005
#: Smallest wheel speed cap, m/s (a cap below 1 mm/s is a typo or a wrong unit).
SPEED_MIN_MPS = 0.001
#: Smallest steering-angle limit, rad (about half a degree).
STEER_ANGLE_MIN_RAD = 0.01
#: Most consecutive reply timeouts a run tolerates before it stops (at the paper's 62.5 Hz,
#: 100 cycles are 1.6 s of driving blind).
TIMEOUTS_MAX = 100


def robot_bounds(table: ControlTable) -> dict[str, Bound]:
    """The accepted range of every number in the robot file, for servos of ``table``'s model.

    Keys are dotted paths with ``[]`` for any list item and ``*`` for any gain register. Ranges
    that come from the servo are read from the model's control table (e-Manual,
    https://emanual.robotis.com/docs/en/dxl/x/xh430-w210/#control-table): IDs, Return Delay Time,
    Bus Watchdog, Velocity Limit, profiles and gains. configs/README.md lists them for the shipped
    model; ``tests/configs/test_robot_bounds.py`` keeps the two equal.
    """
    def reg(name, unit="", why="", si=False, lo_raw=None):
        r = table[name]
        lo, hi = r.raw_bounds()
        lo = lo if lo_raw is None else lo_raw
        if si:
            return Bound(r.to_si(lo), r.to_si(hi), unit, why)
        return Bound(lo, hi, unit, why, integer=True)

    rdt = table[Reg.RETURN_DELAY_TIME]
    rdt_step_us = rdt.to_si(1) * 1e6
    velocity = reg(Reg.VELOCITY_LIMIT, "rad/s", "Velocity Limit (44): one unit to its largest value",
                   si=True, lo_raw=1)
    offset = Bound(-OFFSET_MAX_M, OFFSET_MAX_M, "m", "wheel position on the body")
    ids = reg(Reg.ID, why="ID (7): 0-252 (253 and 254 are reserved for the bus)")
    sign = Bound(-1, 1, why="+1 or -1: which way the servo is mounted", integer=True, allowed=(1, -1))
    bounds = {
        "geometry.a_m": Bound(OFFSET_MIN_M, OFFSET_MAX_M, "m", "half wheelbase"),
        "geometry.b_m": Bound(OFFSET_MIN_M, OFFSET_MAX_M, "m", "half track"),
        "geometry.wheel_radius_m": Bound(WHEEL_RADIUS_MIN_M, WHEEL_RADIUS_MAX_M, "m", "wheel radius"),
        "limits.v1_max_mps": Bound(SPEED_MIN_MPS, SPEED_MAX_MPS, "m/s",
                                   "wheel ground speed cap; also v1_max_mps / wheel_radius_m must be "
                                   "within the drive servo's Velocity Limit (44)"),
        "limits.steer_rate_max_radps": velocity,
        "limits.steer_angle_max_rad": Bound(STEER_ANGLE_MIN_RAD, math.pi, "rad", "half a turn at most"),
        "link.baud": Bound(min(BAUD_RATES_BPS), max(BAUD_RATES_BPS), "bps", "Baud Rate (8) values",
                           integer=True, allowed=tuple(BAUD_RATES_BPS)),
        "link.return_delay_us": Bound(0.0, rdt.to_si(rdt.raw_bounds()[1]) * 1e6, "us",
                                      "Return Delay Time (9), 2 us units", step=rdt_step_us),
        "link.protocol": Bound(2.0, 2.0, why="Protocol 2.0 only", allowed=(2.0,)),
        "link.adapter_latency_ms": Bound(ADAPTER_LATENCY_MIN_MS, ADAPTER_LATENCY_MAX_MS, "ms",
                                         "USB adapter latency timer, whole ms; absent: no adapter",
                                         integer=True),
        "wheels[].x_m": offset,
        "wheels[].y_m": offset,
        "wheels[].drive_id": ids,
        "wheels[].steer_id": ids,
        "drive.direction[]": sign,
        "steering.direction[]": sign,
        "steering.center_pulse[]": Bound(0, table.pulses_per_rev - 1, "pulse",
                                         "Present Position over one turn", integer=True),
        "safety.bus_watchdog_s": reg(Reg.BUS_WATCHDOG, "s", "Bus Watchdog (98), 20 ms units; 0: off",
                                     si=True),
        "safety.max_consecutive_timeouts": Bound(1, TIMEOUTS_MAX, why="reply timeouts in a row before "
                                                 "a run stops", integer=True),
    }
    for group in ("drive", "steering"):
        for key in ("profile_velocity", "profile_acceleration"):
            bounds[f"{group}.{key}"] = reg(key, "raw", f"{table[key].name} item, raw units")
        gains = [table[n].raw_bounds() for n in table.registers if n.endswith("_gain")]
        bounds[f"{group}.gains.*"] = Bound(min(lo for lo, _ in gains), max(hi for _, hi in gains), "raw",
                                           "gain items (P, I, D of velocity and position), each "
                                           "within its own control-table range", integer=True)
    return bounds


@dataclass(frozen=True)
class LinkConfig:
    """Serial link: ``port`` URL, ``baud`` bps, servo ``return_delay_us``, and the USB-serial
    adapter's latency timer ``adapter_latency_ms`` (``None``: no USB adapter between the host and
    the cable, e.g. a UART on the host's board)."""

    port: str
    baud: int
    return_delay_us: float
    protocol: float = 2.0
    adapter_latency_ms: int | None = None


@dataclass(frozen=True)
class WheelConfig:
    """One wheel module: position on the body (m), servo IDs, signs and steering zero."""

    name: str
    x_m: float
    y_m: float
    drive_id: int
    steer_id: int
    axle: str
    drive_direction: int
    steer_direction: int
    center_pulse: int


@dataclass(frozen=True)
class ServoGroupConfig:
    """Settings shared by the four drive (or steering) servos."""

    operating_mode: int
    gains: Mapping[str, int]
    profile_velocity: int | None
    profile_acceleration: int | None


@dataclass(frozen=True)
class RobotConfig:
    """The whole robot file, validated."""

    name: str
    a_m: float
    b_m: float
    wheel_radius_m: float
    v1_max_mps: float
    steer_rate_max_radps: float
    steer_angle_max_rad: float
    link: LinkConfig
    model: str
    wheels: tuple[WheelConfig, ...]
    drive: ServoGroupConfig
    steering: ServoGroupConfig
    bus_watchdog_s: float
    max_consecutive_timeouts: int
    source: str = ""

    @property
    def table(self) -> ControlTable:
        return table_for(self.model)

    @property
    def drive_ids(self) -> tuple[int, ...]:
        return tuple(w.drive_id for w in self.wheels)

    @property
    def steer_ids(self) -> tuple[int, ...]:
        return tuple(w.steer_id for w in self.wheels)

    @property
    def drive_max_radps(self) -> float:
        """Wheel speed cap from ``limits.v1_max_mps`` / ``wheel_radius_m``, rad/s."""
        return self.v1_max_mps / self.wheel_radius_m


def _group(sec: Section, table: ControlTable, bounds: Mapping[str, Bound]) -> ServoGroupConfig:
    group = sec.key()
    mode = sec.choice("operating_mode", MODE_NAMES)
    gsec = sec.section("gains")
    gains = {}
    for name in gsec.keys():
        if str(name) not in table or not str(name).endswith("_gain"):
            gsec.fail(f"not a gain register of {table.model}", name)
        lo, hi = table[str(name)].raw_bounds()
        gains[str(name)] = gsec.bounded(name, Bound(lo, hi, "raw", integer=True))
    prof = {key: sec.bounded(key, bounds[f"{group}.{key}"], None)
            for key in ("profile_velocity", "profile_acceleration")}
    return ServoGroupConfig(int(mode), MappingProxyType(gains), **prof)


def parse_robot_config(data: Any, where: str = "robot config") -> RobotConfig:
    """Validate a robot document: a :class:`~swerve.configs.loader.Document` (errors then carry
    line numbers) or already-parsed YAML data named ``where`` in errors.

    Every number is checked against :func:`robot_bounds` of the file's servo model.
    """
    doc = data if isinstance(data, Document) else document(data, where)
    top = doc.root()
    geo, lim, link, safety = (top.section(k) for k in ("geometry", "limits", "link", "safety"))
    model = top.string("model")
    try:
        table = table_for(model)
    except SwerveError as exc:
        top.fail(str(exc), "model")
    bounds = robot_bounds(table)
    port = link.string("port")
    baud = link.bounded("baud", bounds["link.baud"])
    rdt = link.bounded("return_delay_us", bounds["link.return_delay_us"])
    protocol = link.bounded("protocol", bounds["link.protocol"], 2.0)
    adapter_ms = link.bounded("adapter_latency_ms", bounds["link.adapter_latency_ms"], None)
    wheels_in = top.items("wheels", 4)
    drive, steering = top.section("drive"), top.section("steering")
    ddir = drive.bounded_list("direction", 4, bounds["drive.direction[]"])
    sdir = steering.bounded_list("direction", 4, bounds["steering.direction[]"])
    centers = steering.bounded_list("center_pulse", 4, bounds["steering.center_pulse[]"])
    wheels, seen = [], {}
    for k, w in enumerate(wheels_in):
        ids = {}
        for key in ("drive_id", "steer_id"):
            ids[key] = w.bounded(key, bounds[f"wheels[].{key}"])
            if ids[key] in seen:
                w.fail(f"duplicate servo ID {ids[key]} (also {seen[ids[key]]})", key)
            seen[ids[key]] = w.key(key)
        wheels.append(WheelConfig(
            name=w.string("name"), x_m=w.bounded("x_m", bounds["wheels[].x_m"]),
            y_m=w.bounded("y_m", bounds["wheels[].y_m"]),
            drive_id=ids["drive_id"], steer_id=ids["steer_id"], axle=w.string("axle", "", nonempty=False),
            drive_direction=ddir[k], steer_direction=sdir[k], center_pulse=centers[k]))
        w.check_unknown()
    dgroup = _group(drive, table, bounds)
    sgroup = _group(steering, table, bounds)
    if dgroup.operating_mode != OperatingMode.VELOCITY:
        drive.fail("drive servos must be in velocity mode", "operating_mode")
    if sgroup.operating_mode not in POSITION_MODES:
        steering.fail("steering servos must be in a position mode", "operating_mode")
    cfg = RobotConfig(
        name=top.string("name", "", nonempty=False),
        a_m=geo.bounded("a_m", bounds["geometry.a_m"]),
        b_m=geo.bounded("b_m", bounds["geometry.b_m"]),
        wheel_radius_m=geo.bounded("wheel_radius_m", bounds["geometry.wheel_radius_m"]),
        v1_max_mps=lim.bounded("v1_max_mps", bounds["limits.v1_max_mps"]),
        steer_rate_max_radps=lim.bounded("steer_rate_max_radps", bounds["limits.steer_rate_max_radps"]),
        steer_angle_max_rad=lim.bounded("steer_angle_max_rad", bounds["limits.steer_angle_max_rad"]),
        link=LinkConfig(port, baud, rdt, protocol, adapter_ms),
        model=table.model, wheels=tuple(wheels), drive=dgroup, steering=sgroup,
        bus_watchdog_s=safety.bounded("bus_watchdog_s", bounds["safety.bus_watchdog_s"]),
        max_consecutive_timeouts=safety.bounded("max_consecutive_timeouts",
                                                bounds["safety.max_consecutive_timeouts"], 3),
        source=doc.file)
    wheel_max = bounds["limits.steer_rate_max_radps"].hi
    if cfg.drive_max_radps > wheel_max:
        lim.fail(f"{cfg.v1_max_mps:g} m/s on a {cfg.wheel_radius_m:g} m wheel is {cfg.drive_max_radps:.4g} "
                 f"rad/s, above the drive servo's Velocity Limit {wheel_max:.4g} rad/s", "v1_max_mps")
    for sec in (top, geo, lim, link, safety, drive, steering):
        sec.check_unknown()
    return cfg


def load_robot_config(path: str | Path = DEFAULT_PATH) -> RobotConfig:
    """Read and validate a robot YAML file (default: the shipped ``robot.yaml``).

    Raises :class:`ConfigError` ``FILE:LINE: KEY: problem`` on anything malformed.
    """
    return parse_robot_config(read_yaml(path, what="robot config"))
