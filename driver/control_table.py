"""X-series control tables, loaded from data files in ``configs/models/`` (one per model).

The driver and the emulator's memory map load the same files (through
:mod:`swerve.configs.loader`, so a malformed entry is reported as ``FILE:LINE: KEY: problem``).
X-series constants are read from them here once: :data:`BAUD_RATES_BPS`, :data:`ID_MAX`, and
the SI scales used by the emulator's physics. Registers are named by the
:class:`Reg` enum (typos fail at import, not on the wire); raw <-> SI conversion happens here
once, and raises :class:`~driver.errors.OutOfRangeError` instead of clamping.
"""
from __future__ import annotations

import dataclasses
import functools
import math
import threading
from dataclasses import dataclass, field
from enum import IntEnum, StrEnum
from pathlib import Path

from swerve.configs import shipped_dir
from swerve.configs.loader import Section, read_yaml
from swerve.driver.errors import ConfigError, OutOfRangeError, RegisterError

CONFIG_DIR = shipped_dir()
MODELS_DIR = CONFIG_DIR / "models"


class Reg(StrEnum):
    """Control-table item names (snake_case of the e-Manual names)."""

    MODEL_NUMBER = "model_number"
    MODEL_INFORMATION = "model_information"
    FIRMWARE_VERSION = "firmware_version"
    ID = "id"
    BAUD_RATE = "baud_rate"
    RETURN_DELAY_TIME = "return_delay_time"
    DRIVE_MODE = "drive_mode"
    OPERATING_MODE = "operating_mode"
    SECONDARY_ID = "secondary_id"
    PROTOCOL_TYPE = "protocol_type"
    HOMING_OFFSET = "homing_offset"
    MOVING_THRESHOLD = "moving_threshold"
    TEMPERATURE_LIMIT = "temperature_limit"
    MAX_VOLTAGE_LIMIT = "max_voltage_limit"
    MIN_VOLTAGE_LIMIT = "min_voltage_limit"
    PWM_LIMIT = "pwm_limit"
    CURRENT_LIMIT = "current_limit"
    VELOCITY_LIMIT = "velocity_limit"
    MAX_POSITION_LIMIT = "max_position_limit"
    MIN_POSITION_LIMIT = "min_position_limit"
    EXTERNAL_PORT_MODE_1 = "external_port_mode_1"
    EXTERNAL_PORT_MODE_2 = "external_port_mode_2"
    EXTERNAL_PORT_MODE_3 = "external_port_mode_3"
    STARTUP_CONFIGURATION = "startup_configuration"
    PWM_SLOPE = "pwm_slope"
    SHUTDOWN = "shutdown"
    TORQUE_ENABLE = "torque_enable"
    LED = "led"
    STATUS_RETURN_LEVEL = "status_return_level"
    REGISTERED_INSTRUCTION = "registered_instruction"
    HARDWARE_ERROR_STATUS = "hardware_error_status"
    VELOCITY_I_GAIN = "velocity_i_gain"
    VELOCITY_P_GAIN = "velocity_p_gain"
    POSITION_D_GAIN = "position_d_gain"
    POSITION_I_GAIN = "position_i_gain"
    POSITION_P_GAIN = "position_p_gain"
    FEEDFORWARD_2ND_GAIN = "feedforward_2nd_gain"
    FEEDFORWARD_1ST_GAIN = "feedforward_1st_gain"
    BUS_WATCHDOG = "bus_watchdog"
    GOAL_PWM = "goal_pwm"
    GOAL_CURRENT = "goal_current"
    GOAL_VELOCITY = "goal_velocity"
    PROFILE_ACCELERATION = "profile_acceleration"
    PROFILE_VELOCITY = "profile_velocity"
    GOAL_POSITION = "goal_position"
    REALTIME_TICK = "realtime_tick"
    MOVING = "moving"
    MOVING_STATUS = "moving_status"
    PRESENT_PWM = "present_pwm"
    PRESENT_CURRENT = "present_current"
    PRESENT_LOAD = "present_load"
    PRESENT_VELOCITY = "present_velocity"
    PRESENT_POSITION = "present_position"
    VELOCITY_TRAJECTORY = "velocity_trajectory"
    POSITION_TRAJECTORY = "position_trajectory"
    PRESENT_INPUT_VOLTAGE = "present_input_voltage"
    PRESENT_TEMPERATURE = "present_temperature"
    BACKUP_READY = "backup_ready"
    EXTERNAL_PORT_DATA_1 = "external_port_data_1"
    EXTERNAL_PORT_DATA_2 = "external_port_data_2"
    EXTERNAL_PORT_DATA_3 = "external_port_data_3"


