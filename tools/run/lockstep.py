"""Robot time from a lockstep emulator: the ticker's clock over the emulator's control channel.

With this clock the loop waits on simulated time, not the wall clock: ``sleep_until(t)`` asks the
emulator to advance its physics to ``t`` (after it has taken every byte the driver wrote to the
pty), and ``now()`` is the emulator's robot time, which includes the wire time of every bus
exchange. The protocol is in :mod:`swerve.emulator.lockstep_socket` and emulator/README.md.

Each request is a process hand-over, so the clock asks as little as it can, two requests per
control cycle: ``now()`` asks ``pose`` (time and true pose in one answer) and ``pose()`` reuses
that answer while no byte has been written since; with the bus attached (:meth:`attach`),
``ask_after_next_write()`` sends that request the moment the read's instruction has gone out,
so the emulator answers it in the same turn as the read; ``start_sleep(t)`` sends ``advance``
and takes its answer, which the emulator gives before it steps the physics (the caller must
not write to the pty before ``end_sleep``). ``defer(work)`` keeps the rest of a cycle (its log)
until the next instruction has gone out: it then runs while the emulator steps the physics and
serves that instruction, off the chain of turns between the two processes.
"""
from __future__ import annotations

import math
import socket
import struct
import time
from typing import Callable

from swerve.driver.errors import SwerveError

#: Wall seconds a control request may take before the emulator is taken for dead.
CONTROL_TIMEOUT_S = 30.0
#: Bus timeout slack against a lockstep emulator, wall s: its replies are never late in robot
#: time, and a reply not in by then is waited for if the emulator says it sent it (the clock is
#: the bus's reply gate), so this only sets how soon a lost reply is confirmed lost.
LOCKSTEP_TIMEOUT_MARGIN_S = 0.005


class LockstepError(SwerveError):
    """The lockstep emulator refused a request or stopped answering."""


