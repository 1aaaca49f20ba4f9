"""The emulated bus: virtual servos behind a pty, served by one thread that also runs the clock.

:class:`Emulator` owns the pty (:mod:`.pty_link`) and its one bus thread. The thread blocks in
``select`` on the pty master (and a wake-up pipe and, in lockstep, the control channel), feeds a
:class:`driver.parser.PacketParser`, abandons a partial frame after an idle gap
(``inter_byte_timeout_s``, 1.5 ms as on the servo) and, for each instruction, lets the clock
charge its wire time, runs it under the one lock (:func:`.instructions.dispatch`: every
instruction's semantics) and hands its replies to the pacer (:mod:`.reply_pacing`: due times and
fault draws). Between requests it calls the clock object passed in (:mod:`.clock`), which runs
the due steps through :class:`.stepping.Stepper` (every servo, then the world). The lockstep
control channel (:mod:`.lockstep_socket`) calls the hooks :meth:`Emulator.receive_until`,
:meth:`Emulator.move_to` and :meth:`Emulator.settle`, in the bus thread.
"""
from __future__ import annotations

import gc
import logging
import operator
import os
import select
import sys
import threading
import time
from dataclasses import dataclass
from typing import Callable, Sequence, cast

from swerve.driver.errors import ChecksumError, ConfigError, CorruptPacketError
from swerve.driver.packets import MAX_ID, StatusPacket
from swerve.driver.parser import PacketParser
from swerve.driver.transport import BITS_PER_BYTE
from swerve.emulator.adapter import UsbAdapter
from swerve.emulator.bus_stats import Stats
from swerve.emulator.clock import ClockStats, FrozenClock, HandOverLock, PhysicsClock, RobotTimeClock
from swerve.emulator.faults import Faults
from swerve.emulator.instructions import READS_ONLY, DispatchRules, crc_error_replies, dispatch
from swerve.emulator.lockstep_socket import ControlServer
from swerve.emulator.pty_link import PtyLink
from swerve.emulator.reply_pacing import ReplyPacer
from swerve.emulator.servo import BAUD_RATES, VirtualServo
from swerve.emulator.stepping import Stepper, World

log = logging.getLogger(__name__)
_SERVO_ID = operator.attrgetter("id")


def freeze_startup_heap() -> None:
    """In a process that serves the emulator: freeze what start-up allocated, as it is.

    Later collections then walk only objects made since (``gc.freeze``). Without it a full
    collection of the ~90 000 objects numpy and scipy bring stalls the bus thread for 10–25 ms
    (measured in the emulator process), several missed cycles at time scale 5. No collection
    comes first: start-up allocates much and frees little (with numba loaded, a collection of
    ~170 000 objects costs ~80 ms of CPU to free ~1 000).
    """
    gc.freeze()


DEFAULT_IDS = tuple(range(1, 9))
DEFAULT_MODEL = "xh430-w210"
DEFAULT_BAUD = 1_000_000
IDLE_POLL_S = 0.25          # select timeout while the line is idle (only to notice close)
#: GIL hand-over interval while the emulator runs, s. CPython's default (5 ms) lets the busy bus
#: thread delay a client in the same process (tests) by up to 5 ms per hand-over.
SWITCH_INTERVAL_S = 2e-4
#: Said once per emulator on stderr when a client first flushes its output queue.
OUTPUT_FLUSH_NOTICE = ("swerve emulator: the client flushed its output (tcflush TCOFLUSH) on the pty; "
                       "whatever it had written that the emulator had not yet read was discarded and never "
                       "reached the servos (on a U2D2 they would have been sent). Counted in "
                       "stats.client_output_flushes; the number of bytes lost cannot be known.")


