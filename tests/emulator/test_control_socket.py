"""The lockstep control socket against hostile clients: the bus never goes deaf.

Hypothesis draws what a client may send (random bytes, overlong lines, floods of requests it
never reads the replies of, numbers at and beyond every limit). After each, the bus must still
answer a Ping on the pty, and a well-behaved client connecting afterwards must still be served.
"""
from __future__ import annotations

import socket
import time

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from swerve.configs import shipped
from swerve.driver.bus import Bus
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.clock import LockstepPhysicsClock, WallPhysicsClock
from swerve.emulator.lockstep_socket import MAX_ADVANCE_S, MAX_CLIENTS, MAX_LINE_BYTES, MAX_TX_BYTES, ControlServer
from swerve.emulator.physics.params import load_config
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.factory import build_emulator
from swerve.emulator.server import Emulator
from swerve.emulator.servo import make_servos
from swerve.emulator.timing import Lockstep

#: First words of every reply line the protocol defines.
REPLY_WORDS = {"at", "pose", "ok", "stats", "info", "error"}
#: Wall-clock bound on one reply, s (the test fails rather than hangs; verdicts never depend on it).
REPLY_WAIT_S = 30.0
#: The emulator's wait for pty bytes a request announces, s. No test here writes the bytes a
#: control request announces, so every such wait ends in its timeout and an ``error`` reply,
#: whatever its length; a short one keeps a hostile ``now 7`` from holding the bus for the
#: default 10 s.
BARRIER_TIMEOUT_S = 0.02


@pytest.fixture(scope="module")
def lockstep_robot():
    """A lockstep robot emulator (8 servos and a body) and a driver on its pty."""
    robot = load_robot_config(shipped("robot.yaml"))
    timing = Lockstep(barrier_timeout_s=BARRIER_TIMEOUT_S)
    with build_emulator(robot, load_config(shipped("emulator.yaml")), timing=timing, body=BodySettings()) as emu:
        # no lockstep clock gates this bus's replies, so its deadline is a wall-clock bound that
        # only turns a deaf bus into a failure (a loaded host must not)
        with Bus(emu.port, 1_000_000, default_model="xh430-w210", timeout_margin_s=REPLY_WAIT_S) as bus:
            yield emu, bus


def _connect(path: str) -> socket.socket:
    """A client connection (waits while the listener's backlog is full)."""
    s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    s.connect(path)                 # blocking: returns once the bus thread has room for it
    s.settimeout(REPLY_WAIT_S)
    return s


def _lines(sock: socket.socket, n: int) -> list[str]:
    """``n`` reply lines (fewer if the server closes the connection)."""
    buf = b""
    while buf.count(b"\n") < n:
        try:
            chunk = sock.recv(65536)
        except ConnectionResetError:
            break
        if not chunk:
            break
        buf += chunk
    return [ln.decode("ascii") for ln in buf.split(b"\n")[:n] if ln or buf.count(b"\n") >= n]


def _assert_alive(emu, bus) -> None:
    """A new client's requests are answered, and the bus answers a Ping.

    The client first restores every servo: a hostile client may have sent a well-formed
    ``fault 0 vanish ID``, which silences that servo by design (and would silence it for the
    next examples too, since the emulator is shared).
    """
    deadline = time.monotonic() + REPLY_WAIT_S
    while True:         # clients a test just closed hold their slots until the bus thread sees them go
        with _connect(emu.control.path) as good:
            good.sendall(b"".join(b"fault 0 restore %d\n" % i for i in range(1, 9)) + b"now 0\n")
            replies = _lines(good, 9)
        if not (replies and replies[0].startswith("error more than")) or time.monotonic() > deadline:
            break
        time.sleep(0.01)
    assert replies[:8] == ["ok"] * 8 and replies[8].startswith("at "), replies
    assert bus.ping(1).model_number > 0


# one hostile client's action: (name, payload, keep the connection open while the bus is pinged)
_number_text = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(min_value=-10**30, max_value=10**30).map(str),
    st.sampled_from(["1e300", "-1e300", "1e-300", "nan", "inf", "-inf", "9" * 300, "0x10", "", "1_0"]),
)
_request = st.tuples(
    st.sampled_from(["advance", "now", "pose", "fault", "info", "stats", "advance", ""]),
    st.lists(_number_text, max_size=3),
).map(lambda t: " ".join([t[0], *t[1]]).encode("ascii"))
_fault = st.tuples(
    st.sampled_from(["vanish", "restore", "hwerror", "explode"]),
    st.lists(_number_text, min_size=1, max_size=2),
).map(lambda t: " ".join(["fault", "0", t[0], *t[1]]).encode("ascii"))
_action = st.one_of(
    st.tuples(st.just("bytes"), st.binary(min_size=1, max_size=4096), st.booleans()),
    st.tuples(st.just("long line"), st.integers(MAX_LINE_BYTES - 2, 4 * MAX_LINE_BYTES).map(lambda n: b"a" * n),
              st.booleans()),
    st.tuples(st.just("stalled"), st.integers(1, 20_000).map(lambda n: b"info\n" * n), st.just(True)),
    st.tuples(st.just("request"), st.lists(st.one_of(_request, _fault), min_size=1, max_size=8)
              .map(lambda rs: b"\n".join(rs) + b"\n"), st.booleans()),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                 HealthCheck.too_slow])
