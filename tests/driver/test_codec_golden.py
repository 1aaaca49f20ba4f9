"""Golden vectors from the e-Manual (docs/reference/protocol.md §1-2), both directions.

Decoding goes through :class:`PacketParser`, the path the bus and the emulator use
(parser -> ``decode_frame`` -> the ``decode`` of the packet's kind).
"""
import pytest

from swerve.driver import packets as P
from swerve.driver.errors import ChecksumError, CorruptPacketError
from swerve.driver.packets import FastStatus, InstructionPacket, StatusPacket
from swerve.driver.parser import PacketParser


def h(s: str) -> bytes:
    return bytes.fromhex(s)


def parse(wire: bytes, fast_lengths=None):
    """The one packet ``wire`` decodes to through the parser, fed whole and byte by byte."""
    whole, dribble = PacketParser(), PacketParser()
    whole.expect_fast(fast_lengths)
    dribble.expect_fast(fast_lengths)
    got = whole.feed(wire)
    got_dribbled = [p for b in wire for p in dribble.feed(bytes((b,)))]
    assert got == got_dribbled and len(got) == 1, (got, whole.take_errors())
    assert whole.pending == 0 and not whole.errors
    return got[0]


INSTRUCTIONS = [
    ("ping", P.ping(1), "FF FF FD 00 01 03 00 01 19 4E"),
    ("ping_broadcast", P.ping(0xFE), "FF FF FD 00 FE 03 00 01 31 42"),
    ("read", P.read(1, 132, 4), "FF FF FD 00 01 07 00 02 84 00 04 00 1D 15"),
    ("write", P.write(1, 116, (512).to_bytes(4, "little")),
     "FF FF FD 00 01 09 00 03 74 00 00 02 00 00 CA 89"),
    ("reg_write", P.reg_write(1, 104, (200).to_bytes(4, "little")),
     "FF FF FD 00 01 09 00 04 68 00 C8 00 00 00 AE 8E"),
    ("action", P.action(1), "FF FF FD 00 01 03 00 05 02 CE"),
    ("factory_reset", P.factory_reset(1, P.ResetOption.EXCEPT_ID), "FF FF FD 00 01 04 00 06 01 A1 E6"),
    ("reboot", P.reboot(1), "FF FF FD 00 01 03 00 08 2F 4E"),
    ("clear", P.clear(1), "FF FF FD 00 01 08 00 10 01 44 58 4C 22 B1 DC"),
    ("backup_store", P.control_table_backup(1), "FF FF FD 00 01 08 00 20 01 43 54 52 4C 16 F5"),
    # the e-Manual prints 92 F5; the correct CRC is 9E F5 (docs/reference/protocol.md §1)
    ("backup_restore", P.control_table_backup(1, restore=True),
     "FF FF FD 00 01 08 00 20 02 43 54 52 4C 9E F5"),
    ("sync_read", P.sync_read(132, 4, [1, 2]), "FF FF FD 00 FE 09 00 82 84 00 04 00 01 02 CE FA"),
    ("sync_write", P.sync_write(116, 4, {1: (150).to_bytes(4, "little"), 2: (170).to_bytes(4, "little")}),
     "FF FF FD 00 FE 11 00 83 74 00 04 00 01 96 00 00 00 02 AA 00 00 00 82 87"),
    ("bulk_read", P.bulk_read([(1, 144, 2), (2, 146, 1)]),
     "FF FF FD 00 FE 0D 00 92 01 90 00 02 00 02 92 00 01 00 1A 05"),
    ("bulk_write", P.bulk_write([(1, 32, (160).to_bytes(2, "little")), (2, 31, bytes([80]))]),
     "FF FF FD 00 FE 10 00 93 01 20 00 02 00 A0 00 02 1F 00 01 00 50 B7 68"),
    ("fast_sync_read", P.sync_read(132, 4, [3, 7, 4], fast=True),
     "FF FF FD 00 FE 0A 00 8A 84 00 04 00 03 07 04 20 F2"),
    # the e-Manual prints CRC 20 F2 (copied from the line above); correct is DA 2D
    ("fast_bulk_read", P.bulk_read([(3, 132, 4), (7, 124, 2), (4, 146, 1)], fast=True),
     "FF FF FD 00 FE 12 00 9A 03 84 00 04 00 07 7C 00 02 00 04 92 00 01 00 DA 2D"),
    ("write_stuffed", P.write(1, 116, (-131073).to_bytes(4, "little", signed=True)),
     "FF FF FD 00 01 0A 00 03 74 00 FF FF FD FD FF 23 E5"),
]

