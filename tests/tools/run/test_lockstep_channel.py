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