class OperatingMode(IntEnum):
    """Values of Operating Mode (11), e-Manual "Operating Mode(11)".

    ``robot.yaml`` names them in lower case (``operating_mode: velocity``).
    """

    CURRENT = 0
    VELOCITY = 1
    POSITION = 3
    EXTENDED_POSITION = 4
    CURRENT_BASED_POSITION = 5
    PWM = 16


#: The modes in which Goal Position (116) drives the servo.
POSITION_MODES = (OperatingMode.POSITION, OperatingMode.EXTENDED_POSITION,
                  OperatingMode.CURRENT_BASED_POSITION)


class HardwareError:
    """Bits of Hardware Error Status (70) and Shutdown (63)."""

    INPUT_VOLTAGE = 0x01
    OVERHEATING = 0x04
    MOTOR_ENCODER = 0x08
    ELECTRICAL_SHOCK = 0x10
    OVERLOAD = 0x20
    #: Each bit's name and what it means (e-Manual, X series, "Hardware Error Status(70)").
    BITS = {0x01: ("input voltage", "the supply is outside Min/Max Voltage Limit"),
            0x04: ("overheating", "the internal temperature exceeded Temperature Limit"),
            0x08: ("motor encoder", "the encoder malfunctioned"),
            0x10: ("electrical shock", "an electrical shock on the circuit, or too little power to drive "
                                       "the motor"),
            0x20: ("overload", "a persistent load beyond the servo's maximum output")}
    NAMES = {b: name for b, (name, _) in BITS.items()}

    @classmethod
    def describe(cls, bits: int) -> str:
        """``"overload, overheating"`` for the set bits; ``"none"`` if zero."""
        names = [n for b, n in cls.NAMES.items() if bits & b]
        return ", ".join(names) if names else "none"

    @classmethod
    def explain(cls, bits: int) -> str:
        """``"overload: a persistent load ..."`` for each set bit, ``;``-separated; unknown bits
        are named as such."""
        known = [f"{name}: {meaning}" for b, (name, meaning) in cls.BITS.items() if bits & b]
        rest = bits & ~sum(cls.BITS)
        if rest:
            known.append(f"unknown bits 0x{rest:02X}")
        return "; ".join(known) if known else "none"