STATUSES = [
    ("ping_status", StatusPacket(1, 0, h("06 04 26")), "FF FF FD 00 01 07 00 55 00 06 04 26 65 5D"),
    ("ping_status_id2", StatusPacket(2, 0, h("06 04 26")), "FF FF FD 00 02 07 00 55 00 06 04 26 6F 6D"),
    ("read_status", StatusPacket(1, 0, (166).to_bytes(4, "little")),
     "FF FF FD 00 01 08 00 55 00 A6 00 00 00 8C C0"),
    ("ok_status", StatusPacket(1, 0), "FF FF FD 00 01 04 00 55 00 A1 0C"),
    ("sync_status_id2", StatusPacket(2, 0, (2079).to_bytes(4, "little")),
     "FF FF FD 00 02 08 00 55 00 1F 08 00 00 BA BE"),
    ("bulk_status_id1", StatusPacket(1, 0, (119).to_bytes(2, "little")), "FF FF FD 00 01 06 00 55 00 77 00 C3 69"),
    ("bulk_status_id2", StatusPacket(2, 0, bytes([36])), "FF FF FD 00 02 05 00 55 00 24 8B A9"),
    ("status_stuffed", StatusPacket(1, 0, (-131073).to_bytes(4, "little", signed=True)),
     "FF FF FD 00 01 09 00 55 00 FF FF FD FD FF DA 9E"),
]


@pytest.mark.parametrize("pkt,wire", [(p, w) for _, p, w in INSTRUCTIONS], ids=[n for n, _, _ in INSTRUCTIONS])
def test_instruction_encode_and_decode(pkt, wire):
    assert pkt.encode() == h(wire)
    assert parse(h(wire)) == pkt


@pytest.mark.parametrize("pkt,wire", [(p, w) for _, p, w in STATUSES], ids=[n for n, _, _ in STATUSES])
def test_status_encode_and_decode(pkt, wire):
    assert pkt.encode() == h(wire)
    assert parse(h(wire)) == pkt


def test_crc_check_value():
    assert P.crc16(b"123456789") == 0xFEE8


def test_two_byte_crc_table_is_two_steps_of_the_byte_table():
    t = P._CRC_TABLE
    assert P._CRC_TABLE16 == [((t[h] << 8) & 0xFFFF) ^ t[lo ^ (t[h] >> 8)]
                              for h in range(256) for lo in range(256)]
    for data in (b"", b"\x01", b"\xff\xff\xfd\x00", bytes(range(256)) * 3):
        crc = 0
        for b in data:                  # the e-Manual's one-byte-at-a-time update
            crc = ((crc << 8) ^ t[(crc >> 8) ^ b]) & 0xFFFF
        assert P.crc16(data) == crc


FAST_SYNC = "FF FF FD 00 FE 19 00 55 00 03 A6 00 00 00 84 08 00 07 1F 08 00 00 16 CA 00 04 FF 03 00 00 D1 9E"
FAST_BULK = "FF FF FD 00 FE 14 00 55 00 03 A6 00 00 00 67 A4 00 07 A5 01 24 74 00 04 1F D9 C1"


def test_fast_sync_read_reply_both_directions():
    fs = FastStatus(tuple(StatusPacket(i, 0, v.to_bytes(4, "little")) for i, v in [(3, 166), (7, 2079), (4, 1023)]))
    assert fs.encode() == h(FAST_SYNC)
    assert parse(h(FAST_SYNC), [4, 4, 4]) == fs
    assert b"".join(fs.slices()) == h(FAST_SYNC)