class LockstepLoopClock:
    """A :class:`~swerve.tools.run.ticker.Clock` in robot seconds, owned by a lockstep emulator.

    ``control_path``: the emulator's control socket (``CONTROL`` on ``swerve emulate``'s PORT
    line, or ``EmulatorProcess.control_path``). Connect before writing to the pty, then
    :meth:`attach` the :class:`~swerve.driver.bus.Bus` (or give another writer's byte counter to
    :meth:`count_tx`).
    ``time_scale``: pace robot time at this many robot seconds per wall second (``None``: as
    fast as the emulator runs).
    """

    def __init__(self, control_path: str, time_scale: float | None = None):
        if time_scale is not None and not (math.isfinite(time_scale) and time_scale > 0):
            raise LockstepError(f"lockstep time scale must be > 0, got {time_scale}")
        self.time_scale = time_scale
        try:
            self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self._sock.settimeout(CONTROL_TIMEOUT_S)
            self._sock.connect(str(control_path))
            # a blocking socket whose kernel send/receive calls time out: each request costs
            # one send and one receive, without the poll() a Python-level timeout adds to each
            self._sock.settimeout(None)
            limit = struct.pack("ll", int(CONTROL_TIMEOUT_S), round(CONTROL_TIMEOUT_S % 1 * 1e6))  # timeval
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, limit)
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, limit)
        except OSError as exc:
            raise LockstepError(f"cannot connect to the lockstep control socket {control_path}: {exc}") from None
        self._reader = self._sock.makefile("rb")      # buffered: one recv per reply line
        self._tx: Callable[[], int] = lambda: 0
        self._tx_last = 0
        self._now_s = 0.0
        self._known = False             # _now_s is the emulator's time (no request since)
        self._pose: tuple[float, float, float] | None = None   # true pose at _now_s, if asked
        self._pending: str | None = None    # a request sent whose answer is not read yet
        self._asked_s: float | None = None  # robot time when the last advance was asked, until ended
        self._pace_start: tuple[float, float] | None = None    # (robot s, wall s) when pacing started
        self.requests = 0
        self.emulator = self.info()     # the emulator has accepted us: bytes from now on count
        self._has_body = bool(self.emulator.get("body", 0))
        self._attached = self._armed = False
        self._deferred: Callable[[], None] | None = None     # work to run after the next write

    def count_tx(self, tx_bytes: Callable[[], int]) -> None:
        """Count the bytes written to the pty with ``tx_bytes()`` from now on (the barrier)."""
        self._tx = tx_bytes
        self._tx_last = tx_bytes()

    def _ask(self, request: str) -> list[str]:
        self._send(request)
        return self._answer()

    def _send(self, request: str) -> None:
        self._answer_pending()
        self.requests += 1
        try:
            self._sock.sendall(request.encode("ascii") + b"\n")
        except OSError as exc:
            raise LockstepError(f"lockstep emulator: {request.split()[0]} failed: {exc}") from None
        self._pending = request

    def _answer_pending(self) -> None:
        """Collect the answer to a request left pending (:meth:`start_sleep`, :meth:`written`)."""
        if self._pending is None:
            return
        if self._pending.startswith("pose "):
            self._take_pose(self._answer())
            return
        words = self._answer()
        self._now_s = float(words[1])
        self._known = True
        self._asked_s = float(words[2]) if len(words) > 2 else self._now_s
        if self.time_scale is not None:
            self._pace()

    def _answer(self) -> list[str]:
        request, self._pending = self._pending, None
        try:
            line = self._reader.readline()
        except OSError as exc:
            raise LockstepError(f"lockstep emulator: {request.split()[0]} failed: {exc}") from None
        if not line.endswith(b"\n") and (line or not self._closed_by_peer()):
            raise LockstepError(f"lockstep emulator: {request.split()[0]} got no answer "
                                f"within {CONTROL_TIMEOUT_S:g} s")
        words = line.decode("ascii", "replace").split()
        if not words:
            raise LockstepError("the lockstep emulator closed its control channel")
        if words[0] == "error":
            raise LockstepError(f"lockstep emulator: {' '.join(words[1:])}")
        return words

    def _closed_by_peer(self) -> bool:
        """After a read that returned nothing: True if the emulator closed the channel, False
        if the read timed out."""
        try:
            return self._sock.recv(1, socket.MSG_PEEK | socket.MSG_DONTWAIT) == b""
        except BlockingIOError:
            return False
        except OSError:
            return True

    def _delta(self) -> int:
        total = self._tx()
        delta, self._tx_last = total - self._tx_last, total
        return delta

    def now(self) -> float:
        """Robot time, s (bus exchanges so far included).

        Without bytes written since the last answer, robot time cannot have moved (this client
        is the one that moves it), so the last answer is returned without asking. Otherwise
        the true pose comes with the time, for :meth:`pose`."""
        self._answer_pending()
        if self._tx() != self._tx_last or not self._known:
            if self._has_body:
                self._ask_pose()
            else:
                self._now_s = float(self._ask(f"now {self._delta()}")[1])
                self._known = True
        return self._now_s

    def start_sleep(self, t: float) -> None:
        """Advance robot time to ``t`` and return once the emulator has answered, before its
        physics runs: the emulator answers as soon as it has served the bytes written so far and
        steps the physics afterwards, so the caller's work (e.g. writing its log) runs beside
        that physics. The caller must write nothing to the pty before :meth:`end_sleep`."""
        self._send(f"advance {t!r} {self._delta()}")
        self._known, self._pose, self._asked_s = False, None, None
        self._answer_pending()

    def end_sleep(self) -> float:
        """Wait for the advance asked by :meth:`start_sleep`: robot time then stands at ``t``, and
        the emulator runs the physics there before it serves anything else (read the world in
        the emulator's process only after a request that waits for it, e.g. :meth:`pose`); with
        a time scale, also until the wall clock has caught up. Returns the robot time when the
        advance was asked, s (every byte written before it served)."""
        self._answer_pending()
        if self._asked_s is None:
            raise LockstepError("end_sleep() without start_sleep()")
        asked_s, self._asked_s = self._asked_s, None
        return asked_s

    def sleep_until(self, t: float) -> None:
        """Advance robot time to ``t`` (the physics runs there); with a time scale, also wait
        until the wall clock has caught up with it."""
        self.start_sleep(t)
        self.end_sleep()

    def _pace(self) -> None:
        wall = time.monotonic()
        if self._pace_start is None:
            self._pace_start = (self._now_s, wall)
            return
        due = self._pace_start[1] + (self._now_s - self._pace_start[0]) / self.time_scale
        while due > wall:
            time.sleep(due - wall)
            wall = time.monotonic()

    def align(self, step_s: float) -> float:
        """Advance to the next multiple of ``step_s`` (e.g. the physics step) and return it, so a
        schedule started there has its deadlines on the physics grid."""
        now = self.now()
        self.sleep_until(math.ceil(now / step_s - 1e-9) * step_s)
        return self._now_s

    def stamp_ns(self) -> int:
        """Robot time of the latest answer, ns (a log stamp that is the same on every run)."""
        return round(self._now_s * 1e9)

    def pose(self) -> tuple[float, float, float]:
        """True body pose ``(x_m, y_m, theta_rad)`` after every byte written so far was served
        (the answer that came with the last :meth:`now`, if nothing was written since). The
        emulator answers once its physics stands at robot time."""
        self._answer_pending()
        if self._pose is None or self._tx() != self._tx_last:
            self._ask_pose()
        return self._pose

    def _ask_pose(self) -> None:
        self._take_pose(self._ask(f"pose {self._delta()}"))

    def _take_pose(self, words: list[str]) -> None:
        self._now_s = float(words[1])
        self._pose = (float(words[2]), float(words[3]), float(words[4]))
        self._known = True

    def ask_after_next_write(self) -> None:
        """Have :meth:`written` ask for the time and pose right after the next instruction is
        sent (the emulator answers once it has served it), so the :meth:`now` that follows its
        reply costs no extra round trip. Needs the bus's write callback (:meth:`attach`)."""
        self._armed = self._has_body and self._attached

    def written(self) -> None:
        """The bus's after-write callback: sends the request :meth:`ask_after_next_write` armed,
        then runs the work :meth:`defer` kept (the emulator serves the instruction meanwhile)."""
        if self._armed:
            self._armed = False
            self._send(f"pose {self._delta()}")
        self.run_deferred()

    def defer(self, work: Callable[[], None]) -> None:
        """Keep ``work`` until the next instruction has been written (:meth:`written`), with the
        bus attached; run it now otherwise. Work kept before runs first."""
        self.run_deferred()
        if self._attached:
            self._deferred = work
        else:
            work()

    def run_deferred(self) -> None:
        """Run the work :meth:`defer` kept, if any."""
        work, self._deferred = self._deferred, None
        if work is not None:
            work()

    def attach(self, bus) -> None:
        """Count the bytes ``bus`` (a :class:`swerve.driver.bus.Bus`) writes to the pty, hear of
        each write (``bus.call_after_write``) and be its reply gate (``bus.gate_replies``), so a
        reply is waited for until the emulator says it was never sent, whatever the host's load."""
        self.count_tx(lambda: bus.bytes_written)
        bus.call_after_write(self.written)
        self._sent_base = self._sent() - bus.bytes_received     # nothing is in flight now
        bus.gate_replies(self)
        self._attached = True

    def _sent(self) -> int:
        words = self._ask(f"sent {self._delta()}")
        self._now_s, self._known, self._pose = float(words[1]), True, None
        return int(words[2])

    def bytes_sent(self) -> int:
        """Bytes the emulator has written to the pty, on the attached bus's count, after it
        served every byte written so far (:class:`swerve.driver.bus.ReplyGate`)."""
        return self._sent() - self._sent_base

    def fault(self, what: str, *args) -> None:
        """Inject a fault once every byte written so far was served: ``fault("vanish", 7)``,
        ``fault("restore", 7)``, ``fault("hwerror", 5, "overload")``."""
        self._ask(" ".join(["fault", str(self._delta()), what, *map(str, args)]))
        self._known, self._pose = False, None

    def counters(self) -> dict[str, int]:
        """The emulator's bus counters (``replies_dropped``, ``packets_received``, ...)."""
        words = self._ask("stats")[1:]
        return {k: int(v) for k, v in zip(words[::2], words[1::2])}

    def info(self) -> dict[str, float]:
        """``{"rate_hz", "reply_latency_s", "baud", "adapter_latency_ms", "body"}`` of the emulator
        (``adapter_latency_ms`` 0: no USB adapter; ``body`` 1: it has a robot body, so a true pose)."""
        words = self._ask("info")[1:]
        return {k: float(v) for k, v in zip(words[::2], words[1::2])}

    def close(self) -> None:
        self._pending = None
        for closer in (self._reader.close, self._sock.close):
            try:
                closer()
            except OSError:
                pass

    def __enter__(self) -> "LockstepLoopClock":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
