"""Every shipped model through a second, independent client: rustypot (Pollen Robotics' Rust
Dynamixel library, PyPI ``rustypot``), beside dynamixel-sdk in test_conformance.py.

rustypot frames and parses packets in Rust, so it shares no code with dynamixel-sdk or the
project's codec. Its XL330 and XL430 servo definitions also carry their own control tables,
which the layout test compares with ours (``configs/models``).
"""
from __future__ import annotations

import pytest

from swerve.driver.control_table import Reg, models

from .conftest import check_reads_match, valid_value

rustypot = pytest.importorskip("rustypot")

IDS = [1, 2, 3, 4]
#: Seconds rustypot waits for a status packet (only absent IDs wait that long).
TIMEOUT_S = 1.0


def _controller_class(model: str):
    """rustypot's controller for the family; raw reads and writes work for any X-series model."""
    return rustypot.Xl330PyController if model.startswith("XL330") else rustypot.Xl430PyController


@pytest.fixture
def pot(model_emulator):
    c = _controller_class(model_emulator.model)(model_emulator.port, 1_000_000, TIMEOUT_S)
    yield c
    c.close()


def test_ping_and_model_number(model_emulator, pot):
    number = model_emulator.table.model_number
    assert all(pot.ping(i) for i in IDS)
    assert not pot.ping(9)
    assert [list(pot.read_model_number(i)) for i in IDS] == [[number]] * len(IDS)


def test_read_and_write_every_item(model_emulator, pot):
    table, servo = model_emulator.table, model_emulator.servo(2)
    check_reads_match(lambda reg: pot.read_raw_data_with_error(2, reg.address, reg.size), table, servo)
    for reg in (r for r in table if r.writable and not r.eeprom):
        value = valid_value(reg, servo)
        assert pot.write_raw_data_with_error(2, reg.address, list(reg.encode(value))) == 0, reg.name
        assert servo.read(reg.name) == value, reg.name


def test_out_of_range_write_is_refused(model_emulator, pot):
    mode = model_emulator.table[Reg.OPERATING_MODE]
    err = pot.write_raw_data_with_error(1, mode.address, [2])          # no X-series mode 2
    assert err & 0x7F == 0x04                                           # Data Range Error
    assert model_emulator.servo(1).read(Reg.OPERATING_MODE) == mode.default


def test_sync_write_then_sync_read(model_emulator, pot):
    gp = model_emulator.table[Reg.GOAL_POSITION]
    pot.sync_write_raw_data(IDS, gp.address, [list(gp.encode(40 * i)) for i in IDS])
    assert pot.ping(1)                       # no reply to a sync write: a round trip orders it
    got = pot.sync_read_raw_data(IDS, gp.address, 4)
    assert [gp.decode(bytes(b)) for b in got] == [40 * i for i in IDS]
    assert [model_emulator.servo(i).read(Reg.GOAL_POSITION) for i in IDS] == [40 * i for i in IDS]


def test_fast_sync_read(model_emulator, pot):
    pos = model_emulator.table[Reg.PRESENT_POSITION]
    for i in IDS:
        model_emulator.servo(i).write(Reg.PRESENT_POSITION, -13 * i)
    pot.set_fast_sync_read(True)
    got = pot.sync_read_raw_data(IDS, pos.address, 4)
    assert [pos.decode(bytes(b)) for b in got] == [-13 * i for i in IDS]
    assert model_emulator.stats.replies_sent >= len(IDS)


@pytest.mark.parametrize("model, controller", [("xl330-m288", "Xl330PyController"),
                                               ("xl330-m077", "Xl330PyController"),
                                               ("xl430-w250", "Xl430PyController")])
def test_control_table_layout_agrees_with_rustypot(model, controller):
    table = models()[model]
    theirs = {r.name: (r.addr, r.size) for r in getattr(rustypot, controller).registers()}
    shared = [r for r in table if r.name in theirs]
    assert len(shared) >= 45
    assert {r.name: (r.address, r.size) for r in shared} == {r.name: theirs[r.name] for r in shared}
    assert table.model_number in getattr(rustypot, controller).definition().models.values()
