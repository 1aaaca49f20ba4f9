"""The lockstep clock's control channel: a silent emulator times out, a closed one is named."""
import socket
import threading

import pytest

from swerve.tools.run import lockstep
from swerve.tools.run.lockstep import LockstepLoopClock, LockstepError


def _serve(path, after_info):
    """A control socket at ``path`` that answers ``info``, then does ``after_info(conn)``."""
    srv = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    srv.bind(str(path))
    srv.listen(1)

    def run():
        conn, _ = srv.accept()
        conn.makefile("rb").readline()
        conn.sendall(b"info rate_hz 1000 reply_latency_s 5e-05 baud 1000000 body 1\n")
        after_info(conn)
        srv.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def test_a_silent_emulator_is_a_timeout(tmp_path, monkeypatch):
    monkeypatch.setattr(lockstep, "CONTROL_TIMEOUT_S", 0.2)
    done = threading.Event()
    _serve(tmp_path / "c", lambda conn: (done.wait(60), conn.close()))
    with LockstepLoopClock(str(tmp_path / "c")) as clock:
        with pytest.raises(LockstepError, match="got no answer within 0.2 s"):
            clock.now()
    done.set()


def test_a_closed_channel_is_named(tmp_path):
    # the request is taken, then the channel closes without an answer
    _serve(tmp_path / "c", lambda conn: (conn.recv(100), conn.close()))
    with LockstepLoopClock(str(tmp_path / "c")) as clock:
        with pytest.raises(LockstepError, match="closed its control channel"):
            clock.now()


class _Bus:
    """What :meth:`LockstepLoopClock.attach` uses of a bus: byte counters and the write hook."""

    def __init__(self):
        self.bytes_written = self.bytes_received = 0
        self.after_write = None

    def call_after_write(self, callback):
        self.after_write = callback

    def gate_replies(self, gate):
        pass


def _answering(conn):
    """Answer ``sent`` and ``pose`` requests until the channel closes."""
    for line in conn.makefile("rb"):
        word = line.split()[0]
        conn.sendall(b"sent 0.0 0\n" if word == b"sent" else b"pose 0.001 1.0 2.0 3.0\n")


def test_deferred_work_runs_after_the_next_instruction_and_its_request(tmp_path):
    """The loop's log (``defer``) waits for the next write; it runs once the ``pose`` request
    armed for that write is sent, before the reply is awaited; ``run_deferred`` runs what is left."""
    _serve(tmp_path / "c", _answering)
    with LockstepLoopClock(str(tmp_path / "c")) as clock:
        ran = []
        clock.defer(lambda: ran.append("before attach"))
        assert ran == ["before attach"]              # no write hook yet: runs at once
        bus = _Bus()
        clock.attach(bus)
        clock.defer(lambda: ran.append(clock.requests))
        assert ran == ["before attach"]              # kept for the next write
        requests = clock.requests
        clock.ask_after_next_write()
        bus.bytes_written += 14                      # an instruction went out
        bus.after_write()
        assert ran == ["before attach", requests + 1]   # after the pose request was sent
        assert clock.pose() == (1.0, 2.0, 3.0)       # its answer is still taken
        bus.after_write()                            # nothing kept: nothing runs
        clock.defer(lambda: ran.append("last"))
        clock.run_deferred()
        clock.run_deferred()
        assert ran == ["before attach", requests + 1, "last"]
