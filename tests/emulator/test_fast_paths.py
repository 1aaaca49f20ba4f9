"""The emulator's fast paths equal its general paths over the whole input space.

Each fast path (a Sync Read of a plain range, a write of one whole item, the adapter's packet
edges found from a packet's last byte) is compared with the general code it stands in for, on
the same state: the same replies or errors, and the same state afterwards.
"""
from __future__ import annotations

import math
from bisect import bisect_right

from hypothesis import example, given, settings
from hypothesis import strategies as st

from swerve.driver import packets as pk
from swerve.driver.control_table import Reg, table_for
from swerve.emulator.adapter import AdapterSettings, Delivery, byte_arrivals, deliver
from swerve.emulator.factory import build_emulator
from swerve.emulator.instructions import DispatchRules, _plain_everywhere, listed_reads, plain_sync_read
from swerve.emulator.memory import WriteRejected
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.servo import make_servos

MODEL = "xh430-w210"
TABLE = table_for(MODEL)
#: Bytes that make stuffing patterns (FF FF FD) and Alert bits likely.
BYTES = st.sampled_from([0x00, 0x01, 0x7F, 0xFD, 0xFF])


def _servos(ids, stored: bytes, alerts, delays, stale, since_s):
    """Servos with ``ids`` whose plain memory below the first Indirect Address item holds
    ``stored`` (the same bytes, each servo's own ID, Hardware Error Status, Return Delay Time)."""
    servos = make_servos(ids, MODEL, 1_000_000)
    for k, s in enumerate(servos):
        m = s.memory
        m._bytes[:len(stored)] = stored
        m.set(Reg.ID, s.id)
        m.set(Reg.BAUD_RATE, 3)
        m.set(Reg.HARDWARE_ERROR_STATUS, alerts[k % len(alerts)])
        m.set(Reg.RETURN_DELAY_TIME, delays[k % len(delays)])
        m.stale = stale
        s._since_traffic_s = since_s
    return servos


def _state(servos):
    return [(s.memory.stored_bytes(s.memory.size), s._since_traffic_s, s.memory.stale) for s in servos]


PLAIN_END = min(block.address_start for block in TABLE.indirect)
PHYSICS = load_config(resolve_emulator_config("realistic"))


@given(ids=st.lists(st.integers(0, 252), min_size=1, max_size=6, unique=True),
       listed=st.lists(st.integers(0, 252), max_size=10),
       pick=st.lists(st.integers(0, 5), max_size=10),
       vanished=st.sets(st.integers(0, 5), max_size=3),
       address=st.integers(0, PLAIN_END - 1), length=st.integers(1, 40),
       stored=st.binary(min_size=PLAIN_END, max_size=PLAIN_END) | st.lists(BYTES, min_size=PLAIN_END,
                                                                          max_size=PLAIN_END).map(bytes),
       alerts=st.lists(st.sampled_from([0, 0x01, 0x20]), min_size=1, max_size=3),
       delays=st.lists(st.integers(0, 254), min_size=1, max_size=3),
       stale=st.booleans(), since_s=st.floats(0.0, 1.0), chain_break=st.booleans())
@example(ids=[1, 2, 3], listed=[1, 2, 3], pick=[], vanished=set(), address=126, length=10,
         stored=bytes(PLAIN_END), alerts=[0], delays=[0], stale=True, since_s=0.5, chain_break=True)
