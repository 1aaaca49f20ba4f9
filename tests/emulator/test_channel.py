"""The emulator process's channel: values cross both ways unchanged, a closed end is EOF, poll waits."""
import socket
import threading

import pytest
from hypothesis import given, settings, strategies as st

from swerve.emulator.channel import Channel

values = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text() | st.binary(),
    lambda inner: st.lists(inner, max_size=5) | st.tuples(inner, inner)
    | st.dictionaries(st.text(max_size=8), inner, max_size=5),
    max_leaves=30)


def _pair():
    a, b = socket.socketpair()
    return Channel(a), Channel(b)


@settings(max_examples=60, deadline=None)
@given(sent=st.lists(values, min_size=1, max_size=4))
def test_values_cross_both_ways_unchanged(sent):
    a, b = _pair()
    try:
        for v in sent:
            a.send(v)
            b.send(v)
        assert [b.recv() for _ in sent] == sent
        assert [a.recv() for _ in sent] == sent
    finally:
        a.close()
        b.close()


def test_a_value_larger_than_the_socket_buffer_crosses():
    a, b = _pair()
    big = ("stats", {"blob": bytes(range(256)) * 8192})       # 2 MiB
    sender = threading.Thread(target=a.send, args=(big,))
    sender.start()
    assert b.recv() == big
    sender.join()
    a.close()
    b.close()


def test_poll_waits_for_a_value_and_a_closed_end_is_eof():
    a, b = _pair()
    assert not b.poll(0.01)
    a.send("stop")
    assert b.poll(1.0) and b.recv() == "stop"
    a.close()
    assert b.poll(1.0)                  # the close is readable
    with pytest.raises(EOFError):
        b.recv()
    with pytest.raises(OSError):        # the other end is gone
        b.send("x")
        b.send("x" * 100_000)
    b.close()


def test_a_close_in_the_middle_of_a_value_is_eof():
    a, b = _pair()
    raw = a._sock
    raw.sendall(b"\x00\x00\x01\x00" + b"partial")        # announces 256 bytes, sends 7
    raw.close()
    with pytest.raises(EOFError):
        b.recv()
    b.close()


def test_an_inherited_descriptor_is_an_end():
    a, b = socket.socketpair()
    end = Channel.from_fd(b.detach())
    Channel(a).send(("port", ("/dev/pts/9", None)))
    assert end.recv() == ("port", ("/dev/pts/9", None))
    a.close()
    end.close()