@dataclass(frozen=True)
class Register:
    """One control-table item. Raw values are integers; ``scale`` is SI units per LSB."""

    name: str
    address: int
    size: int
    access: str                 # "R" or "RW"
    area: str                   # "EEPROM" or "RAM"
    default: int
    min: int | None = None      # raw range (None: read-only item)
    max: int | None = None
    signed: bool = False
    unit: str | None = None     # SI unit of to_si(); None = raw integer
    scale: float | None = None
    limit: str | None = None    # symmetric limit item (|value| <= limit)
    limit_min: str | None = None
    limit_max: str | None = None
    allowed: tuple[int, ...] | None = None
    divisor: int | None = None  # firmware gain = raw / divisor
    extra: dict = field(default_factory=dict, compare=False, hash=False)

    def __hash__(self) -> int:
        # The generated hash would hash every field on each use as a dict key (the emulator's
        # write path does that per item); name and address identify an item within a table.
        return hash((self.name, self.address))

    @property
    def writable(self) -> bool:
        return self.access == "RW"

    @property
    def eeprom(self) -> bool:
        return self.area == "EEPROM"

    # raw <-> bytes
    def encode(self, raw: int) -> bytes:
        """Little-endian bytes of a raw value (two's complement where signed)."""
        try:
            return int(raw).to_bytes(self.size, "little", signed=self.signed)
        except OverflowError:
            lo, hi = self.raw_bounds()
            raise OutOfRangeError(self.name, raw, lo, hi) from None

    def decode(self, data: bytes) -> int:
        """Raw value from little-endian bytes (sign-extended where signed)."""
        if len(data) != self.size:
            raise ValueError(f"{self.name}: expected {self.size} bytes, got {len(data)}")
        return int.from_bytes(data, "little", signed=self.signed)

    def raw_bounds(self) -> tuple[int, int]:
        """The widest raw range: the item's documented range, else what its size holds."""
        return self._bounds

    @functools.cached_property
    def _bounds(self) -> tuple[int, int]:
        # worked out once per item: the control loop checks eight goals a cycle against it
        if self.min is not None and self.max is not None:
            return self.min, self.max
        bits = 8 * self.size
        return (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if self.signed else (0, (1 << bits) - 1)

    def check_raw(self, raw: int) -> int:
        """Return ``raw`` if inside the item's fixed range, else raise OutOfRangeError."""
        lo, hi = self._bounds
        if not lo <= raw <= hi or (self.allowed is not None and raw not in self.allowed):
            raise OutOfRangeError(self.name, raw, lo, hi)
        return raw

    # raw <-> SI
    def to_si(self, raw: int) -> float:
        """SI value (``unit``) of a raw value; raw integers pass through as float."""
        return float(raw) * self.scale if self.scale else float(raw)

    def from_si(self, value: float) -> int:
        """Raw value nearest to ``value`` (in ``unit``); raises if NaN or out of range."""
        if value is None or (isinstance(value, float) and math.isnan(value)):
            raise OutOfRangeError(self.name, value, *self._si_bounds(), unit=self.unit or "")
        raw = round(value / self.scale) if self.scale else round(value)
        lo, hi = self._bounds
        if not lo <= raw <= hi:
            raise OutOfRangeError(self.name, value, *self._si_bounds(), unit=self.unit or "")
        return self.check_raw(int(raw))

    def _si_bounds(self) -> tuple[float, float]:
        lo, hi = self.raw_bounds()
        return self.to_si(lo), self.to_si(hi)


@dataclass(frozen=True)
class IndirectBlock:
    """``count`` Indirect Address items (2 bytes each) and their Indirect Data bytes; an
    Indirect Address may name bytes ``target_min .. target_max``."""

    address_start: int
    data_start: int
    count: int
    first: int
    target_min: int
    target_max: int


@dataclass(frozen=True)
class ControlTable:
    """The control table of one servo model."""

    model: str
    model_number: int
    gear_ratio: float
    pulses_per_rev: int         # encoder pulses per output turn
    registers: dict[str, Register]
    indirect: tuple[IndirectBlock, ...] = ()

    def __getitem__(self, name: str | Reg) -> Register:
        try:
            return self.registers[str(name)]
        except KeyError:
            raise RegisterError(f"{self.model} has no register named {str(name)!r}") from None

    def __contains__(self, name: object) -> bool:
        return str(name) in self.registers

    def __iter__(self):
        return iter(self.registers.values())

    @functools.cached_property
    def by_address(self) -> dict[int, Register]:
        return {r.address: r for r in self.registers.values()}

    @functools.cached_property
    def _within_cache(self) -> dict[tuple[int, int], tuple[Register, ...]]:
        return {}

    def within(self, address: int, length: int) -> tuple[Register, ...]:
        """The registers lying wholly inside bytes ``address .. address+length-1`` (cached)."""
        regs = self._within_cache.get((address, length))
        if regs is None:
            end = address + length
            regs = self._within_cache[(address, length)] = tuple(
                r for r in self.registers.values() if address <= r.address and r.address + r.size <= end)
        return regs

    def at(self, address: int) -> Register:
        """The register starting at ``address``."""
        try:
            return self.by_address[address]
        except KeyError:
            raise RegisterError(f"{self.model} has no register at address {address}") from None

    @property
    def size(self) -> int:
        """Bytes of memory the table spans (through the last indirect data byte)."""
        ends = [r.address + r.size for r in self.registers.values()]
        ends += [b.data_start + b.count for b in self.indirect]
        return max(ends)

    def span(self, first: str | Reg, last: str | Reg) -> tuple[int, int]:
        """``(address, length)`` covering registers ``first`` through ``last`` contiguously."""
        a, b = self[first], self[last]
        return a.address, b.address + b.size - a.address


_REG_NAMES = frozenset(Reg.__members__.values())


def _register(sec: Section) -> Register:
    name = sec.string("name")
    if name not in _REG_NAMES:
        sec.fail(f"unknown register name {name!r} (not in driver.control_table.Reg)", "name")
    size = sec.integer("size")
    if size not in (1, 2, 4):
        sec.fail(f"size must be 1, 2 or 4, got {size}", "size")
    allowed = sec.integers("allowed", None, None)
    reg = Register(
        name=name, address=sec.integer("address", min=0, max=0xFFFF), size=size,
        access=sec.choice("access", ("R", "RW")), area=sec.choice("area", ("EEPROM", "RAM")),
        default=sec.integer("default"), min=sec.integer("min", None), max=sec.integer("max", None),
        signed=sec.boolean("signed", False), unit=sec.string("unit", None, nonempty=False),
        scale=sec.number("scale", None, positive=True),
        limit=sec.string("limit", None), limit_min=sec.string("limit_min", None),
        limit_max=sec.string("limit_max", None), allowed=tuple(allowed) if allowed else None,
        divisor=sec.integer("divisor", None, min=1))
    # keys the Register has no field for (e.g. ``values_bps`` of baud_rate) stay available
    return dataclasses.replace(reg, extra=sec.unread())


def load_table(path: str | Path) -> ControlTable:
    """Load one model file; raises :class:`ConfigError` ``FILE:LINE: KEY: problem``."""
    top = read_yaml(path, what="control table").root()
    regs: dict[str, Register] = {}
    entries = []
    for sec in top.items("registers"):
        r = _register(sec)
        if r.name in regs:
            sec.fail(f"register {r.name} is listed twice", "name")
        regs[r.name] = r
        entries.append((sec, r))
    for sec, r in entries:
        for key in ("limit", "limit_min", "limit_max"):
            lim = getattr(r, key)
            if lim is not None and lim not in regs:
                sec.fail(f"{r.name} names unknown limit item {lim!r}", key)
    _check_overlaps(regs, Path(path))
    blocks = []
    for sec in top.items("indirect", None) if "indirect" in top else ():
        blocks.append(IndirectBlock(**{k: sec.integer(k, min=0) for k in
                                       ("address_start", "data_start", "count", "first",
                                        "target_min", "target_max")}))
        sec.check_unknown()
    table = ControlTable(
        model=top.string("model"), model_number=top.integer("model_number", min=0, max=0xFFFF),
        gear_ratio=top.number("gear_ratio", positive=True, max=1e4), registers=regs,
        indirect=tuple(blocks),
        pulses_per_rev=top.integer("encoder_pulses_per_rev", min=1))
    top.check_unknown()
    return table


def _check_overlaps(registers: dict[str, Register], path: Path) -> None:
    spans = sorted((r.address, r.address + r.size, r.name) for r in registers.values())
    for (a0, a1, n0), (b0, _, n1) in zip(spans, spans[1:]):
        if b0 < a1:
            raise ConfigError(f"{path}: registers {n0} and {n1} overlap")


#: The model whose table gives the X-series constants shared by every model file.
REFERENCE_MODEL = "xh430-w210"


class ModelLibrary:
    """The model files of one folder (``<model>.yaml``, lower-case names), each parsed at its
    first use and kept: a bus of one model parses one file.

    Every table's baud list is checked against the ``reference`` model's as it is loaded
    (:func:`check_baud_list`).
    """

    def __init__(self, folder: Path, reference: str = REFERENCE_MODEL):
        self.folder = Path(folder)
        self.reference = reference
        self._tables: dict[str, ControlTable] = {}
        self._names: tuple[str, ...] | None = None
        self._lock = threading.RLock()       # the emulator's and the driver's threads share the tables

    def names(self) -> tuple[str, ...]:
        """The models of the folder, lower case (``"xh430-w210"``): the files' names, sorted."""
        if self._names is None:
            self._names = tuple(sorted(p.stem for p in self.folder.glob("*.yaml")))
        return self._names

    def load(self, key: str) -> ControlTable:
        """The table of ``<key>.yaml`` (``key`` one of :meth:`names`), parsed the first time."""
        with self._lock:
            table = self._tables.get(key)
            if table is None:
                table = load_table(self.folder / f"{key}.yaml")
                check_baud_list(table, table if key == self.reference else self.load(self.reference))
                self._tables[key] = table
            return table

    def all(self) -> dict[str, ControlTable]:
        """Every model's table, keyed by :meth:`names` (parses every file the first time)."""
        return {key: self.load(key) for key in self.names()}

    def table_for(self, model: str | int) -> ControlTable:
        """The table of a model name (``"XH430-W210"``, any case) or model number (1010); a
        number needs every file. Raises :class:`ConfigError` naming the known ones."""
        if isinstance(model, int):
            tables = self.all()
            for t in tables.values():
                if t.model_number == model:
                    return t
            raise ConfigError(f"unknown model number {model}; known: "
                              + ", ".join(f"{t.model} ({t.model_number})" for t in tables.values()))
        key = str(model).lower()
        if key not in self.names():
            raise ConfigError(f"unknown servo model {model!r}; known: {', '.join(self.names())}")
        return self.load(key)


#: The shipped models (``configs/models``).
SHIPPED_MODELS = ModelLibrary(MODELS_DIR)


def models() -> dict[str, ControlTable]:
    """Every shipped model, keyed by lower-case name (``"xh430-w210"``); parses every file the
    first time, where :func:`table_for` with a name parses that model's only."""
    return SHIPPED_MODELS.all()


def table_for(model: str | int) -> ControlTable:
    """The shipped control table for a model name (``"XH430-W210"``) or model number (1010)."""
    return SHIPPED_MODELS.table_for(model)


def model_name(model_number: int) -> str:
    """Catalogue name for a model number, or ``"unknown (N)"``."""
    try:
        return table_for(int(model_number)).model
    except ConfigError:
        return f"unknown ({model_number})"


def _baud_list(table: ControlTable) -> tuple[int, ...]:
    """Baud Rate (8) value -> bps of one model, from ``values_bps`` of its baud_rate item."""
    return tuple(int(v) for v in table[Reg.BAUD_RATE].extra.get("values_bps", ()))


def check_baud_list(table: ControlTable, reference: ControlTable) -> None:
    """Raise :class:`ConfigError` unless ``table``'s baud list holds ``max + 1`` rates and begins
    ``reference``'s.

    e-Manual, XH430-W210 "Baud Rate(8)": 0 = 9,600, 1 = 57,600 (factory default), 2 = 115,200,
    3 = 1M, 4 = 2M, 5 = 3M, 6 = 4M, 7 = 4.5M bps. The X series shares the numbering; a model
    may stop short of the top rate (XL330: up to 6 = 4M), so each model's list must begin the
    reference model's and hold ``max + 1`` rates.
    """
    own, reg = _baud_list(table), table[Reg.BAUD_RATE]
    if len(own) != reg.max + 1:
        raise ConfigError(f"{table.model}: baud_rate.values_bps must list {reg.max + 1} rates")
    if own != _baud_list(reference)[:len(own)]:
        raise ConfigError(f"{table.model}: baud_rate.values_bps does not begin {reference.model}'s")


_REFERENCE = table_for(REFERENCE_MODEL)
#: Highest servo ID (ID item 7, e-Manual: 0 ~ 252; 253-254 are reserved and broadcast).
ID_MAX: int = _REFERENCE[Reg.ID].max
#: Baud Rate (8) item value -> bits per second (index = raw value), of the reference model; every
#: model's list begins it (checked as the model's file is loaded).
BAUD_RATES_BPS: tuple[int, ...] = _baud_list(_REFERENCE)
#: The factory-default rate (Baud Rate default, 57,600 bps).
DEFAULT_BAUD_BPS: int = BAUD_RATES_BPS[_REFERENCE[Reg.BAUD_RATE].default]
#: Order in which a scan tries the rates: the factory default first, then the others fastest
#: first (a try at a fast rate costs the least time).
SCAN_BAUDS_BPS: tuple[int, ...] = (DEFAULT_BAUD_BPS,) + tuple(
    sorted((b for b in BAUD_RATES_BPS if b != DEFAULT_BAUD_BPS), reverse=True))


def baud_index(bps: int) -> int:
    """Baud Rate item value for ``bps``; raises :class:`ConfigError` if the X series lacks it."""
    try:
        return BAUD_RATES_BPS.index(int(bps))
    except ValueError:
        raise ConfigError(f"{bps} bps is not an X-series baud rate "
                          f"({', '.join(map(str, BAUD_RATES_BPS))})") from None
