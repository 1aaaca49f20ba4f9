"""Incremental parser: arbitrary chunking, garbage, truncation, bad CRC; hypothesis round trips."""
from hypothesis import given, settings, strategies as st

from swerve.driver import packets as P
from swerve.driver.packets import InstructionPacket, StatusPacket
from swerve.driver.parser import PacketParser

ids = st.integers(0, 252)
payload = st.one_of(st.binary(max_size=64),
                    st.lists(st.sampled_from([b"\xff\xff\xfd", b"\xff", b"\xfd", b"\x00", b"\xff\xff\xfd\xfd"]),
                             max_size=20).map(b"".join))


@given(ids, st.sampled_from([i for i in P.Instruction if i != P.Instruction.STATUS]), payload)
def test_instruction_round_trip(id_, inst, params):
    pkt = InstructionPacket(id_, inst, params)
    assert InstructionPacket.decode(pkt.encode()) == pkt


@given(ids, st.integers(0, 255), payload)
def test_status_round_trip(id_, err, params):
    pkt = StatusPacket(id_, err, params)
    assert StatusPacket.decode(pkt.encode()) == pkt


@given(payload)
def test_stuffing_inverts_and_removes_headers(body):
    stuffed = P.stuff(body)
    assert P.unstuff(stuffed) == body
    # after stuffing no FF FF FD is followed by anything but FD: no false header inside a frame
    i = stuffed.find(b"\xff\xff\xfd")
    while i >= 0:
        assert stuffed[i + 3:i + 4] == b"\xfd"
        i = stuffed.find(b"\xff\xff\xfd", i + 4)


@settings(max_examples=200)
@given(st.lists(st.tuples(ids, payload), min_size=1, max_size=6), st.lists(st.integers(1, 40), min_size=1),
       st.binary(max_size=30))
def test_parser_any_chunking_with_garbage(packets, cuts, garbage):
    pkts = [StatusPacket(i, 0, p) for i, p in packets]
    stream = garbage.replace(b"\xff\xff\xfd\x00", b"") + b"".join(p.encode() for p in pkts)
    parser, got, pos, k = PacketParser(), [], 0, 0
    while pos < len(stream):
        n = cuts[k % len(cuts)]
        got += parser.feed(stream[pos:pos + n])
        pos, k = pos + n, k + 1
    assert got == pkts


def test_parser_resyncs_after_bad_crc_and_truncation():
    good1, good2 = StatusPacket(1, 0, b"\x01\x02"), StatusPacket(2, 0, b"\x03")
    bad = bytearray(StatusPacket(3, 0, b"\x09" * 8).encode())
    bad[-1] ^= 1
    truncated = StatusPacket(4, 0, b"\x07" * 30).encode()[:12]  # claims more bytes than follow
    parser = PacketParser()
    out = parser.feed(b"\x00\xff\x12" + bytes(bad) + good1.encode() + truncated + good2.encode())
    # good2's header inside the truncated frame's claimed body ends that frame at once
    assert out == [good1, good2]
    errs = parser.take_errors()
    assert any("CRC" in str(e) for e in errs)
    assert parser.bad_frames >= 1


def test_parser_rejects_implausible_length_without_waiting():
    parser = PacketParser()
    junk = b"\xff\xff\xfd\x00\x01\xff\xff"  # LENGTH 65535
    assert parser.feed(junk + P.ping(1).encode()) == [P.ping(1)]
    assert "LENGTH" in str(parser.take_errors()[0])


def test_parser_keeps_split_header():
    pkt = P.ping(7)
    parser = PacketParser()
    assert parser.feed(b"\x11\x22" + pkt.encode()[:2]) == []
    assert parser.feed(pkt.encode()[2:]) == [pkt]


def test_flush_leaves_nothing_pending():
    parser = PacketParser()
    good = P.ping(3)
    assert parser.feed(b"\xff\xff\xfd\x00\x01\x20\x00" + good.encode() + b"\xff\xff") == [good]
    assert parser.feed(b"\xfd\x00\x01\x20\x00\x03\x01") == []    # a frame cut short
    assert parser.flush() == []
    assert parser.pending == 0
    assert parser.feed(P.ping(4).encode()) == [P.ping(4)]
