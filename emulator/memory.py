"""Control-table memory of one virtual servo: bytes, access rules, indirect mapping, resets.

The layout, defaults, ranges and limits come from the same ``configs/models/*.yaml`` files the
driver loads (:func:`driver.control_table.table_for`). Rules enforced on bus writes
(e-Manual "Control Table", docs/reference/protocol.md §3 and §6):

* EEPROM items (``area: EEPROM`` in the table) are writable only while Torque Enable = 0 -> Access Error;
* read-only items and undefined addresses -> Access Error;
* a write that covers an item only partly -> Data Length Error;
* a value outside the item's fixed range or allowed set -> Data Range Error;
* a value outside a configured limit item (Velocity/Current/PWM/Position Limit) ->
  ``limit_error`` (Data Limit Error by default; UNCONFIRMED, see emulator/README.md).

A write is checked completely before any byte changes (all or nothing).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Iterable, Iterator, Mapping, Sequence

from swerve.driver.control_table import ControlTable, Reg, Register
from swerve.driver.errors import RegisterError
from swerve.driver.control_table import OperatingMode
from swerve.driver.packets import ErrorNumber, ResetOption
from swerve.driver.span_codec import item_struct, items_struct

#: Goal items that a tripped Bus Watchdog makes read-only (writes -> Data Range Error).
WATCHDOG_LOCKED = (Reg.GOAL_PWM, Reg.GOAL_CURRENT, Reg.GOAL_VELOCITY, Reg.GOAL_POSITION)
#: Factory Reset options: which items survive.
RESET_ALL, RESET_EXCEPT_ID, RESET_EXCEPT_ID_BAUD = ResetOption.ALL, ResetOption.EXCEPT_ID, ResetOption.EXCEPT_ID_BAUD
POSITION_MODE = OperatingMode.POSITION
TIME_BASED_PROFILE_BIT = 0x04
# Items the write rules name, looked up once (an Enum member costs a metaclass lookup per use)
_TORQUE_ENABLE, _PROFILE_VELOCITY, _DRIVE_MODE, _GOAL_POSITION, _OPERATING_MODE = (
    Reg.TORQUE_ENABLE, Reg.PROFILE_VELOCITY, Reg.DRIVE_MODE, Reg.GOAL_POSITION, Reg.OPERATING_MODE)


def _reader(size: int, signed: bool) -> Callable[[bytearray, int], tuple[int]]:
    """``read(buffer, address) -> (raw,)`` for an item of ``size`` bytes (a ``struct`` unpacker
    where one fits: 2x faster than ``int.from_bytes`` of a slice)."""
    fmt = item_struct(size, signed)
    if fmt is not None:
        return fmt.unpack_from

    def read(buffer: bytearray, address: int) -> tuple[int]:
        return (int.from_bytes(buffer[address:address + size], "little", signed=signed),)
    return read


class WriteRejected(Exception):
    """A bus write broke a rule; ``number`` is the status error to return."""

    def __init__(self, number: ErrorNumber, detail: str):
        super().__init__(detail)
        self.number = number


@dataclass(frozen=True, slots=True)
class _ItemWrite:
    """An item a bus write covers, with its fixed rules (:meth:`ServoMemory._check_item`)."""

    reg: Register
    name: str
    offset: int                 # of its first byte in the written data (a whole-item write)
    read: Callable              # ``read(data, offset) -> (raw,)``
    writable: bool
    eeprom: bool
    locked: bool                # made read-only by a tripped Bus Watchdog
    lo: int
    hi: int
    allowed: tuple[int, ...] | None
    limited: bool               # has a limit item (checked against the memory)


def _item_rules(reg: Register, read: Callable) -> _ItemWrite:
    """The write rules of item ``reg`` (at offset 0), read by ``read``."""
    lo, hi = reg.raw_bounds()
    return _ItemWrite(reg, reg.name, 0, read, reg.writable, reg.eeprom, reg.name in WATCHDOG_LOCKED, lo, hi,
                      reg.allowed, reg.limit is not None or reg.limit_min is not None or reg.limit_max is not None)


#: The other items of a write of one item (:meth:`ServoMemory._check_limits`' ``pending``).
_NOTHING_PENDING: dict[str, int] = {}
#: A write layout not worked out yet (:meth:`ServoMemory._write_layout`).
_UNSEEN = object()
#: Most write layouts a memory keeps (:meth:`ServoMemory._write_layout`; a client writes a few).
_MAX_WRITE_LAYOUTS = 256


@dataclass(frozen=True)
class _Slot:
    """An Indirect Address item (2 bytes) and its Indirect Data byte."""

    address: int
    data: int
    target_min: int
    target_max: int


class ServoMemory:
    """The bytes of one servo's control table plus its rules.

    ``read``/``write`` follow the bus rules; ``get``/``set`` bypass them (for the servo's own
    firmware, physics and tests). Values are raw integers, sign-extended where the item is signed.

    Present items may be published lazily: whoever advances the physics sets :attr:`stale`, and
    the next bus read, or ``get`` of a name in :attr:`published`, first calls :attr:`publisher`
    (which writes them with ``set``). Nothing outside sees a difference from writing every tick.
    A publisher may also write a reading in two parts (:meth:`publish_in_parts`): a plain read
    inside the part's bytes writes only those, any other access the rest of the same reading.
    """

    def __init__(self, table: ControlTable, *, limit_error: ErrorNumber = ErrorNumber.DATA_LIMIT):
        self.table = table
        self.limit_error = ErrorNumber(limit_error)
        self.size = table.size
        #: One past the last EEPROM item's byte: what Control Table Backup stores.
        self.eeprom_end = max(r.address + r.size for r in table if r.eeprom)
        self._bytes = bytearray(self.size)
        self._slices = {reg.name: (reg.address, reg.address + reg.size, reg.signed) for reg in table}
        self._readers = {reg.name: (_reader(reg.size, reg.signed), reg.address) for reg in table}
        self._owner: list[Register | None] = [None] * self.size
        for reg in table:
            for a in range(reg.address, reg.address + reg.size):
                self._owner[a] = reg
        self._data_slot: dict[int, _Slot] = {}
        self._addr_slot: dict[int, _Slot] = {}
        for block in table.indirect:
            for k in range(block.count):
                slot = _Slot(block.address_start + 2 * k, block.data_start + k, block.target_min, block.target_max)
                self._addr_slot[slot.address] = slot
                self._addr_slot[slot.address + 1] = slot
                self._data_slot[slot.data] = slot
        # addresses a bus access must resolve byte by byte (indirect data and address items)
        special = [*self._data_slot, *self._addr_slot]
        self._special_lo, self._special_hi = (min(special), max(special)) if special else (self.size, -1)
        #: Each item's write rules (at offset 0), and the layouts of the writes seen
        self._rules = {reg.name: _item_rules(reg, self._readers[reg.name][0]) for reg in table}
        self._write_layouts: dict[tuple[int, int], tuple[_ItemWrite, ...] | None] = {}
        self.watchdog_tripped = False
        #: ``publisher(reading)``: writes every published item, of ``reading`` (what a part
        #: publisher returned) or of a new reading (``None``)
        self.publisher: Callable[[object | None], None] | None = None
        self.published: frozenset[str] = frozenset()
        self.stale = False
        self._part: Callable[[], object | None] | None = None
        self._part_lo, self._part_hi = 0, -1
        self._rest: object | None = None       # a reading whose part only is written
        self.load_defaults()

    # --- defaults and resets ------------------------------------------------------------------
    def load_defaults(self, keep: Iterable[str] = ()) -> None:
        """Every item to its default (except the names in ``keep``), indirect map to itself."""
        kept = {name: self.get(name) for name in keep}
        self._bytes[:] = bytes(self.size)
        for reg in self.table:
            self._put(reg, reg.default)
        self._reset_indirect()
        for name, value in kept.items():
            self.set(name, value)
        self.watchdog_tripped = False

    def reset_ram(self) -> None:
        """What a reboot does to memory: RAM items back to defaults, EEPROM kept."""
        for reg in self.table:
            if not reg.eeprom:
                self._put(reg, reg.default)
        self._reset_indirect()
        self.watchdog_tripped = False

    def factory_reset(self, option: int) -> None:
        """Factory Reset: 0xFF everything, 0x01 all but ID, 0x02 all but ID and Baud Rate."""
        keep = {RESET_ALL: (), RESET_EXCEPT_ID: (Reg.ID,),
                RESET_EXCEPT_ID_BAUD: (Reg.ID, Reg.BAUD_RATE)}[option]
        self.load_defaults(keep=[str(k) for k in keep])

    def _reset_indirect(self) -> None:
        for slot in set(self._data_slot.values()):
            self._bytes[slot.address:slot.address + 2] = slot.data.to_bytes(2, "little")
            self._bytes[slot.data] = 0

    # --- bypass access ----------------------------------------------------------------------------
    def publish(self) -> None:
        """Bring published items up to date if the physics moved since they were written (or
        write the rest of a reading whose part only is written)."""
        if self.stale:
            self.stale = False
            self._rest = None
            if self.publisher is not None:
                self.publisher(None)
        elif self._rest is not None:
            reading, self._rest = self._rest, None
            self.publisher(reading)

    def publish_in_parts(self, lo: int, hi: int, part: Callable[[], object | None]) -> None:
        """Let a plain bus read (:meth:`read_plain`) of bytes within ``lo .. hi-1`` publish only
        those: ``part()`` writes them for a new reading and returns the reading, which
        :attr:`publisher` is given to write the rest of it when anything else is accessed;
        or returns ``None`` when it wrote every published item itself."""
        self._part, self._part_lo, self._part_hi = part, lo, hi

    def get(self, name: str) -> int:
        """Raw value of item ``name`` (no rules)."""
        if (self.stale or self._rest is not None) and name in self.published:
            self.publish()
        try:
            read, address = self._readers[name]
        except KeyError:
            raise RegisterError(f"{self.table.model} has no register named {str(name)!r}") from None
        return read(self._bytes, address)[0]

    def byte(self, address: int) -> int:
        """The stored byte at ``address``: the raw value of an unsigned one-byte item that is
        not published (no rules; the servo's own reads of its Return Delay Time and Hardware
        Error Status, once per reply)."""
        return self._bytes[address]

    def set(self, name: str, raw: int) -> None:
        """Store raw value ``raw`` in item ``name`` (no rules; raises if it does not fit the size)."""
        if self._rest is not None and name in self.published:
            self.publish()              # the rest of the reading first: it must not overwrite this
        try:
            a, b, signed = self._slices[name]
            self._bytes[a:b] = int(raw).to_bytes(b - a, "little", signed=signed)
        except (KeyError, OverflowError):
            self._put(self.table[name], raw)       # raises RegisterError / OutOfRangeError

    def packer(self, names: Sequence[str]) -> Callable[[Sequence[int]], None] | None:
        """A writer of raw values for the items ``names`` (values in that order) with one
        ``struct.pack_into``, if the items lie back to back; ``None`` if not. A value that does not
        fit raises :class:`struct.error` (items before it in address order may be written)."""
        start = min(self.table[n].address for n in names)
        ordered, fmt = items_struct(self.table, names, start)
        if fmt is None or fmt.size != sum(self.table[n].size for n in names):     # a gap or overlap
            return None
        order = [list(names).index(n) for n in ordered]
        buf = self._bytes
        if order == sorted(order):      # names given in address order: no reordering

            def write(values: Sequence[int]) -> None:
                fmt.pack_into(buf, start, *values)
            return write

        def write_reordered(values: Sequence[int]) -> None:
            fmt.pack_into(buf, start, *[values[k] for k in order])
        return write_reordered

    def _put(self, reg: Register, raw: int) -> None:
        self._bytes[reg.address:reg.address + reg.size] = reg.encode(raw)

    def view(self) -> "Mapping[str, int]":
        """A live read-only mapping name -> raw value (decoded on access; for ``dynamics``)."""
        return _MemoryView(self)

    def stored_bytes(self, end: int) -> bytes:
        """The table's stored bytes ``0 .. end-1``, as written (indirect data not resolved).

        For physics reading its input items each step: one copy instead of a decode per item
        (no item below the first Indirect Data address is indirect).
        """
        return bytes(self._bytes[:end])

    def copy(self) -> "ServoMemory":
        """An independent copy (bytes and watchdog state), e.g. to try a write without applying it."""
        self.publish()
        other = ServoMemory(self.table, limit_error=self.limit_error)
        other._bytes[:] = self._bytes
        other.watchdog_tripped = self.watchdog_tripped
        return other

    def eeprom_bytes(self) -> bytes:
        return bytes(self._bytes[:self.eeprom_end])

    def restore_eeprom(self, data: bytes) -> None:
        self._bytes[:self.eeprom_end] = data

    # --- bus read ---------------------------------------------------------------------------------
    def read(self, address: int, length: int) -> bytes:
        """Bytes ``address .. address+length-1`` as the bus sees them (indirect data resolved).

        Raises :class:`WriteRejected` (Access Error) outside the table, Data Length Error for 0.
        """
        if length <= 0:
            raise WriteRejected(ErrorNumber.DATA_LENGTH, "read of 0 bytes")
        if address < 0 or address + length > self.size:
            raise WriteRejected(ErrorNumber.ACCESS,
                                f"read {address}+{length} outside the table (0..{self.size - 1})")
        if self.stale or self._rest is not None:
            self.publish()
        if address + length <= self._special_lo or address > self._special_hi:
            return bytes(self._bytes[address:address + length])     # no indirect data in the range
        out = bytearray(self._bytes[address:address + length])
        for a in range(address, address + length):
            slot = self._data_slot.get(a)
            if slot is not None:
                out[a - address] = self._bytes[self._target(slot)]
        return bytes(out)

    def plain_range(self, address: int, length: int) -> bool:
        """True if a bus read of ``length`` bytes at ``address`` is a copy of the stored bytes:
        at least one byte, inside the table, no Indirect Data byte (:meth:`read_plain` then
        returns what :meth:`read` would)."""
        end = address + length
        return 0 < length and 0 <= address and end <= self.size and (end <= self._special_lo
                                                                      or address > self._special_hi)

    def read_plain(self, address: int, end: int) -> bytearray:
        """:meth:`read` of bytes ``address .. end-1`` for a range :meth:`plain_range` accepted:
        the published items brought up to date (only those in a part, :meth:`publish_in_parts`,
        if the range lies in it), then a copy of the stored bytes."""
        if self.stale:
            if self._part_lo <= address and end <= self._part_hi:
                self.stale = False
                self._rest = None
                self._rest = self._part()
            else:
                self.publish()
        elif self._rest is not None and not (self._part_lo <= address and end <= self._part_hi):
            self.publish()
        return self._bytes[address:end]

    def _target(self, slot: _Slot) -> int:
        return int.from_bytes(self._bytes[slot.address:slot.address + 2], "little")

    # --- bus write --------------------------------------------------------------------------------
    def write(self, address: int, data: bytes) -> list[str]:
        """Apply a bus write after checking every rule; return the item names changed.

        Raises :class:`WriteRejected` with the error number to report; nothing is changed then.
        """
        n = len(data)
        if not n:
            raise WriteRejected(ErrorNumber.DATA_LENGTH, "write without data")
        if address < 0 or address + n > self.size:
            raise WriteRejected(ErrorNumber.ACCESS, f"write {address}+{n} outside the table")
        layout = self._write_layouts.get((address, n), _UNSEEN)
        if layout is _UNSEEN:
            layout = self._write_layout(address, n)
        if layout is not None and len(layout) == 1:     # one whole plain item (a goal): as below
            item = layout[0]
            value = item.read(data, 0)[0]
            if item.limited:            # its limit items are not in the write: read from memory
                self._check_item(item, value, _NOTHING_PENDING)
            elif not item.writable or item.eeprom or item.locked or item.allowed is not None \
                    or not item.lo <= value <= item.hi:
                self._check_item(item, value, _NOTHING_PENDING)     # it raises the rule's error
            self._bytes[address:address + n] = data
            return [item.name]
        if layout is not None:          # whole plain items: steps 1-2 have nothing to do, and
            whole = {item.name: item.read(data, item.offset)[0] for item in layout}   # the data is the
            for item in layout:                                  # items' encoding (step 4 copies it)
                self._check_item(item, whole[item.name], whole)
            self._bytes[address:address + n] = data
            return list(whole)
        # 1. resolve indirect data bytes to their targets; collect per-item byte patches
        direct: dict[int, int] = {}
        via_indirect: dict[int, int] = {}
        slot_writes: dict[int, int] = {}
        for i, b in enumerate(data):
            a = address + i
            if a in self._data_slot:
                via_indirect[self._target(self._data_slot[a])] = b
            elif a in self._addr_slot:
                slot_writes[a] = b
            else:
                direct[a] = b
        patches: dict[Register, dict[int, int]] = {}
        for a, b in direct.items():
            reg = self._owner[a]
            if reg is None:
                raise WriteRejected(ErrorNumber.ACCESS, f"address {a} is not a writable item")
            patches.setdefault(reg, {})[a] = b
        for reg, bytes_ in patches.items():
            if len(bytes_) != reg.size:
                raise WriteRejected(ErrorNumber.DATA_LENGTH,
                                    f"{reg.name} needs {reg.size} bytes, got {len(bytes_)}")
        for a, b in via_indirect.items():
            reg = self._owner[a]
            if reg is None:
                raise WriteRejected(ErrorNumber.ACCESS, f"indirect target {a} is not an item")
            patches.setdefault(reg, {})[a] = b
        # 2. indirect address items: each 2-byte pair must be whole and in range
        new_slots: dict[_Slot, int] = {}
        for a in slot_writes:
            slot = self._addr_slot[a]
            if slot.address not in slot_writes or slot.address + 1 not in slot_writes:
                raise WriteRejected(ErrorNumber.DATA_LENGTH, f"indirect address {slot.address} needs 2 bytes")
            v = slot_writes[slot.address] | (slot_writes[slot.address + 1] << 8)
            if not slot.target_min <= v <= slot.target_max:
                raise WriteRejected(ErrorNumber.DATA_RANGE,
                                    f"indirect address {v} outside {slot.target_min}..{slot.target_max}")
            new_slots[slot] = v
        # 3. item rules, against the memory as it will be after the whole write
        new_values: dict[str, int] = {}
        for reg, bytes_ in patches.items():
            raw = bytearray(self._bytes[reg.address:reg.address + reg.size])
            for a, b in bytes_.items():
                raw[a - reg.address] = b
            new_values[reg.name] = reg.decode(bytes(raw))
        return self._check_and_apply(new_values, new_slots)

    def _write_layout(self, address: int, length: int) -> tuple[_ItemWrite, ...] | None:
        """The items a write of ``length`` bytes at ``address`` covers, with their rules, if it
        covers whole items only and no indirect byte; ``None`` otherwise (the general path then
        finds the error or the indirect targets). Kept per ``(address, length)``."""
        layout: tuple[_ItemWrite, ...] | None = None
        end = address + length
        if end <= self._special_lo or address > self._special_hi:
            items = []
            a = address
            while a < end:
                reg = self._owner[a]
                if reg is None or reg.address != a or a + reg.size > end:
                    break
                items.append(replace(self._rules[reg.name], offset=a - address))
                a += reg.size
            else:
                layout = tuple(items)
        if len(self._write_layouts) >= _MAX_WRITE_LAYOUTS:
            self._write_layouts.clear()
        self._write_layouts[(address, length)] = layout
        return layout

    def _check_item(self, item: _ItemWrite, value: int, pending: dict[str, int]) -> None:
        """One item's rules (``item``) for the new raw ``value``, against the memory before the
        write and the other items of the write (``pending``); nothing is applied before every
        item passed."""
        if not item.writable:
            raise WriteRejected(ErrorNumber.ACCESS, f"{item.name} is read-only")
        if item.eeprom and self.get(_TORQUE_ENABLE) == 1:
            raise WriteRejected(ErrorNumber.ACCESS, f"{item.name} is in EEPROM and torque is on")
        if item.locked and self.watchdog_tripped:
            raise WriteRejected(ErrorNumber.DATA_RANGE, f"{item.name} is locked by the bus watchdog")
        if not item.lo <= value <= item.hi or (item.allowed is not None and value not in item.allowed):
            raise WriteRejected(ErrorNumber.DATA_RANGE, f"{item.name} = {value} outside [{item.lo}, {item.hi}]")
        if item.limited:
            self._check_limits(item.reg, value, pending)

    def _check_and_apply(self, new_values: dict[str, int], new_slots: dict[_Slot, int]) -> list[str]:
        """Steps 3 and 4 of :meth:`write`: the item rules, then the new values and indirect
        addresses. ``new_values`` is keyed by item name (a ``str`` hashes in C; a Register would
        call its Python ``__hash__`` on every lookup)."""
        regs = self.table.registers
        for name, value in new_values.items():
            self._check_item(self._rules[name], value, new_values)
        for name, value in new_values.items():
            self._put(regs[name], value)
        for slot, v in new_slots.items():
            self._bytes[slot.address:slot.address + 2] = v.to_bytes(2, "little")
        return list(new_values)

    def _check_limits(self, reg: Register, value: int, pending: dict[str, int]) -> None:
        if reg.limit is not None:
            if reg.name == _PROFILE_VELOCITY and self.get(_DRIVE_MODE) & TIME_BASED_PROFILE_BIT:
                return  # time-based profile: Profile Velocity is a time, not capped by Velocity Limit
            limit = reg.limit
            cap = pending[limit] if limit in pending else self.get(limit)
            if abs(value) > cap:
                raise WriteRejected(self.limit_error, f"|{reg.name}| = {abs(value)} above {reg.limit} {cap}")
        if reg.limit_min is not None or reg.limit_max is not None:
            if reg.name == _GOAL_POSITION and self.get(_OPERATING_MODE) != POSITION_MODE:
                return  # position limits apply only in Position Control Mode (3)
            lo, hi = reg.limit_min, reg.limit_max
            lo = (pending[lo] if lo in pending else self.get(lo)) if lo else None
            hi = (pending[hi] if hi in pending else self.get(hi)) if hi else None
            if (lo is not None and value < lo) or (hi is not None and value > hi):
                raise WriteRejected(self.limit_error, f"{reg.name} = {value} outside [{lo}, {hi}]")


class _MemoryView(Mapping):
    """Read-only ``Mapping[str, int]`` over a :class:`ServoMemory`, decoding items on access."""

    def __init__(self, memory: ServoMemory):
        self._memory = memory

    def __getitem__(self, name: str) -> int:
        if name not in self._memory.table:
            raise KeyError(name)
        return self._memory.get(name)

    def __iter__(self) -> Iterator[str]:
        return iter(self._memory.table.registers)

    def __len__(self) -> int:
        return len(self._memory.table.registers)
