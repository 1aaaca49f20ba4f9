"""Register spans <-> bytes with one precompiled :class:`struct.Struct` per span.

A span is a run of control-table items read or written as one block of little-endian bytes (a
Sync Read reply, the emulator's packed writes of its present items, the physics' input items).
Each item's bytes are what :meth:`~swerve.driver.control_table.Register.encode` writes and
:meth:`~swerve.driver.control_table.Register.decode` reads: little-endian, two's complement where
the item is signed (e-Manual, "Control Table": multi-byte items are little-endian). One
``struct`` format for the whole span does that for every item in a single call; gaps between
items are pad bytes. Pure code, no I/O: the driver and the emulator share it.
"""
from __future__ import annotations

import struct
from typing import Callable, Iterable, Sequence

from swerve.driver.control_table import ControlTable, Register

#: ``struct`` code of a little-endian raw item by ``(size in bytes, signed)``.
STRUCT_CODES: dict[tuple[int, bool], str] = {
    (1, False): "B", (1, True): "b", (2, False): "H", (2, True): "h", (4, False): "I", (4, True): "i"}


def item_struct(size: int, signed: bool) -> struct.Struct | None:
    """The little-endian :class:`struct.Struct` of one item of ``size`` bytes, ``None`` if
    ``struct`` has no code for that size."""
    code = STRUCT_CODES.get((size, signed))
    return None if code is None else struct.Struct("<" + code)


def span_struct(regs: Sequence[Register], start: int, end: int | None = None) -> struct.Struct | None:
    """One little-endian :class:`struct.Struct` for items ``regs`` laid out from byte ``start``.

    Parameters
    ----------
    regs : sequence of Register
        The items, in address order; the bytes between them become pad bytes.
    start : int
        Address of the span's first byte (the Struct's offset 0).
    end : int, optional
        Address one past the span's last byte (trailing pad bytes up to it); default: the end of
        the last item.

    Returns
    -------
    struct.Struct or None
        Its ``unpack`` gives the raw values of ``regs`` in order, and ``pack`` takes them in
        order. ``None`` if an item has a size ``struct`` has no code for, or the items are out of
        address order, overlap, or lie outside ``start .. end``.
    """
    fmt, pos = ["<"], start
    for r in regs:
        code = STRUCT_CODES.get((r.size, r.signed))
        if code is None or r.address < pos:
            return None
        fmt.append("x" * (r.address - pos) + code)
        pos = r.address + r.size
    if end is not None:
        if end < pos:
            return None
        fmt.append("x" * (end - pos))
    return struct.Struct("".join(fmt))


def items_struct(table: ControlTable, names: Iterable[str], start: int = 0
                 ) -> tuple[tuple[str, ...], struct.Struct | None]:
    """``(names in address order, Struct)`` for the items ``names`` of ``table`` laid out from
    byte ``start`` (:func:`span_struct`; the Struct is ``None`` where it is)."""
    regs = sorted((table[n] for n in names), key=lambda r: r.address)
    return tuple(r.name for r in regs), span_struct(regs, start)


def span_values(table: ControlTable, address: int, length: int
                ) -> tuple[tuple[str, ...], Callable[[bytes], tuple[int, ...]]]:
    """``(names, values)`` for the registers wholly inside ``length`` bytes at ``address``:
    their names in address order and ``values(data) -> (raw, ...)`` in that order.

    One :func:`span_struct` unpack does what :meth:`Register.decode` does for each item; spans
    with items ``struct`` has no code for, or overlapping items, decode item by item with
    :meth:`Register.decode`.
    """
    regs = table.within(address, length)
    names = tuple(r.name for r in regs)
    fmt = span_struct(regs, address, address + length)
    if fmt is None:
        return names, lambda data: tuple(r.decode(data[r.address - address:r.address - address + r.size])
                                         for r in regs)
    return names, fmt.unpack


def span_decoder(table: ControlTable, address: int, length: int) -> Callable[[bytes], dict[str, int]]:
    """``data -> {register name: raw}`` for the registers wholly inside ``length`` bytes at
    ``address`` (:func:`span_values` as a dict)."""
    names, values = span_values(table, address, length)
    return lambda data: dict(zip(names, values(data)))
