"""Load and validate ``configs/robot.yaml`` into frozen dataclasses.

Every malformed input raises :class:`ConfigError` naming the file and the key path
(e.g. ``robot.yaml: wheels[2].drive_id: duplicate ID 3``). Units are SI unless a key says
otherwise (``center_pulse`` is raw Present Position).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Mapping

import yaml

from swerve.driver.control_table import CONFIG_DIR, ControlTable, table_for
from swerve.driver.errors import ConfigError, SwerveError

DEFAULT_PATH = CONFIG_DIR / "robot.yaml"
#: Largest Bus Watchdog the item (98) holds: 127 units of 20 ms, s.
BUS_WATCHDOG_MAX_S = 2.54

#: Serial rates the X series can be set to (Baud Rate item 8).
SERVO_BAUDS = (9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000, 4_500_000)
_MODES = {"velocity": 1, "position": 3, "extended_position": 4, "current_based_position": 5}


@dataclass(frozen=True)
class LinkConfig:
    """Serial link: ``port`` URL, ``baud`` bps, servo ``return_delay_us``."""

    port: str
    baud: int
    return_delay_us: float
    protocol: float = 2.0


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


class _Doc:
    """Typed access to a nested YAML mapping with key paths in every error."""

    def __init__(self, where: str):
        self.where = where

    def fail(self, key: str, msg: str):
        raise ConfigError(f"{self.where}: {key}: {msg}")

    def get(self, d: Any, key: str, path: str) -> Any:
        if not isinstance(d, Mapping):
            self.fail(path or "(top level)", f"expected a mapping, got {type(d).__name__}")
        if key not in d:
            self.fail(f"{path}.{key}" if path else key, "missing")
        return d[key]

    def num(self, d, key, path, *, positive=False, nonneg=False) -> float:
        v = self.get(d, key, path)
        full = f"{path}.{key}" if path else key
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(full, f"expected a number, got {v!r}")
        if positive and v <= 0:
            self.fail(full, f"must be > 0, got {v}")
        if nonneg and v < 0:
            self.fail(full, f"must be >= 0, got {v}")
        return float(v)

    def int_(self, d, key, path, lo=None, hi=None) -> int:
        v = self.get(d, key, path)
        full = f"{path}.{key}" if path else key
        if isinstance(v, bool) or not isinstance(v, int):
            self.fail(full, f"expected an integer, got {v!r}")
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            self.fail(full, f"{v} is outside [{lo}, {hi}]")
        return v

    def signs(self, d, key, path) -> tuple[int, ...]:
        v = self.get(d, key, path)
        if not isinstance(v, list) or len(v) != 4 or any(s not in (1, -1) or isinstance(s, bool) for s in v):
            self.fail(f"{path}.{key}", f"expected a list of four +1/-1 values, got {v!r}")
        return tuple(v)


def _group(doc: _Doc, d: Any, path: str, table: ControlTable) -> ServoGroupConfig:
    mode = doc.get(d, "operating_mode", path)
    if mode not in _MODES:
        doc.fail(f"{path}.operating_mode", f"unknown mode {mode!r}; expected one of {sorted(_MODES)}")
    gains_in = doc.get(d, "gains", path)
    if not isinstance(gains_in, Mapping):
        doc.fail(f"{path}.gains", "expected a mapping of gain register names to raw values")
    gains = {}
    for name, raw in gains_in.items():
        if str(name) not in table or not str(name).endswith("_gain"):
            doc.fail(f"{path}.gains.{name}", f"not a gain register of {table.model}")
        gains[str(name)] = doc.int_(gains_in, name, f"{path}.gains", *table[str(name)].raw_bounds())
    prof = {}
    for key in ("profile_velocity", "profile_acceleration"):
        prof[key] = (doc.int_(d, key, path, *table[key].raw_bounds())
                     if isinstance(d, Mapping) and key in d else None)
    return ServoGroupConfig(_MODES[mode], MappingProxyType(gains), **prof)


def parse_robot_config(data: Any, where: str = "robot config") -> RobotConfig:
    """Validate an already-parsed YAML document (see :func:`load_robot_config`)."""
    doc = _Doc(where)
    if not isinstance(data, Mapping):
        doc.fail("(top level)", "expected a mapping")
    geo = doc.get(data, "geometry", "")
    lim = doc.get(data, "limits", "")
    link = doc.get(data, "link", "")
    port = doc.get(link, "port", "link")
    if not isinstance(port, str) or not port:
        doc.fail("link.port", f"expected a port path or URL, got {port!r}")
    baud = doc.int_(link, "baud", "link")
    if baud not in SERVO_BAUDS:
        doc.fail("link.baud", f"{baud} is not a Dynamixel X baud rate {SERVO_BAUDS}")
    rdt = doc.num(link, "return_delay_us", "link", nonneg=True)
    if rdt > 508 or rdt % 2:
        doc.fail("link.return_delay_us", f"{rdt} us is not a multiple of 2 us in [0, 508]")
    model = doc.get(data, "model", "")
    try:
        table = table_for(str(model))
    except SwerveError as exc:
        doc.fail("model", str(exc))
    wheels_in = doc.get(data, "wheels", "")
    if not isinstance(wheels_in, list) or len(wheels_in) != 4:
        doc.fail("wheels", "expected a list of exactly four wheels")
    drive = doc.get(data, "drive", "")
    steering = doc.get(data, "steering", "")
    ddir = doc.signs(drive, "direction", "drive")
    sdir = doc.signs(steering, "direction", "steering")
    centers = doc.get(steering, "center_pulse", "steering")
    if not isinstance(centers, list) or len(centers) != 4:
        doc.fail("steering.center_pulse", f"expected four raw positions, got {centers!r}")
    wheels, seen = [], {}
    for k, w in enumerate(wheels_in):
        path = f"wheels[{k}]"
        name = doc.get(w, "name", path)
        ids = {}
        for key in ("drive_id", "steer_id"):
            ids[key] = doc.int_(w, key, path, 0, 252)
            if ids[key] in seen:
                doc.fail(f"{path}.{key}", f"duplicate servo ID {ids[key]} (also {seen[ids[key]]})")
            seen[ids[key]] = f"{path}.{key}"
        center = centers[k]
        if isinstance(center, bool) or not isinstance(center, int):
            doc.fail(f"steering.center_pulse[{k}]", f"expected an integer, got {center!r}")
        if not 0 <= center <= 4095:
            doc.fail(f"steering.center_pulse[{k}]", f"{center} is outside [0, 4095]")
        wheels.append(WheelConfig(
            name=str(name), x_m=doc.num(w, "x_m", path), y_m=doc.num(w, "y_m", path),
            drive_id=ids["drive_id"], steer_id=ids["steer_id"], axle=str(w.get("axle", "")),
            drive_direction=ddir[k], steer_direction=sdir[k], center_pulse=center))
    dgroup = _group(doc, drive, "drive", table)
    sgroup = _group(doc, steering, "steering", table)
    if dgroup.operating_mode != 1:
        doc.fail("drive.operating_mode", "drive servos must be in velocity mode")
    if sgroup.operating_mode not in (3, 4, 5):
        doc.fail("steering.operating_mode", "steering servos must be in a position mode")
    safety = doc.get(data, "safety", "")
    wd = doc.num(safety, "bus_watchdog_s", "safety", nonneg=True)
    if wd > BUS_WATCHDOG_MAX_S + 1e-9:
        doc.fail("safety.bus_watchdog_s", f"{wd} s exceeds the Bus Watchdog maximum {BUS_WATCHDOG_MAX_S} s")
    return RobotConfig(
        name=str(data.get("name", "")),
        a_m=doc.num(geo, "a_m", "geometry", positive=True),
        b_m=doc.num(geo, "b_m", "geometry", positive=True),
        wheel_radius_m=doc.num(geo, "wheel_radius_m", "geometry", positive=True),
        v1_max_mps=doc.num(lim, "v1_max_mps", "limits", positive=True),
        steer_rate_max_radps=doc.num(lim, "steer_rate_max_radps", "limits", positive=True),
        steer_angle_max_rad=doc.num(lim, "steer_angle_max_rad", "limits", positive=True),
        link=LinkConfig(port, baud, rdt, float(link.get("protocol", 2.0))),
        model=table.model, wheels=tuple(wheels), drive=dgroup, steering=sgroup,
        bus_watchdog_s=wd,
        max_consecutive_timeouts=doc.int_(safety, "max_consecutive_timeouts", "safety", 1, None)
        if "max_consecutive_timeouts" in safety else 3,
        source=where)


def load_robot_config(path: str | Path = DEFAULT_PATH) -> RobotConfig:
    """Read and validate a robot YAML file (default ``configs/robot.yaml``)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"cannot read robot config {path}: {exc.strerror}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: not valid YAML: {exc}") from None
    return parse_robot_config(data, str(path))