@example(ids=[1, 2, 3], listed=[1, 9, 3], pick=[], vanished={1}, address=126, length=3,
         stored=b"\xff\xff\xfd" * (PLAIN_END // 3) + b"\xff" * (PLAIN_END % 3), alerts=[0x20, 0],
         delays=[250], stale=False, since_s=0.0, chain_break=False)
@settings(max_examples=300, deadline=None)
def test_plain_sync_read_equals_the_listed_reads(ids, listed, pick, vanished, address, length, stored,
                                                  alerts, delays, stale, since_s, chain_break):
    """Any servos (some vanished), any listed IDs (absent ones, repeats), any plain range, any
    stored bytes (stuffing patterns), Alert bits and Return Delay Times, with or without the
    chain break: the fast Sync Read gives the general path's replies and leaves the same state."""
    listed = listed + [sorted(ids)[k % len(ids)] for k in pick]      # mostly servos that exist
    args = (ids, stored, alerts, delays, stale, since_s)
    fast, general = _servos(*args), _servos(*args)
    rules = DispatchRules(sync_chain_break=chain_break)

    def listening(servos):
        return [s for k, s in enumerate(servos) if k not in vanished]

    if address + length > PLAIN_END:
        length = PLAIN_END - address
    assert _plain_everywhere(listening(fast), address, length) == bool(listening(fast))
    fast_replies, fast_read = plain_sync_read(address, length, tuple(listed),
                                              {s.id: s for s in listening(fast)}, rules)
    items = [(i, address, length) for i in listed]
    replies, read = listed_reads(items, {s.id: s for s in listening(general)}, rules)
    assert fast_replies == replies
    assert [s.id for s in fast_read] == [s.id for s in read]
    assert _state(fast) == _state(general)


def test_a_range_with_indirect_data_or_outside_the_table_is_not_plain():
    servos = make_servos([1, 2], MODEL, 1_000_000)
    indirect_data = TABLE.indirect[0].data_start
    assert not _plain_everywhere(servos, indirect_data, 1)
    assert not _plain_everywhere(servos, indirect_data - 2, 4)
    assert not _plain_everywhere(servos, TABLE.size - 1, 2)
    assert not _plain_everywhere(servos, 0, 0)
    assert not _plain_everywhere([], 126, 10)
    assert _plain_everywhere(servos, 126, 10)


ITEMS = [r for r in TABLE]


@given(reg=st.sampled_from(ITEMS), data=st.data(), torque=st.booleans(), mode=st.sampled_from([0, 1, 3, 4, 5, 16]),
       tripped=st.booleans(), limits=st.tuples(st.integers(0, 1023), st.integers(0, 4095)))
@settings(max_examples=400, deadline=None)
def test_a_write_of_one_whole_item_equals_the_general_write(reg, data, torque, mode, tripped, limits):
    """A bus write covering exactly one item (fast path) gives the error or changed items and
    bytes of the general byte-by-byte write, for every item, any value bytes, torque on or off,
    any mode, a tripped watchdog, any limits."""
    raw = data.draw(st.binary(min_size=reg.size, max_size=reg.size) | st.lists(
        BYTES, min_size=reg.size, max_size=reg.size).map(bytes))
    memories = []
    for _ in range(2):
        m = make_servos([1], MODEL, 1_000_000)[0].memory
        m.set(Reg.OPERATING_MODE, mode)
        m.set(Reg.VELOCITY_LIMIT, limits[0])
        m.set(Reg.MAX_POSITION_LIMIT, limits[1])
        m.set(Reg.TORQUE_ENABLE, int(torque))
        m.watchdog_tripped = tripped
        memories.append(m)
    fast, general = memories
    general._write_layouts[(reg.address, reg.size)] = None     # no layout: the general path

    def outcome(m):
        try:
            return m.write(reg.address, raw)
        except WriteRejected as exc:
            return exc.number

    assert outcome(fast) == outcome(general)
    assert fast.stored_bytes(fast.size) == general.stored_bytes(general.size)


def _searched_delivery(settings_, arrivals, last_send_s):
    """:func:`deliver` with every packet's end found by a search over its bytes (the rule as
    the docstring states it, no shortcut)."""
    latency, cap, frame = settings_.latency_s, settings_.payload_bytes, settings_.frame_s
    packets, t_ref, i, n = [], last_send_s, 0, len(arrivals)
    while i < n:
        first = max(arrivals[i], t_ref)
        expiry = t_ref + max(1, math.ceil((first - t_ref) / latency - 1e-6)) * latency
        j = bisect_right(arrivals, expiry + 1e-6 * frame, i, min(n, i + cap))
        sent = max(arrivals[j - 1], t_ref) if j - i == cap else expiry
        t_ref = math.ceil(sent / frame - 1e-6) * frame
        if j > i:
            packets.append((j, t_ref))
        i = j
    return Delivery(tuple(packets), t_ref)


@given(st.floats(0.0, 100.0), st.lists(st.tuples(st.floats(0.0, 3e-3), st.integers(0, 200)), max_size=10),
       st.sampled_from([10 / 1_000_000, 10 / 57_600, 10 / 4_500_000]), st.sampled_from([1, 2, 16, 255]),
       st.floats(0.0, 100.0), st.sampled_from([62, 1, 7]))
@example(12.345, [(50e-6, 21)] * 8, 1e-5, 1, 12.0, 62)
@settings(max_examples=300, deadline=None)
def test_delivery_equals_a_search_of_every_packet(start_s, frames, byte_s, latency_ms, last_s, payload):
    """Packets found from their last byte's time first give the delivery a search over each
    packet's bytes gives, for lazy and listed arrival times."""
    s = AdapterSettings(latency_ms, payload_bytes=payload)
    lazy = byte_arrivals(start_s, frames, byte_s)
    expected = _searched_delivery(s, list(lazy), last_s)
    for arrivals in (lazy, list(lazy)):
        got = deliver(s, arrivals, last_s)
        assert (got.packets, got.last_send_s) == (expected.packets, expected.last_send_s)


PUBLISHED = sorted(str(n) for n in make_servos([1], MODEL, 1_000_000)[0].memory.published)
#: Reads of a Sync Read of the control cycle (126..135), of parts of it, and of any other range.
RANGES = st.sampled_from([(126, 10), (126, 2), (128, 4), (132, 4), (128, 8)]) | st.tuples(
    st.integers(0, PLAIN_END - 1), st.integers(1, 40)).map(lambda r: (r[0], min(r[1], PLAIN_END - r[0])))
OPS = st.lists(st.one_of(
    st.tuples(st.just("steps"), st.integers(1, 40)),
    st.tuples(st.just("read"), RANGES),
    st.tuples(st.just("get"), st.sampled_from(PUBLISHED)),
    st.tuples(st.just("set"), st.sampled_from(PUBLISHED)),
    st.tuples(st.just("goal"), st.integers(-200, 200)),
    st.tuples(st.just("hwerror"), st.sampled_from([0x04, 0x20])),
    st.tuples(st.just("reboot"), st.none())), max_size=25)


def _physics_bus(seed: int, noise: bool, mode: int):
    """Two servos with physics (sensor noise drawn from one generator), torque on in ``mode``."""
    spec = f"current=0.003,voltage=0.05,seed={seed}" if noise else f"seed={seed}"
    emu = build_emulator(physics=PHYSICS, ids=[1, 2], noise=spec)
    for s in emu.servos:
        s.write(Reg.OPERATING_MODE, mode)
        s.write(Reg.TORQUE_ENABLE, 1)
    return emu


@given(seed=st.integers(0, 2**32 - 1), noise=st.booleans(), mode=st.sampled_from([1, 3, 16]), ops=OPS)
@example(seed=1, noise=True, mode=1, ops=[("steps", 5), ("read", (126, 10)), ("read", (126, 10)),
                                          ("get", "present_input_voltage"), ("steps", 3), ("read", (128, 4)),
                                          ("steps", 2), ("read", (120, 30))])
@example(seed=2, noise=False, mode=3, ops=[("steps", 5), ("read", (126, 10)), ("set", "present_temperature"),
                                          ("get", "present_temperature")])
@settings(max_examples=40, deadline=None)
def test_publishing_the_motion_items_alone_equals_publishing_every_item(seed, noise, mode, ops):
    """Any steps, reads (the cycle's Sync Read, parts of it, any plain range), item gets and
    sets, goal writes, Hardware Errors and reboots, with sensor noise or without: reading through the plain
    read (which publishes Present Current, Velocity and Position alone when the range lies in
    them) gives the bytes the general read gives (which publishes every item), the same noise
    draws, and the same table afterwards."""
    fast, general = _physics_bus(seed, noise, mode), _physics_bus(seed, noise, mode)
    for op, arg in ops:
        outcome = []
        for emu in (fast, general):
            servo = emu.servos[0]
            if op == "steps":
                emu.advance(arg / emu.rate_hz)
                outcome.append(None)
            elif op == "read":
                address, length = arg
                if emu is fast:
                    outcome.append([bytes(s.plain_read_reply(address, address + length)[0]) for s in emu.servos])
                else:
                    outcome.append([bytes(s.read_frame(address, length)) for s in emu.servos])
            elif op == "get":
                outcome.append([s.read(arg) for s in emu.servos])
            elif op == "set":
                servo.write(arg, 1)
                outcome.append(None)
            elif op == "goal":
                outcome.append([s.bus_write(TABLE[Reg.GOAL_VELOCITY if mode == 1 else Reg.GOAL_POSITION].address,
                                            (arg + 2048 * (mode != 1)).to_bytes(4, "little", signed=True))
                                for s in emu.servos])
            elif op == "hwerror":
                servo.raise_hardware_error(arg)
                outcome.append(None)
            else:
                servo.reboot()
                outcome.append(None)
        assert outcome[0] == outcome[1], op
    for emu in (fast, general):
        for s in emu.servos:
            s.memory.publish()
    assert [s.memory.stored_bytes(s.memory.size) for s in fast.servos] == \
        [s.memory.stored_bytes(s.memory.size) for s in general.servos]
    assert fast.servos[0].dynamics.model.rng.bit_generator.state == \
        general.servos[0].dynamics.model.rng.bit_generator.state
