"""Incremental parser: arbitrary chunking, garbage, truncation, bad CRC; hypothesis round trips."""
import pytest
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


@given(st.one_of(ids, st.just(P.BROADCAST_ID)), st.integers(0, 255), payload)
def test_instruction_frame_is_the_general_frame(id_, inst, params):
    """The cached-head encoder gives the bytes of the general one, stuffing or not, twice."""
    for _ in range(2):
        assert P.instruction_frame(id_, inst, params) == P._frame(id_, bytes((inst,)) + params)


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


def _crc16_bitwise(data, crc=0):
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else crc << 1
            crc &= 0xFFFF
    return crc


@given(st.binary(max_size=300), st.binary(max_size=9))
def test_crc16_matches_the_bitwise_definition_and_continues(data, more):
    assert P.crc16(data) == _crc16_bitwise(data)
    assert P.crc16(more, P.crc16(data)) == _crc16_bitwise(data + more)
    assert P.crc16(memoryview(data)) == P.crc16(bytearray(data)) == _crc16_bitwise(data)


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


# --- hostile input: the work must stay linear in the bytes fed ---------------------------------

MIB = 1 << 20
#: Header whose LENGTH (0x0FA0) exceeds any packet a servo buffers.
BOMB_HUGE = b"\xff\xff\xfd\x00\x01\xa0\x0f"
#: Header whose LENGTH (1008) is legal: only the next header inside its body exposes it.
BOMB_LEGAL = b"\xff\xff\xfd\x00\x01\xf0\x03"
#: A scan/CRC budget per byte fed: header searches plus one checksum pass, with slack.
WORK_PER_BYTE = 3


def _feed_chunks(parser, data, chunk=4096):
    out = []
    for i in range(0, len(data), chunk):
        out += parser.feed(data[i:i + chunk])
    return out


def _mutated_frames(rng, nbytes):
    out = bytearray()
    while len(out) < nbytes:
        frame = bytearray(StatusPacket(rng.randrange(253), 0, rng.randbytes(rng.randrange(40))).encode())
        for _ in range(rng.randrange(1, 4)):
            frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
        out += frame[:rng.randrange(4, len(frame) + 1)]
    return bytes(out)


def test_max_length_is_the_sdk_packet_limit():
    # dynamixel-sdk protocol2_packet_handler: TXPACKET_MAX_LEN = RXPACKET_MAX_LEN = 1024 bytes
    assert P.MAX_LENGTH + 7 == 1024


@pytest.mark.parametrize("kind", ["bomb_huge", "bomb_legal", "bomb_mixed", "random", "mutated"])
def test_parser_finds_the_packet_after_1mib_of_garbage_in_linear_work(kind):
    import random

    rng = random.Random(7)
    garbage = {
        "bomb_huge": lambda: BOMB_HUGE * (MIB // len(BOMB_HUGE)),
        "bomb_legal": lambda: BOMB_LEGAL * (MIB // len(BOMB_LEGAL)),
        "bomb_mixed": lambda: (BOMB_HUGE + BOMB_LEGAL + b"\xff\xff\xfd\x00\xfe\x20\x00\x55")
        * (MIB // 22),
        "random": lambda: rng.randbytes(MIB),
        "mutated": lambda: _mutated_frames(rng, MIB),
    }[kind]()
    good = StatusPacket(1, 0, b"\x10\x20\x30\x40")
    parser = PacketParser()
    out = _feed_chunks(parser, garbage + good.encode())
    assert out[-1:] == [good]
    fed = len(garbage) + len(good.encode())
    assert parser.scanned_bytes <= WORK_PER_BYTE * fed, (parser.scanned_bytes, fed)


@settings(max_examples=30, deadline=None)
@given(st.lists(st.one_of(st.binary(max_size=200), st.just(BOMB_HUGE), st.just(BOMB_LEGAL),
                          st.builds(lambda n, k: StatusPacket(n, 0, bytes(k)).encode()[:-1],
                                    ids, st.integers(0, 30))),
                max_size=200),
       st.integers(1, 64))
def test_parser_work_is_linear_for_any_garbage(pieces, chunk):
    garbage = b"".join(pieces)
    good = P.ping(5)
    parser = PacketParser()
    out = _feed_chunks(parser, garbage + good.encode(), chunk)
    assert out[-1:] == [good]
    # each chunk may rescan a header prefix and a few bytes of a waiting header
    fed = len(garbage) + len(good.encode())
    assert parser.scanned_bytes <= WORK_PER_BYTE * fed + 16 * (fed // chunk + 1)


def test_flush_counts_the_slices_of_a_fast_reply_cut_short():
    fs = P.FastStatus(tuple(StatusPacket(i, 0, bytes((i,)) * 4) for i in (3, 7, 4)))
    slices = fs.slices()
    parser = PacketParser()
    parser.expect_fast([4, 4, 4])
    assert parser.feed(slices[0] + slices[1]) == []
    assert parser.flush() == []
    assert parser.fast_entries_received == 2
    parser.reset()
    assert parser.fast_entries_received is None
    assert parser.feed(b"".join(slices)) == [fs]