@dataclass(frozen=True)
class LinkSettings:
    """How the emulated bus behaves on the line (everything but the servos, clock and faults).

    ``path``: symlink to create to the pty slave.
    ``wire_timing``: pace replies as on a cable (10 bits per byte). ``baud_check``: servos only
    hear a client whose line speed equals their Baud Rate item. ``crc_error_reply``: answer a
    unicast frame with a bad CRC with CRC Error (0x03) instead of dropping it.
    ``sync_chain_break``: in a Sync/Bulk Read, servos listed after an absent one stay silent too.
    ``inter_byte_timeout_s``: idle gap that abandons a partial frame (1.5 ms as on the servo).
    ``broadcast_slot_s``: spacing of the replies to a broadcast Ping.
    """

    path: str | os.PathLike | None = None
    wire_timing: bool = False
    baud_check: bool = True
    crc_error_reply: bool = False
    sync_chain_break: bool = True
    inter_byte_timeout_s: float = 1.5e-3
    broadcast_slot_s: float = 1e-4


#: Called with the emulator, under its lock, after each run of clock steps and each ``advance``.
Observer = Callable[["Emulator"], None]


class Emulator:
    """A bus of virtual X-series servos on a pty; use as a context manager.

    Composed of its parts; build one with :func:`swerve.emulator.factory.build_emulator`
    (from a parsed robot config) or directly from :func:`swerve.emulator.servo.make_servos`.

    Parameters
    ----------
    servos : sequence of VirtualServo
        The servos on the bus (one model; distinct IDs).
    link : LinkSettings
        Pty symlink, wire timing and protocol options (the line speed is the servos' Baud Rate).
    clock : PhysicsClock, optional
        Owner of simulated time (:mod:`swerve.emulator.clock`); default frozen.
    faults : Faults or str, optional
        Fault settings (:mod:`emulator.faults`), also reachable as :attr:`faults`.
    world : World, optional
        The robot body, stepped after the servos; gives :attr:`pose`.
    control : ControlServer, optional
        The lockstep control channel (:mod:`swerve.emulator.lockstep_socket`), served by the bus thread;
        needs a clock that keeps robot time (:class:`~swerve.emulator.clock.RobotTimeClock`, e.g.
        :class:`~swerve.emulator.clock.LockstepPhysicsClock`).
    adapter : UsbAdapter, optional
        The USB-serial adapter between the cable and the host (:mod:`swerve.emulator.adapter`):
        replies reach the host when it sends them (its latency timer, full packets, USB frames),
        in robot time with a lockstep clock and in wall time with ``link.wire_timing``.
        ``None``: the host reads the cable directly.
    """

    def __init__(self, servos: Sequence[VirtualServo], *, link: LinkSettings = LinkSettings(),
                 clock: PhysicsClock | None = None, faults: Faults | str | None = None, world: World | None = None,
                 control: ControlServer | None = None, adapter: UsbAdapter | None = None):
        self.servos: tuple[VirtualServo, ...] = tuple(sorted(servos, key=lambda s: s.id))
        if not self.servos:
            raise ConfigError("an emulated bus needs at least one servo")
        self.table = self.servos[0].table
        self.model = self.table.model
        self.settings = link
        #: Line speed the servos' Baud Rate items start at (the lowest ID's), also assumed when the
        #: client's termios speed reads as 0 or unknown.
        self.baud = self.servos[0].baud_bps
        self.clock: PhysicsClock = clock if clock is not None else FrozenClock()
        self.faults = faults if isinstance(faults, Faults) else Faults.parse(faults)
        if control is not None and self.clock.now_s is None:
            raise ConfigError("a lockstep control channel needs a lockstep clock")
        #: The clock the control channel moves: every clock declares ``now_s``, and one that
        #: keeps it (not None) is a robot-time clock.
        self._robot_clock = cast(RobotTimeClock, self.clock) if control is not None else None
        self.control = control
        #: Bytes received from the client on the pty (the control channel's barrier counts them).
        self.rx_bytes = 0
        #: Bytes written to the pty in all (a lockstep client's reply gate counts on it).
        self.tx_bytes = 0
        self.stats = Stats()
        #: True-state observers (e.g. the status file), see :data:`Observer`.
        self.observers: list[Observer] = []
        self._lock = HandOverLock()
        self._rules = DispatchRules(link.sync_chain_break, link.broadcast_slot_s)
        self._stepper = Stepper(self.servos, world, self._lock, self.stats)
        try:
            self.faults.attach(self._raise_hardware_error)
        except KeyError as exc:
            raise ConfigError(f"fault for a servo that is not on the bus: {exc.args[0]}") from None
        self._pty: PtyLink | None = None
        self._packet_baud = 0       # the line speed while an instruction is handled (0: read it)
        self._parser = PacketParser()
        self._stop = threading.Event()
        self._pacer = ReplyPacer(self._write, self.clock, self, self.robot_time_s, self.faults, self.stats,
                                 adapter, link.wire_timing, self._stop)
        self._thread: threading.Thread | None = None
        self._wake_r = self._wake_w = -1
        self._previous_switch_s = sys.getswitchinterval()

    # --- lifecycle ------------------------------------------------------------------------------
    def start(self) -> "Emulator":
        """Open the pty and start serving (idempotent)."""
        if self._pty is not None:
            return self
        self._pty = PtyLink(self.baud, self.settings.path, on_output_flush=self._output_flushed)
        self._wake_r, self._wake_w = os.pipe()
        self._stop.clear()
        if self.observers:
            self._notify()             # the initial state, before the first request
        self._previous_switch_s = sys.getswitchinterval()     # process-wide; restored by close()
        sys.setswitchinterval(min(self._previous_switch_s, SWITCH_INTERVAL_S))
        self._thread = threading.Thread(target=self._serve, name="emulator-bus", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the threads and close the pty (idempotent)."""
        if self._pty is None:
            return
        self._stop.set()
        self.wake()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        sys.setswitchinterval(self._previous_switch_s)
        if self.observers:
            self._notify()             # the final state, after the clock stopped
        self._pty.close()
        self._pty = None
        if self.control is not None:
            self.control.close()
        for fd in (self._wake_r, self._wake_w):
            try:
                os.close(fd)
            except OSError:
                pass
        self._wake_r = self._wake_w = -1

    def __enter__(self) -> "Emulator":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def port(self) -> str:
        """Path of the pty slave the client opens (``/dev/pts/N``)."""
        if self._pty is None:
            raise RuntimeError("emulator is not running (use it as a context manager or call start())")
        return self._pty.path

    @property
    def running(self) -> bool:
        """True while the bus thread serves the pty."""
        return self._thread is not None and self._thread.is_alive()

    @property
    def rate_hz(self) -> float:
        """Clock steps per simulated second."""
        return self.clock.rate_hz

    @property
    def world(self) -> World | None:
        """The robot body stepped after the servos, or ``None``."""
        return self._stepper.world

    @property
    def adapter(self) -> UsbAdapter | None:
        """The USB-serial adapter model between the cable and the host, or ``None``."""
        return self._pacer.adapter

    @property
    def sim_time_s(self) -> float:
        """Simulated seconds stepped so far (clock and :meth:`advance` together)."""
        return self._stepper.sim_time_s

    @property
    def physics(self):
        """The world's physics (``RobotPhysics``), or ``None`` without a robot body."""
        world = self.world
        return world.physics if world is not None else None

    @property
    def link_path(self) -> str | None:
        return None if self._pty is None or self._pty.link is None else str(self._pty.link)

    def servo(self, id_: int) -> VirtualServo:
        """The servo whose ID item is currently ``id_``."""
        for s in self.servos:
            if s.id == id_:
                return s
        raise KeyError(f"no emulated servo with ID {id_} (IDs: {[s.id for s in self.servos]})")

    @property
    def lock(self) -> HandOverLock:
        """The one lock guarding every servo's memory (hold it to read several items coherently)."""
        return self._lock

    def _raise_hardware_error(self, id_: int, bits: int) -> None:
        with self._lock:
            self.servo(id_).raise_hardware_error(bits)

    def line_baud(self) -> int:
        """The line speed the client set on the pty (``baud`` when it reads 0 or unknown); while
        one instruction is handled, the speed read when it arrived."""
        if self._packet_baud:
            return self._packet_baud
        speed = self._pty.speed_bps() if self._pty is not None else 0
        return speed if speed in BAUD_RATES else self.baud

    # --- reader thread -------------------------------------------------------------------------
    def _serve(self) -> None:
        pty, parser = self._pty, self._parser
        control = self.control
        self._first_byte_t = self._last_rx_t = 0.0
        inter_byte_s = self.settings.inter_byte_timeout_s
        control_fds: tuple[int, ...] = ()
        fds = [pty.master, self._wake_r]
        while not self._stop.is_set():
            timeout = inter_byte_s if parser.pending and control is None else IDLE_POLL_S
            timeout = min(timeout, self._run_clock())
            if control is not None and control.fds() is not control_fds:    # a client came or went
                control_fds = control.fds()
                fds = [pty.master, self._wake_r, *control_fds]
            try:
                ready, _, _ = select.select(fds, [], [], timeout)
            except (OSError, ValueError):
                break
            if self._stop.is_set():
                break
            if self._wake_r in ready:
                os.read(self._wake_r, 512)
            if pty.master in ready:
                self._receive()
            elif parser.pending and control is None and time.monotonic() - self._last_rx_t >= inter_byte_s:
                self._abandon_partial()        # the sender went silent mid-frame
            if control is not None:
                for fd in ready:
                    if fd not in (pty.master, self._wake_r):
                        control.handle(fd, self)
        self.settle()                   # steps still owed to a lockstep clock, before close() reads

    def _receive(self) -> None:
        """Read what the client sent and serve every instruction it completes."""
        data = self._pty.read()
        if not data:
            return
        now = time.monotonic()
        if not self._parser.pending:
            self._first_byte_t = now
        self._last_rx_t = now
        self.rx_bytes += len(data)
        packets = self._parser.feed(data)
        self._count_parser_errors()
        for pkt in packets:
            self._handle(pkt, self._first_byte_t, now)
            self._first_byte_t = now

    def _output_flushed(self) -> None:
        """The client flushed its output queue (``tcflush(TCOFLUSH)``): bytes it wrote that were
        not read yet are gone. Count it, drop the partial frame they belonged to, say so once."""
        self.stats.client_output_flushes += 1
        if self._parser.pending:
            self._parser.reset()
            self._count_parser_errors()
        if self.stats.client_output_flushes == 1:
            print(OUTPUT_FLUSH_NOTICE, file=sys.stderr, flush=True)

    def _abandon_partial(self) -> None:
        packets = self._parser.flush()
        if self._parser.pending:
            self._parser.reset()
        self._count_parser_errors()
        now = time.monotonic()
        for pkt in packets:
            self._handle(pkt, self._first_byte_t, now)

    # --- lockstep control (called by the control channel, in the bus thread) -------------------
    def receive_until(self, rx_bytes: int, timeout_s: float) -> bool:
        """Serve the pty until ``rx_bytes`` bytes have arrived in all (False after ``timeout_s``).

        A frame still incomplete then is abandoned, as after an idle gap on the wire."""
        deadline = time.monotonic() + timeout_s
        while self.rx_bytes < rx_bytes:
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self._stop.is_set():
                return False
            try:
                if not select.select([self._pty.master], [], [], min(remaining, IDLE_POLL_S))[0]:
                    continue
            except (OSError, ValueError):
                return False
            self._receive()
        if self._parser.pending:
            self._abandon_partial()
        return True

    def move_to(self, t_s: float) -> float:
        """Move robot time to ``t_s`` (lockstep clock) without waiting for the physics: the bus
        thread runs it before it next serves a byte or blocks, or in :meth:`settle`. The new time."""
        if self._robot_clock is None:
            raise ConfigError("robot time moves only with a lockstep control channel")
        return self._robot_clock.move_to(t_s)

    def settle(self) -> None:
        """Run the physics steps robot time has passed but the physics has not yet (lockstep runs
        those owed by replies and :meth:`move_to` after the answer is out). Bus thread only."""
        self._clocked(self.clock.catch_up)

    def robot_time_s(self) -> float:
        """Robot time of a lockstep clock (bus exchanges included); the physics time otherwise."""
        now_s = self.clock.now_s
        return self.sim_time_s if now_s is None else now_s

    def inject_fault(self, what: str, args: list[str]) -> None:
        """A fault from the control channel: ``vanish ID``, ``restore ID``, ``hwerror ID BITS``."""
        if what in ("vanish", "restore") and len(args) == 1:
            with self._lock:
                self.faults.apply(what, int(args[0]))
        elif what == "hwerror" and len(args) == 2:
            bits = int(args[1]) if args[1].isdigit() else args[1]
            self.faults.raise_hardware_error(int(args[0]), bits)
        else:
            raise ValueError(f"unknown fault {what} {' '.join(args)} (vanish ID, restore ID, hwerror ID BITS)")

    def counters(self) -> dict[str, int]:
        return self.stats.as_dict()

    def control_info(self) -> str:
        adapter_ms = 0 if self.adapter is None else self.adapter.latency_ms
        return (f"rate_hz {self.clock.rate_hz!r} reply_latency_s "
                f"{self.clock.reply_latency_s!r} baud {self.line_baud()} adapter_latency_ms {adapter_ms}")

    def _count_parser_errors(self) -> None:
        p = self._parser
        errors = p.take_errors()
        self.stats.bad_frames = p.bad_frames
        self.stats.dropped_bytes = p.dropped_bytes
        if errors and self.settings.crc_error_reply:
            self._reply_crc_errors(errors)

    def _reply_crc_errors(self, errors) -> None:
        for exc in errors:
            if isinstance(exc, ChecksumError) and len(exc.frame) >= 8 and exc.frame[4] <= MAX_ID:
                with self._lock:
                    replies = crc_error_replies(self._listening(), exc.frame[4])
                self._pacer.send(replies, time.monotonic(), self._byte_time_s())

    def _handle(self, pkt, first_byte_t: float, rx_t: float) -> None:
        if isinstance(pkt, StatusPacket):
            self.stats.status_packets_ignored += 1
            return
        self.stats.packets_received += 1
        self._packet_baud = self.line_baud()    # one termios read per instruction
        try:
            byte_t = self._byte_time_s()
            wire_s = pkt.wire_length() * byte_t      # the instruction's bytes on the wire
            steps = self.clock.stats.steps
            self.clock.on_request(self, wire_s)
            if self.observers and self.clock.stats.steps != steps:
                self._notify()
            with self._lock:
                listening = self._listening()
                if not listening:
                    self.stats.wrong_baud_packets += 1
                    return
                try:
                    replies, touched = dispatch(pkt, listening, self._rules)
                except CorruptPacketError as exc:     # e.g. a sync write block of the wrong size
                    self.stats.malformed_packets += 1
                    log.debug("ignored %s: %s", pkt.name, exc)
                    return
                # ID / baud changes take effect for the next instruction; the replies are
                # already encoded, so nothing is left to do once the last one is out (Sync and
                # Bulk Reads change neither)
                if pkt.instruction not in READS_ONLY:
                    for s in touched:
                        s.apply_pending()
            # replies are timed from the instant the request ended on the wire, not from the
            # end of the dispatch above: the emulator's own work is not charged on top
            end_t = max(rx_t, first_byte_t + wire_s) if self.settings.wire_timing else rx_t
            self._pacer.send(replies, end_t, byte_t)
        except Exception:  # noqa: BLE001 - one bad packet must never stop the bus
            self.stats.dispatch_errors += 1
            log.debug("error handling %r", pkt, exc_info=True)
        finally:
            self._packet_baud = 0

    def _byte_time_s(self) -> float:
        return BITS_PER_BYTE / self.line_baud()

    def _listening(self) -> list[VirtualServo]:
        """Servos present on the bus and listening at the client's line speed, by ascending ID."""
        line = self.line_baud() if self.settings.baud_check else None
        vanished = self.faults.vanished
        out = [s for s in self.servos if s.id not in vanished and (line is None or s.baud_bps == line)]
        out.sort(key=_SERVO_ID)         # an ID write may have changed the order
        return out

    def _write(self, data: bytes) -> None:
        if data:
            sent = self._pty.write(bytes(data))
            self.tx_bytes += sent
            self.stats.tx_overflow_bytes += len(data) - sent

    # --- clock ----------------------------------------------------------------------------------
    def wake(self) -> None:
        """Make the bus thread call the clock again now (any thread; e.g. a lockstep request)."""
        try:
            os.write(self._wake_w, b"x")
        except OSError:
            pass

    def request_pending(self) -> bool:
        """True if bytes from the client wait in the pty (the clock then returns so requests go first)."""
        try:
            return bool(select.select([self._pty.master], [], [], 0)[0])
        except (OSError, ValueError, AttributeError):
            return False

    def lock_wanted(self) -> bool:
        """True if another thread waits for the bus lock."""
        return bool(self._lock.waiting)

    def step(self, dt_s: float) -> None:
        """One clock step of ``dt_s`` simulated s: every servo, then the world, under the lock."""
        self._stepper.step(dt_s)

    def step_many(self, dt_s: float, n: int) -> None:
        """``n`` clock steps of ``dt_s`` simulated s, the same result as ``n`` :meth:`step` s
        (:meth:`.stepping.Stepper.step_many`)."""
        self._stepper.step_many(dt_s, n)

    def _run_clock(self) -> float:
        """Let the clock run what is due; the seconds the bus thread may block (``inf``: no limit)."""
        wait_s = self._clocked(self.clock.run)
        return IDLE_POLL_S if wait_s is None else wait_s

    def _clocked(self, call):
        """``call(self)``, a clock method that may run physics steps; its result. A physics error
        is counted and logged, not raised (a bug must not kill the bus): then None. Observers
        hear of new steps."""
        steps = self.clock.stats.steps
        try:
            return call(self)
        except Exception:  # noqa: BLE001 - a physics bug must not kill the bus
            self.stats.dispatch_errors += 1
            log.debug("error in physics step", exc_info=True)
            return None
        finally:
            if self.observers and self.clock.stats.steps != steps:
                self._notify()

    def _notify(self) -> None:
        with self._lock:
            for observer in self.observers:
                observer(self)

    def advance(self, dt_s: float) -> None:
        """Advance simulated time by ``dt_s`` s at once, in steps of at most ``1/clock.rate_hz``
        (tests and benches; works with any clock)."""
        with self._lock:
            steps = max(1, round(dt_s * self.clock.rate_hz))
            self._stepper.ticks(dt_s / steps, steps)
            for observer in self.observers:
                observer(self)

    # --- true state (never through the bus) ----------------------------------------------------
    @property
    def pose(self) -> tuple[float, float, float]:
        """True body pose ``(x_m, y_m, theta_rad)`` (needs a world)."""
        return self.true_state()[1]

    def true_state(self) -> tuple[float, tuple[float, float, float]]:
        """``(sim_time_s, (x_m, y_m, theta_rad))`` read under one lock (a coherent pair)."""
        return self._stepper.true_state()

    @property
    def clock_stats(self) -> ClockStats:
        return self.clock.stats