@given(action=_action)
@example(action=("bytes", b"\xe9\n", False))
@example(action=("request", b"fault 0 vanish 1\n", True))
@example(action=("request", b"advance 1e300 0\n", False))
@example(action=("request", b"now 7\nfault 1_0 vanish 1\nnow 0\n", True))
@example(action=("request", b"advance nan 0\nadvance inf 0\nnow -1\nnow 99999999999999999999\n", False))
@example(action=("long line", b"a" * (10 * MAX_LINE_BYTES), True))
@example(action=("stalled", b"info\n" * 20_000, True))
def test_no_client_makes_the_bus_deaf(lockstep_robot, action):
    emu, bus = lockstep_robot
    kind, payload, keep_open = action
    hostile = _connect(emu.control.path)
    try:
        try:
            hostile.sendall(payload)
        except OSError:                 # dropped while sending: that is allowed
            keep_open = False
        if kind == "request":           # a client that reads gets one well-formed line per request
            replies = _lines(hostile, payload.count(b"\n"))
            assert len(replies) == payload.count(b"\n")
            assert all(r.split(" ", 1)[0] in REPLY_WORDS for r in replies), replies
        if not keep_open:
            hostile.close()
        _assert_alive(emu, bus)
    finally:
        hostile.close()


def test_extreme_requests_get_error_lines(lockstep_robot):
    emu, bus = lockstep_robot
    with _connect(emu.control.path) as c:
        c.sendall(b"now 0\n")
        (now,) = _lines(c, 1)
        t0 = float(now.split()[1])
        requests = [f"advance {t0 + MAX_ADVANCE_S * 2!r} 0", "advance 1e300 0", "advance nan 0",
                    f"now {MAX_TX_BYTES + 1}", "now -1", "\xe9".encode("latin-1").decode("latin-1")]
        c.sendall("\n".join(requests).encode("latin-1") + b"\n")
        replies = _lines(c, len(requests))
    assert [r.split(" ", 1)[0] for r in replies] == ["error"] * len(requests), replies
    assert "refused" in replies[0] and "not ASCII" in replies[-1]
    _assert_alive(emu, bus)


def test_announced_bytes_that_never_arrive_get_an_error(lockstep_robot):
    """A request announcing pty bytes nobody writes is answered after the barrier timeout (the
    emulator's setting), and the connection serves the next request from where the bytes stand."""
    emu, bus = lockstep_robot
    assert emu.control.barrier_timeout_s == BARRIER_TIMEOUT_S
    with _connect(emu.control.path) as c:
        c.sendall(b"now 7\nnow 0\n")
        replies = _lines(c, 2)
    assert replies[0] == f"error only 0 of the 7 announced bytes arrived within {BARRIER_TIMEOUT_S:g} s", replies
    assert replies[1].startswith("at "), replies
    _assert_alive(emu, bus)


@pytest.mark.parametrize("timeout_s", [0.0, -1.0, float("nan"), float("inf")])
def test_barrier_timeout_must_be_positive_and_finite(tmp_path, timeout_s):
    with pytest.raises(ValueError, match="barrier timeout must be a finite number of seconds > 0"):
        ControlServer(tmp_path / "c.sock", barrier_timeout_s=timeout_s)
    assert not (tmp_path / "c.sock").exists()


def test_an_overlong_line_drops_only_that_client(lockstep_robot):
    emu, bus = lockstep_robot
    with _connect(emu.control.path) as bystander, _connect(emu.control.path) as c:
        c.sendall(b"x" * (MAX_LINE_BYTES + 10))
        (reply,) = _lines(c, 1)
        assert reply.startswith("error") and "longer than" in reply
        assert c.recv(1) == b""                          # disconnected
        bystander.sendall(b"now 0\n")
        assert _lines(bystander, 1)[0].startswith("at ")
    _assert_alive(emu, bus)


def test_a_flood_of_connections_is_capped(lockstep_robot):
    emu, bus = lockstep_robot
    socks = [_connect(emu.control.path) for _ in range(MAX_CLIENTS + 4)]
    try:
        for s in socks:                     # every connection is served in turn, or told it is one too many
            try:
                s.sendall(b"now 0\n")
            except (BrokenPipeError, ConnectionResetError):
                pass                        # one too many: already told so and closed by the emulator
        replies = [(_lines(s, 1) or ["(closed)"])[0] for s in socks]
    finally:
        for s in socks:
            s.close()
    assert sum(r.startswith("at ") for r in replies) >= MAX_CLIENTS - 1      # the fixture's own may hold one
    assert all(r.startswith(("at ", "error more than")) or r == "(closed)" for r in replies), replies
    _assert_alive(emu, bus)


def test_control_path_on_an_existing_file_is_refused(tmp_path):
    victim = tmp_path / "notes.txt"
    victim.write_text("keep me")
    with pytest.raises(FileExistsError, match="exists and is not a socket"):
        ControlServer(victim)
    assert victim.read_text() == "keep me"
    stale = tmp_path / "stale.sock"
    old = socket.socket(socket.AF_UNIX)
    old.bind(str(stale))
    old.close()                                          # a socket file left behind is replaced
    ControlServer(stale).close()


@pytest.mark.parametrize("clock", [None, WallPhysicsClock(1.0)], ids=["frozen", "wall"])
def test_control_channel_needs_a_clock_that_keeps_robot_time(tmp_path, clock):
    control = ControlServer(tmp_path / "c.sock")
    try:
        with pytest.raises(ConfigError, match="needs a lockstep clock"):
            Emulator(make_servos([1], "xh430-w210", 1_000_000), clock=clock, control=control)
        Emulator(make_servos([1], "xh430-w210", 1_000_000), clock=LockstepPhysicsClock(), control=control)
    finally:
        control.close()
