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

from swerve.configs.loader import Document, Section, document, read_yaml
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
#: Range of an FTDI USB-serial adapter's latency timer (``link.adapter_latency_ms``), ms: whole
#: ms in 1..255 (FTDI AN232B-04 §3.3; Linux commit db9240662a44, which also notes the chip runs
#: the invalid 0 as 1 ms).
ADAPTER_LATENCY_MIN_MS = 1
ADAPTER_LATENCY_MAX_MS = 255


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


def _group(sec: Section, table: ControlTable) -> ServoGroupConfig:
    mode = sec.choice("operating_mode", MODE_NAMES)
    gsec = sec.section("gains")
    gains = {}
    for name in gsec.keys():
        if str(name) not in table or not str(name).endswith("_gain"):
            gsec.fail(f"not a gain register of {table.model}", name)
        lo, hi = table[str(name)].raw_bounds()
        gains[str(name)] = gsec.integer(name, min=lo, max=hi)
    prof = {}
    for key in ("profile_velocity", "profile_acceleration"):
        lo, hi = table[key].raw_bounds()
        prof[key] = sec.integer(key, None, min=lo, max=hi)
    return ServoGroupConfig(int(mode), MappingProxyType(gains), **prof)


def parse_robot_config(data: Any, where: str = "robot config") -> RobotConfig:
    """Validate a robot document: a :class:`~swerve.configs.loader.Document` (errors then carry
    line numbers) or already-parsed YAML data named ``where`` in errors."""
    doc = data if isinstance(data, Document) else document(data, where)
    top = doc.root()
    geo, lim, link, safety = (top.section(k) for k in ("geometry", "limits", "link", "safety"))
    port = link.string("port")
    baud = link.integer("baud")
    if baud not in BAUD_RATES_BPS:
        link.fail(f"{baud} is not a Dynamixel X baud rate {BAUD_RATES_BPS}", "baud")
    rdt = link.number("return_delay_us", nonneg=True, max=RETURN_DELAY_MAX_US)
    if rdt % 2:
        link.fail(f"{rdt:g} us is not a multiple of 2 us in [0, {RETURN_DELAY_MAX_US:g}]", "return_delay_us")
    protocol = link.number("protocol", 2.0)
    if protocol != 2.0:
        link.fail(f"only Protocol 2.0 is supported, got {protocol:g}", "protocol")
    adapter_ms = link.integer("adapter_latency_ms", None, min=ADAPTER_LATENCY_MIN_MS, max=ADAPTER_LATENCY_MAX_MS)
    model = top.string("model")
    try:
        table = table_for(model)
    except SwerveError as exc:
        top.fail(str(exc), "model")
    wheels_in = top.items("wheels", 4)
    drive, steering = top.section("drive"), top.section("steering")
    ddir = drive.integers("direction", 4, allowed=(1, -1))
    sdir = steering.integers("direction", 4, allowed=(1, -1))
    centers = steering.integers("center_pulse", 4, min=0, max=table.pulses_per_rev - 1)
    wheels, seen = [], {}
    for k, w in enumerate(wheels_in):
        ids = {}
        for key in ("drive_id", "steer_id"):
            ids[key] = w.integer(key, min=0, max=table[Reg.ID].max)
            if ids[key] in seen:
                w.fail(f"duplicate servo ID {ids[key]} (also {seen[ids[key]]})", key)
            seen[ids[key]] = w.key(key)
        wheels.append(WheelConfig(
            name=w.string("name"), x_m=w.number("x_m", min=-OFFSET_MAX_M, max=OFFSET_MAX_M),
            y_m=w.number("y_m", min=-OFFSET_MAX_M, max=OFFSET_MAX_M),
            drive_id=ids["drive_id"], steer_id=ids["steer_id"], axle=w.string("axle", "", nonempty=False),
            drive_direction=ddir[k], steer_direction=sdir[k], center_pulse=centers[k]))
        w.check_unknown()
    dgroup = _group(drive, table)
    sgroup = _group(steering, table)
    if dgroup.operating_mode != OperatingMode.VELOCITY:
        drive.fail("drive servos must be in velocity mode", "operating_mode")
    if sgroup.operating_mode not in POSITION_MODES:
        steering.fail("steering servos must be in a position mode", "operating_mode")
    wd = safety.number("bus_watchdog_s", nonneg=True, max=BUS_WATCHDOG_MAX_S + 1e-9)
    cfg = RobotConfig(
        name=top.string("name", "", nonempty=False),
        a_m=geo.number("a_m", positive=True, max=OFFSET_MAX_M),
        b_m=geo.number("b_m", positive=True, max=OFFSET_MAX_M),
        wheel_radius_m=geo.number("wheel_radius_m", positive=True, max=WHEEL_RADIUS_MAX_M),
        v1_max_mps=lim.number("v1_max_mps", positive=True, max=SPEED_MAX_MPS),
        steer_rate_max_radps=lim.number("steer_rate_max_radps", positive=True,
                                        max=table[Reg.VELOCITY_LIMIT].to_si(table[Reg.VELOCITY_LIMIT].max)),
        steer_angle_max_rad=lim.number("steer_angle_max_rad", positive=True, max=math.pi),
        link=LinkConfig(port, baud, rdt, protocol, adapter_ms),
        model=table.model, wheels=tuple(wheels), drive=dgroup, steering=sgroup,
        bus_watchdog_s=wd,
        max_consecutive_timeouts=safety.integer("max_consecutive_timeouts", 3, min=1),
        source=doc.file)
    for sec in (top, geo, lim, link, safety, drive, steering):
        sec.check_unknown()
    return cfg


def load_robot_config(path: str | Path = DEFAULT_PATH) -> RobotConfig:
    """Read and validate a robot YAML file (default: the shipped ``robot.yaml``).

    Raises :class:`ConfigError` ``FILE:LINE: KEY: problem`` on anything malformed.
    """
    return parse_robot_config(read_yaml(path, what="robot config"))
