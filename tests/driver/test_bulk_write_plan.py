"""A Bulk Write from a precomputed plan (one struct, bounds checked up front) must send the bytes
the item-by-item encoding sends, and refuse the values it refuses, for any registers and values."""
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swerve.driver import packets as pk
from swerve.driver.bus import Bus
from swerve.driver.errors import OutOfRangeError
from swerve.driver.robot_config import load_robot_config

TABLE = load_robot_config().table
#: Runs of writable items with no gap between them: what one servo's part of a Bulk Write can hold.
RUNS = []
for first in sorted((r for r in TABLE.registers.values() if r.writable), key=lambda r: r.address):
    run, end = [first], first.address + first.size
    for r in sorted(TABLE.registers.values(), key=lambda r: r.address):
        if r.address == end and r.writable:
            run.append(r)
            end += r.size
    for k in range(1, min(len(run), 3) + 1):
        RUNS.append(tuple(run[:k]))


@pytest.fixture(scope="module")
def bus():
    with Bus("loop://", 1_000_000, default_model=TABLE.model) as b:
        yield b


def _item_by_item(items):
    """The parameters as ``Register.check_raw`` / ``encode`` and ``packets.bulk_write`` make them."""
    entries = []
    for i, regs, values in items:
        entries.append((i, regs[0].address, b"".join(r.encode(r.check_raw(int(v))) for r, v in zip(regs, values))))
    return pk.bulk_write(entries).params


@st.composite
def writes(draw):
    ids = draw(st.lists(st.integers(0, pk.MAX_ID), min_size=1, max_size=8, unique=True))
    out = []
    for i in ids:
        regs = draw(st.sampled_from(RUNS))
        values = [draw(st.one_of(st.integers(*r.raw_bounds()), st.integers(-2**33, 2**33))) for r in regs]
        out.append((i, regs, values))
    return out


@settings(max_examples=300, deadline=None)
@given(writes())
@example([(1, (TABLE["goal_velocity"],), [TABLE["goal_velocity"].raw_bounds()[1] + 1])])
@example([(5, (TABLE["goal_position"],), [-(2**31)])])
def test_plan_sends_the_item_by_item_bytes(bus, items):
    plan = bus.bulk_write_plan([(i, tuple(r.name for r in regs)) for i, regs, _ in items])
    values = [v for _, _, vs in items for v in vs]
    try:
        expected = _item_by_item(items)
    except OutOfRangeError as exc:
        with pytest.raises(OutOfRangeError) as got:
            plan.params(values)
        assert str(got.value) == str(exc)
        return
    assert plan.params(values) == expected


def test_plan_refuses_a_repeated_id_and_a_wrong_count(bus):
    with pytest.raises(ValueError, match="appears twice"):
        bus.bulk_write_plan([(1, ("goal_velocity",)), (1, ("goal_position",))])
    plan = bus.bulk_write_plan([(1, ("goal_velocity",))])
    with pytest.raises(ValueError, match="takes 1 values, got 2"):
        plan.params([0, 0])
