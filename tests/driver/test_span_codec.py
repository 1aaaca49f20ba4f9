"""The register-span codec packs and unpacks what Register.encode/decode do, item by item, and
the model tables give the constants the code reads from them."""
from __future__ import annotations

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swerve.driver.control_table import Reg, load_table, models, table_for
from swerve.driver.errors import ConfigError
from swerve.driver.packets import FastStatus, StatusPacket, fast_entries, fast_status_bytes, fast_status_length
from swerve.driver.parser import PacketParser
from swerve.driver.span_codec import STRUCT_CODES, item_struct, items_struct, span_struct
from swerve.emulator.memory import ServoMemory

MODELS = sorted(models())


@st.composite
def items_and_values(draw):
    """A model, a non-empty set of its item names in any order, and a raw value for each."""
    table = models()[draw(st.sampled_from(MODELS))]
    regs = list(table)
    chosen = draw(st.lists(st.sampled_from(regs), min_size=1, max_size=12, unique_by=lambda r: r.name))
    values = [draw(st.integers(*r.raw_bounds()) if r.min is None else st.integers(r.min, r.max)) for r in chosen]
    return table, chosen, values


@given(items_and_values())
@example((table_for("xh430-w210"), [table_for("xh430-w210")[Reg.PRESENT_CURRENT]], [-32768]))
@settings(max_examples=300, deadline=None)
def test_a_span_packs_and_unpacks_as_the_items_encode(case):
    table, chosen, values = case
    by_address = sorted(zip(chosen, values), key=lambda rv: rv[0].address)
    regs = [r for r, _ in by_address]
    start = regs[0].address
    end = regs[-1].address + regs[-1].size + 3
    fmt = span_struct(regs, start, end)
    assert fmt is not None and fmt.size == end - start
    data = fmt.pack(*[v for _, v in by_address])
    for r, v in by_address:
        assert data[r.address - start:r.address - start + r.size] == r.encode(v)
    assert list(fmt.unpack(data)) == [r.decode(data[r.address - start:r.address - start + r.size])
                                      for r in regs]
    names, fmt0 = items_struct(table, [r.name for r in chosen], start)
    assert names == tuple(r.name for r in regs) and fmt0.format == span_struct(regs, start).format


def test_spans_that_struct_cannot_lay_out_are_refused():
    t = table_for("xh430-w210")
    pos, vel = t[Reg.PRESENT_POSITION], t[Reg.PRESENT_VELOCITY]
    assert span_struct([pos, vel], pos.address) is None             # out of address order
    assert span_struct([vel, vel], vel.address) is None              # overlapping
    assert span_struct([vel], vel.address + 1) is None               # item before the span's start
    assert span_struct([vel], vel.address, vel.address + 2) is None  # item past the span's end
    assert item_struct(3, False) is None and item_struct(4, True).format == "<i"
    assert set(STRUCT_CODES) == {(n, s) for n in (1, 2, 4) for s in (False, True)}


@st.composite
def back_to_back_items(draw):
    """A run of items that lie back to back in one model's table, in any order, with values."""
    table = models()[draw(st.sampled_from(MODELS))]
    regs = sorted(table, key=lambda r: r.address)
    first = draw(st.integers(0, len(regs) - 1))
    run = [regs[first]]
    for r in regs[first + 1:]:
        if r.address != run[-1].address + run[-1].size or len(run) == 8:
            break
        run.append(r)
    run = draw(st.permutations(run[:draw(st.integers(1, len(run)))]))
    return table, run, [draw(st.integers(r.min, r.max) if r.min is not None else st.integers(*r.raw_bounds()))
                        for r in run]


@given(st.one_of(items_and_values(), back_to_back_items()))
@settings(max_examples=300, deadline=None)
def test_the_memory_packer_writes_what_set_writes(case):
    table, chosen, values = case
    names = [r.name for r in chosen]
    packed, plain = ServoMemory(table), ServoMemory(table)
    write = packed.packer(names)
    regs = sorted(chosen, key=lambda r: r.address)
    back_to_back = all(b.address == a.address + a.size for a, b in zip(regs, regs[1:]))
    if not back_to_back:
        assert write is None
        return
    write(values)
    for n, v in zip(names, values):
        plain.set(n, v)
    assert packed.stored_bytes(packed.size) == plain.stored_bytes(plain.size)


@pytest.mark.parametrize("model", MODELS)
def test_constants_come_from_the_model_file(model):
    t = models()[model]
    # e-Manual "Control Table": the EEPROM area is addresses 0-63; 4096 pulses per turn
    assert ServoMemory(t).eeprom_end == 64
    assert t.pulses_per_rev == 4096
    assert all(r.address < 64 for r in t if r.eeprom) and all(r.address >= 64 for r in t if not r.eeprom)


def test_a_model_file_must_give_its_pulses_per_turn(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("model: X\nmodel_number: 1\ngear_ratio: 1\nregisters:\n"
                    "  - {name: led, address: 0, size: 1, access: R, area: RAM, default: 0}\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml.*encoder_pulses_per_rev"):
        load_table(path)


fast_entries_st = st.lists(st.tuples(st.integers(0, 252), st.integers(0, 0xFF), st.binary(max_size=12)),
                           min_size=1, max_size=8)


@given(fast_entries_st, st.data())
@example([(1, 0, b"\xff\xff\xfd"), (2, 0x80, b"")], None)
@settings(max_examples=300, deadline=None)
def test_fast_reply_length_and_running_crc_walk(entries, data):
    packets = tuple(StatusPacket(i, e, p) for i, e, p in entries)
    lengths = [len(p) for _, _, p in entries]
    frame = FastStatus(packets).encode()
    assert len(frame) == fast_status_bytes(lengths) == 7 + fast_status_length(lengths)
    assert frame[5] | frame[6] << 8 == fast_status_length(lengths)
    assert FastStatus.decode(frame, lengths).entries == packets
    walked = list(fast_entries(frame, lengths))
    assert [frame[pos + 2:end] for pos, end, _ in walked] == [p for _, _, p in entries]
    assert all(crc == frame[end] | frame[end + 1] << 8 for _, end, crc in walked)
    # a reply cut short: the walk stops at the first incomplete entry, and so does the parser's count
    cut = len(frame) - 1 if data is None else data.draw(st.integers(8, len(frame) - 1))
    complete = sum(1 for _, end, _ in walked if end + 2 <= cut)
    assert len(list(fast_entries(frame[:cut], lengths))) == complete
    parser = PacketParser()
    parser.expect_fast(lengths)
    assert parser.feed(frame[:cut]) == []
    parser.flush()
    assert parser.fast_entries_received == complete
