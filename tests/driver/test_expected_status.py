"""The parser's shortcut for expected statuses (a Sync Read's replies) against its general path.

:meth:`PacketParser.expect_statuses` lets whole frames of the expected statuses be decoded by
their cached heads (:class:`ExpectedStatus`). Over every stream — clean replies, error bytes,
stuffed data, flipped bits, wrong CRCs, frames cut short, frames from other IDs or of other
lengths, garbage, any chunking, extra bytes — a parser with the expectation must return the same
packets, keep the same errors and count the same work as one without it.
"""
from hypothesis import example, given, settings, strategies as st

from swerve.driver import packets as P
from swerve.driver.packets import STATUS_HEAD_BYTES, ExpectedStatus, StatusPacket
from swerve.driver.parser import PacketParser

ids = st.integers(0, 252)
#: Data with the byte patterns that need stuffing, or that look like a header, now and then.
data_bytes = st.one_of(st.binary(max_size=24),
                       st.lists(st.sampled_from([b"\xff\xff\xfd", b"\xff", b"\xfd", b"\x00", b"\x55",
                                                 b"\xff\xff\xfd\x00", b"\xff\xff\xfd\xfd"]),
                                max_size=8).map(b"".join))


@st.composite
def frames(draw, expected: list[int], length: int) -> bytes:
    """One frame as it may arrive: mostly an expected reply, sometimes damaged or different."""
    id_ = draw(st.one_of(st.sampled_from(expected), ids))
    kind = draw(st.sampled_from(["clean", "clean", "clean", "error", "stuffed", "unstuffed", "flip", "crc",
                                 "cut", "length", "garbage"]))
    data = draw(st.binary(min_size=length, max_size=length))
    if kind in ("stuffed", "unstuffed"):
        data = (draw(data_bytes) + data)[:length].ljust(length, b"\xfd")
    if kind == "length":
        data = draw(data_bytes)
    error = draw(st.integers(1, 255)) if kind == "error" else 0
    if kind == "unstuffed":     # sent without stuffing (a right CRC over FF FF FD .. as it stands)
        frame = bytearray(P._frame(id_, bytes((P.Instruction.STATUS, 0)) + data, stuffed=False))
    else:
        frame = bytearray(StatusPacket(id_, error, data).encode())
    if kind == "flip":
        frame[draw(st.integers(0, len(frame) - 1))] ^= 1 << draw(st.integers(0, 7))
    elif kind == "crc":
        frame[-1 - draw(st.integers(0, 1))] ^= draw(st.integers(1, 255))
    elif kind == "cut":
        del frame[draw(st.integers(0, len(frame) - 1)):]
    elif kind == "garbage":
        frame = bytearray(draw(st.binary(max_size=30))) + frame
    return bytes(frame)


@st.composite
def replies(draw):
    """``(expected IDs, data length, stream, chunk sizes)``."""
    expected = draw(st.lists(ids, min_size=1, max_size=8, unique=True))
    length = draw(st.integers(0, 12))
    stream = b"".join(draw(st.lists(frames(expected, length), min_size=1, max_size=10)))
    stream += draw(st.one_of(st.just(b""), st.binary(max_size=12)))     # extra bytes after
    cuts = draw(st.one_of(st.just([len(stream) or 1]), st.lists(st.integers(1, 40), min_size=1, max_size=8)))
    return expected, length, stream, cuts


def _state(parser: PacketParser) -> tuple:
    """What a parser shows: counters, pending bytes, the errors it kept (messages)."""
    return (parser.scanned_bytes, parser.dropped_bytes, parser.bad_frames, parser.pending,
            [str(e) for e in parser.take_errors()])


def _run(parser: PacketParser, stream: bytes, cuts: list[int]) -> list:
    """Each feed's packets and the parser's state after it, then the flush's."""
    out, pos, k = [], 0, 0
    while pos < len(stream):
        n = cuts[k % len(cuts)]
        out.append((parser.feed(stream[pos:pos + n]), _state(parser)))
        pos, k = pos + n, k + 1
    out.append((parser.flush(), _state(parser)))
    return out


def _expected(ids_: list[int], length: int) -> dict[int, ExpectedStatus]:
    return {i: ExpectedStatus.of(i, length) for i in ids_}