def test_fast_bulk_read_reply_both_directions():
    fs = FastStatus((StatusPacket(3, 0, (166).to_bytes(4, "little")),
                     StatusPacket(7, 0, (421).to_bytes(2, "little")),
                     StatusPacket(4, 0, bytes([31]))))
    assert fs.encode() == h(FAST_BULK)
    assert parse(h(FAST_BULK), [4, 2, 1]) == fs


def test_unrequested_fast_reply_is_rejected_from_its_header():
    parser = PacketParser()
    assert parser.feed(h(FAST_SYNC)) == []
    assert "not requested" in str(parser.take_errors()[0])


def test_fast_reply_with_a_bad_entry_crc_names_it():
    wire = bytearray(h(FAST_SYNC))
    wire[14] ^= 1                       # first entry's running CRC
    parser = PacketParser()
    parser.expect_fast([4, 4, 4])
    assert parser.feed(bytes(wire)) == []
    assert isinstance(parser.take_errors()[0], ChecksumError)


def test_fast_reply_with_wrong_lengths_is_rejected():
    with pytest.raises(CorruptPacketError, match="expected"):
        FastStatus.decode(h(FAST_SYNC), [4, 4])
    parser = PacketParser()
    parser.expect_fast([4, 4])
    assert parser.feed(h(FAST_SYNC)) == []
    assert "expected" in str(parser.take_errors()[0])


def test_bad_crc_raises_with_fields():
    wire = bytearray(h("FF FF FD 00 01 03 00 01 19 4E"))
    wire[-1] ^= 0xFF
    parser = PacketParser()
    assert parser.feed(bytes(wire)) == []
    (err,) = parser.take_errors()
    assert isinstance(err, ChecksumError)
    assert err.expected == 0x4E19 and err.actual == 0xB119


def test_status_error_byte_decoding():
    st = P.StatusError.from_byte(0x87)
    assert st.alert and st.number == P.ErrorNumber.ACCESS
    assert st.to_byte() == 0x87
    assert P.StatusError.from_byte(0x00).ok
    assert StatusPacket(1, 0x84).error_number == P.ErrorNumber.DATA_RANGE


@pytest.mark.parametrize("bad", [lambda: P.ping(253), lambda: P.ping(-1),
                                 lambda: P.sync_write(116, 4, {1: b"\x00\x00"}),
                                 lambda: P.bulk_read([(1, 0, 2), (1, 2, 2)])],
                         ids=["id253", "negative", "short_sync_data", "bulk_dup"])
def test_builders_reject_bad_arguments(bad):
    with pytest.raises(ValueError):
        bad()


def test_param_parsers_invert_builders():
    sw = P.sync_write(116, 4, {1: b"abcd", 9: b"efgh"})
    assert P.parse_sync_write(sw.params) == (116, 4, {1: b"abcd", 9: b"efgh"})
    br = P.bulk_read([(3, 132, 4), (7, 124, 2)])
    assert P.parse_bulk_read(br.params) == [(3, 132, 4), (7, 124, 2)]
    bw = P.bulk_write([(1, 32, b"\xa0\x00"), (2, 31, b"P")])
    assert P.parse_bulk_write(bw.params) == [(1, 32, b"\xa0\x00"), (2, 31, b"P")]
    assert P.parse_sync_read(P.sync_read(132, 4, [1, 2]).params) == (132, 4, (1, 2))


@pytest.mark.parametrize("pkt", [
    P.ping(1),
    P.sync_read(126, 10, range(1, 9)),
    P.bulk_write([(1, 104, b"\x10\x00\x00\x00"), (5, 116, b"\x00\x08\x00\x00")]),
    P.write(3, 116, b"\xff\xff\xfd\x00"),                   # stuffed: one byte longer on the wire
    InstructionPacket(7, 0xFF, b"\xff\xfd\xff\xff\xfd"),    # the pattern across INST and params
], ids=["ping", "sync_read", "bulk_write", "stuffed_write", "stuffed_across_inst"])
def test_wire_length_is_the_encoded_length(pkt):
    assert pkt.wire_length() == len(pkt.encode())