@settings(max_examples=400, deadline=None)
@given(replies())
@example(([1, 2, 3], 10, b"".join(StatusPacket(i, 0, bytes(range(i, i + 10))).encode() for i in (1, 2, 3)), [63]))
@example(([5], 3, StatusPacket(5, 0, b"\xff\xff\xfd").encode(), [100]))          # stuffed: general path
@example(([5], 4, StatusPacket(5, 0x80, b"\x01\x02\x03\x04").encode(), [100]))   # alert bit: general path
@example(([5], 4, StatusPacket(5, 0, b"\xff\xff\xfd").encode(), [100]))  # stuffed to 4 bytes: unstuffed to 3
@example(([5], 4, P._frame(5, b"\x55\x00\xff\xff\xfd\x00", stuffed=False), [100]))    # a header in the data
@example(([5], 4, StatusPacket(5, 0, b"\x01\x02\x03\x04").encode()[:-3], [100]))  # cut short
@example(([5, 6], 2, StatusPacket(5, 0, b"\x01\x02").encode()[:7] + StatusPacket(6, 0, b"\x03\x04").encode(), [3]))
def test_expected_statuses_decode_as_the_general_path(reply):
    expected, length, stream, cuts = reply
    fast = PacketParser()
    fast.expect_statuses(_expected(expected, length))
    assert _run(fast, stream, cuts) == _run(PacketParser(), stream, cuts)


@settings(max_examples=200, deadline=None)
@given(st.lists(ids, min_size=1, max_size=8, unique=True), st.integers(0, 12), st.data())
def test_a_parser_with_a_small_max_length_rejects_expected_statuses_as_before(expected, length, data):
    frames_ = [StatusPacket(i, 0, data.draw(st.binary(min_size=length, max_size=length))).encode()
               for i in expected]
    max_length = data.draw(st.integers(3, 20))
    fast = PacketParser(max_length)
    fast.expect_statuses(_expected(expected, length))
    stream = b"".join(frames_)
    assert _run(fast, stream, [len(stream)]) == _run(PacketParser(max_length), stream, [len(stream)])


@settings(max_examples=500, deadline=None)
@given(ids, st.integers(0, 12), st.binary(max_size=40), st.data())
def test_expected_status_decode_is_status_decode_or_none(id_, length, tail, data):
    frame = data.draw(st.one_of(frames([id_], length), st.binary(max_size=30)))
    expected = ExpectedStatus.of(id_, length)
    got = expected.decode(frame + tail)
    whole = frame[:expected.frame_bytes]
    try:
        general = StatusPacket.decode(whole)
    except (P.CorruptPacketError, ValueError):
        general = None
    if got is not None:
        assert got == general
    else:   # declined: not a whole, clean, unstuffed, error-free frame of this shape
        assert (general is None or general != StatusPacket(id_, 0, general.params)
                or len(general.params) != length or P._STUFF_PATTERN in whole[STATUS_HEAD_BYTES:-2]
                or len(frame) < expected.frame_bytes)


def test_a_clean_reply_takes_the_cached_heads(monkeypatch):
    """Each frame of a clean reply is decoded by its :class:`ExpectedStatus` (the shortcut runs)."""
    calls = []
    original = ExpectedStatus.decode
    monkeypatch.setattr(ExpectedStatus, "decode", lambda self, buf: calls.append(self.id) or original(self, buf))
    pkts = [StatusPacket(i, 0, bytes((i,)) * 10) for i in (1, 2, 3, 4, 5, 6, 7, 8)]
    parser = PacketParser()
    parser.expect_statuses(_expected(list(range(1, 9)), 10))
    assert parser.feed(b"".join(p.encode() for p in pkts)) == pkts
    assert calls == list(range(1, 9))
    parser.expect_statuses(None)
    assert parser.feed(pkts[0].encode()) == pkts[:1] and calls == list(range(1, 9))


def test_expected_status_checks_its_arguments():
    import pytest

    with pytest.raises(ValueError, match="ID"):
        ExpectedStatus.of(253, 4)
    with pytest.raises(ValueError, match="length"):
        ExpectedStatus.of(1, P.MAX_LENGTH)
    e = ExpectedStatus.of(7, 10)
    assert e.head == StatusPacket(7, 0, bytes(10)).encode()[:STATUS_HEAD_BYTES]
    assert e.frame_bytes == len(StatusPacket(7, 0, bytes(10)).encode())
