"""The emulated bus: virtual servos behind a pty, served by one thread that also runs the clock.

Bus thread: blocks in ``select`` on the pty master (and a wake-up pipe), feeds a
:class:`driver.parser.PacketParser`, abandons a partial frame after an idle gap
(``inter_byte_timeout_s``, 1.5 ms as on the servo), dispatches each instruction to the
addressed servos under the one lock, then writes the replies after each servo's Return Delay
Time (monotonic deadlines, ``time.sleep``; never spinning). Between requests it calls the clock
object passed in (:mod:`emulator.clock`), which runs the due steps: :meth:`VirtualServo.advance`
on every servo (Realtime Tick, Bus Watchdog, physics), then ``world.step``.

Reply order: broadcast Ping in ascending ID order; Sync/Bulk Read in listed order; Fast
Sync/Bulk Read as one combined frame (:class:`driver.packets.FastStatus`), one slice per servo.
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
from dataclasses import dataclass, fields
from typing import Callable, Iterable, Protocol, Sequence

from swerve.driver.control_table import table_for
from swerve.driver.errors import ChecksumError, ConfigError, CorruptPacketError
from swerve.driver.packets import (BROADCAST_ID, MAX_ID, MAX_LENGTH, ErrorNumber, FastStatus, Instruction,
                            InstructionPacket, StatusPacket, parse_bulk_read, parse_bulk_write,
                            fast_status_length, parse_sync_read, parse_sync_write)
from swerve.driver.parser import PacketParser
from swerve.driver.transport import BITS_PER_BYTE

from swerve.emulator.adapter import UsbAdapter, byte_arrivals
from swerve.emulator.clock import HAND_OVER_S, ClockStats, FrozenClock, HandOverLock, PhysicsClock
from swerve.emulator.lockstep_socket import ControlServer
from swerve.emulator.faults import Faults
from swerve.emulator.pty_link import PtyLink, precise_timers
from swerve.emulator.servo import BAUD_RATES, Dynamics, VirtualServo

log = logging.getLogger(__name__)
_SERVO_ID = operator.attrgetter("id")


def freeze_startup_heap() -> None:
    """In a process that serves the emulator: collect once and freeze what start-up allocated.

    Later collections then walk only objects made since (``gc.freeze``). Without it a full
    collection of the ~90 000 objects numpy and scipy bring stalls the bus thread for 10–25 ms
    (measured in the emulator process), several missed cycles at time scale 5.
    """
    gc.collect()
    gc.freeze()

DEFAULT_IDS = tuple(range(1, 9))
DEFAULT_MODEL = "xh430-w210"
DEFAULT_BAUD = 1_000_000
#: Most physics steps :meth:`Emulator.step_many` runs under one hold of the lock (~2 ms of CPU).
MAX_STEPS_PER_HOLD = 100
IDLE_POLL_S = 0.25          # select timeout while the line is idle (only to notice close)
#: Replies of one exchange due within this window go out together, at the due time of the
#: latest of them (later than the cable for the earlier ones, never earlier); the reply that
#: ends the exchange goes out alone at its own due time unless it is already due.
GROUP_WRITE_S = 1e-3
#: GIL hand-over interval while the emulator runs, s. CPython's default (5 ms) lets the busy bus
#: thread delay a client in the same process (tests) by up to 5 ms per hand-over.
SWITCH_INTERVAL_S = 2e-4
SYNC_READS = (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ)
BULK_READS = (Instruction.BULK_READ, Instruction.FAST_BULK_READ)
FAST_READS = (Instruction.FAST_SYNC_READ, Instruction.FAST_BULK_READ)
BUS_WRITES = (Instruction.SYNC_WRITE, Instruction.BULK_WRITE)
BUS_INSTRUCTIONS = SYNC_READS + BULK_READS + BUS_WRITES
#: Said once per emulator on stderr when a client first flushes its output queue.
OUTPUT_FLUSH_NOTICE = ("swerve emulator: the client flushed its output (tcflush TCOFLUSH) on the pty; "
                       "whatever it had written that the emulator had not yet read was discarded and never "
                       "reached the servos (on a U2D2 they would have been sent). Counted in "
                       "stats.client_output_flushes; the number of bytes lost cannot be known.")


@dataclass
class Stats:
    """Counters of one emulator run (read them any time; written by the server threads)."""

    packets_received: int = 0      # instruction packets decoded
    replies_sent: int = 0          # status frames (or fast-read slices) written
    replies_dropped: int = 0       # by fault injection
    replies_corrupted: int = 0     # by fault injection
    bad_frames: int = 0            # bad CRC / implausible length (parser)
    dropped_bytes: int = 0         # garbage and abandoned partial frames (parser)
    status_packets_ignored: int = 0  # status frames on the line (another device talking)
    malformed_packets: int = 0     # valid frames whose parameters make no sense (ignored)
    dispatch_errors: int = 0       # unexpected exceptions caught while handling one packet
    wrong_baud_packets: int = 0    # no servo listens at the client's line speed
    tx_overflow_bytes: int = 0     # reply bytes the pty would not take (client not reading)
    client_output_flushes: int = 0  # client tcflush(TCOFLUSH) calls seen (pty packet mode); each
                                    # discards what the emulator had not read: how much is unknown
    clock_ticks: int = 0           # physics steps (clock and advance)

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(slots=True)
class _Reply:
    frame: bytes
    delay_s: float         # wait after the previous reply (or the instruction) ends
    fast: bool = False     # part of a combined fast-read frame (one fault draw per frame)


@dataclass(frozen=True)
class LinkSettings:
    """How the emulated bus behaves on the line (everything but the servos, clock and faults).

    ``baud``: line speed the servos' Baud Rate item starts at, also assumed when the client's
    termios speed reads as 0 or unknown. ``path``: symlink to create to the pty slave.
    ``wire_timing``: pace replies as on a cable (10 bits per byte). ``baud_check``: servos only
    hear a client whose line speed equals their Baud Rate item. ``crc_error_reply``: answer a
    unicast frame with a bad CRC with CRC Error (0x03) instead of dropping it.
    ``sync_chain_break``: in a Sync/Bulk Read, servos listed after an absent one stay silent too.
    ``inter_byte_timeout_s``: idle gap that abandons a partial frame (1.5 ms as on the servo).
    ``broadcast_slot_s``: spacing of the replies to a broadcast Ping.
    """

    baud: int = DEFAULT_BAUD
    path: str | os.PathLike | None = None
    wire_timing: bool = False
    baud_check: bool = True
    crc_error_reply: bool = False
    sync_chain_break: bool = True
    inter_byte_timeout_s: float = 1.5e-3
    broadcast_slot_s: float = 1e-4

    def __post_init__(self):
        if self.baud not in BAUD_RATES:
            raise ConfigError(f"baud {self.baud} is not an X-series rate ({', '.join(map(str, BAUD_RATES))})")


class World(Protocol):
    """What moves besides the servos (the robot body): stepped after them, under the bus lock.

    A world that steps one tick at a time after the servos subclasses :class:`SteppedWorld` for
    the members that batch or couple the steps.
    """

    pose: tuple[float, float, float]    # true (x_m, y_m, theta_rad)
    physics: object | None              # the physics model behind it (``RobotPhysics``), if any

    def step(self, dt_s: float) -> None:
        """Advance by ``dt_s`` simulated s from the servos' present shaft states."""

    def traces(self) -> dict | None:
        """Empty per-step trace lists for a run of several steps, servo after servo, then the
        body from the traces (:meth:`step_many`); ``None`` if the body must step between the
        servos."""

    def step_many(self, dt_s: float, n: int, traces: dict) -> None:
        """``n`` body steps from the servos' recorded ``traces`` (from :meth:`traces`)."""

    def run_coupled(self, servos: Sequence[VirtualServo], dt_s: float, n: int) -> int:
        """Up to ``n`` steps of the ``servos`` and the body together in one call, as many
        :meth:`VirtualServo.advance` then :meth:`step`; the steps run (0: step tick by tick)."""


class SteppedWorld:
    """The :class:`World` members of a body stepped one tick at a time after the servos, with
    no physics model to show; a subclass defines ``pose`` and ``step``."""

    physics = None

    def traces(self) -> dict | None:
        return None

    def step_many(self, dt_s: float, n: int, traces: dict) -> None:
        for _ in range(n):
            self.step(dt_s)

    def run_coupled(self, servos: Sequence[VirtualServo], dt_s: float, n: int) -> int:
        return 0


def make_servos(ids: Iterable[int], model: str, baud: int, *, limit_error: ErrorNumber = ErrorNumber.DATA_LIMIT,
                dynamics: Callable[[VirtualServo], Dynamics | None] | None = None) -> tuple[VirtualServo, ...]:
    """One :class:`VirtualServo` of ``model`` per ID (ascending), each with ``dynamics(servo)``.

    ``limit_error``: error for a value beyond a limit item (UNCONFIRMED; default Data Limit Error).
    """
    ids = list(ids)
    if not ids or len(set(ids)) != len(ids) or any(not 0 <= i <= MAX_ID for i in ids):
        raise ConfigError(f"servo IDs must be distinct values in 0..252, got {ids}")
    table = table_for(model)
    servos = tuple(VirtualServo(table, i, baud, limit_error=limit_error) for i in sorted(ids))
    if dynamics is not None:
        for s in servos:
            s.dynamics = dynamics(s)
    return servos


#: Called with the emulator, under its lock, after each run of clock steps and each ``advance``.
Observer = Callable[["Emulator"], None]


class Emulator:
    """A bus of virtual X-series servos on a pty; use as a context manager.

    Composed of its parts; build one with :func:`swerve.emulator.robot_emulator.build_emulator`
    (from a parsed robot config) or directly from :func:`make_servos`.

    Parameters
    ----------
    servos : sequence of VirtualServo
        The servos on the bus (one model; distinct IDs).
    link : LinkSettings
        Line speed, pty symlink and protocol options.
    clock : PhysicsClock, optional
        Owner of simulated time (:mod:`swerve.emulator.clock`); default frozen.
    faults : Faults or str, optional
        Fault settings (:mod:`emulator.faults`), also reachable as :attr:`faults`.
    world : World, optional
        The robot body, stepped after the servos; gives :attr:`pose`.
    control : ControlServer, optional
        The lockstep control channel (:mod:`swerve.emulator.lockstep_socket`), served by the bus thread;
        needs a clock with ``move_to`` (:class:`~swerve.emulator.clock.LockstepPhysicsClock`).
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
        self.baud = link.baud
        self.wire_timing = link.wire_timing
        self.clock: PhysicsClock = clock if clock is not None else FrozenClock()
        self.faults = faults if isinstance(faults, Faults) else Faults.parse(faults)
        self.world = world
        if control is not None and self.clock.now_s is None:     # only a lockstep clock keeps robot time
            raise ConfigError("a lockstep control channel needs a lockstep clock")
        self.control = control
        self.adapter = adapter
        #: Bytes received from the client on the pty (the control channel's barrier counts them).
        self.rx_bytes = 0
        #: Bytes written to the pty in all (a lockstep client's reply gate counts on it).
        self.tx_bytes = 0
        self.stats = Stats()
        #: Simulated seconds stepped so far (clock and :meth:`advance` together).
        self.sim_time_s = 0.0
        #: True-state observers (e.g. the status file), see :data:`Observer`.
        self.observers: list[Observer] = []
        self._lock = HandOverLock()
        try:
            self.faults.attach(self._raise_hardware_error)
        except KeyError as exc:
            raise ConfigError(f"fault for a servo that is not on the bus: {exc.args[0]}") from None
        self._pty: PtyLink | None = None
        self._packet_baud = 0       # the line speed while an instruction is handled (0: read it)
        self._parser = PacketParser()
        self._stop = threading.Event()
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
    def physics(self):
        """The world's physics (``RobotPhysics``), or ``None`` without a robot body."""
        return self.world.physics if self.world is not None else None

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
        while not self._stop.is_set():
            timeout = inter_byte_s if parser.pending and control is None else IDLE_POLL_S
            timeout = min(timeout, self._run_clock())
            fds = [pty.master, self._wake_r, *control.fds()] if control is not None else [pty.master, self._wake_r]
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
        return self.clock.move_to(t_s)

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
                getattr(self.faults, what)(int(args[0]))
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
                    targets = self._addressed(exc.frame[4])
                    replies = [_Reply(s.status(ErrorNumber.CRC).encode(), s.return_delay_s)
                               for s, primary in targets if primary and s.status_return_level == 2]
                self._transmit(replies, time.monotonic())

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
                try:
                    replies, touched = self._dispatch(pkt)
                except CorruptPacketError as exc:     # e.g. a sync write block of the wrong size
                    self.stats.malformed_packets += 1
                    log.debug("ignored %s: %s", pkt.name, exc)
                    return
                # ID / baud changes take effect for the next instruction; the replies are
                # already encoded, so nothing is left to do once the last one is out (Sync and
                # Bulk Reads change neither)
                if pkt.instruction not in SYNC_READS and pkt.instruction not in BULK_READS:
                    for s in touched:
                        s.apply_pending()
            # replies are timed from the instant the request ended on the wire, not from the
            # end of the dispatch above: the emulator's own work is not charged on top
            end_t = max(rx_t, first_byte_t + wire_s) if self.wire_timing else rx_t
            self._transmit(replies, end_t, byte_t)
        except Exception:  # noqa: BLE001 - one bad packet must never stop the bus
            self.stats.dispatch_errors += 1
            log.debug("error handling %r", pkt, exc_info=True)
        finally:
            self._packet_baud = 0

    def _byte_time_s(self) -> float:
        return BITS_PER_BYTE / self.line_baud()

    # --- dispatch (under the lock) -------------------------------------------------------------
    def _listening(self) -> list[VirtualServo]:
        """Servos present on the bus and listening at the client's line speed, by ascending ID."""
        line = self.line_baud() if self.settings.baud_check else None
        vanished = self.faults.vanished
        out = [s for s in self.servos if s.id not in vanished and (line is None or s.baud_bps == line)]
        out.sort(key=_SERVO_ID)         # an ID write may have changed the order
        return out

    def _addressed(self, id_: int) -> list[tuple[VirtualServo, bool]]:
        """``(servo, by_primary_id)`` for every listening servo an ID addresses."""
        out = []
        for s in self._listening():
            if id_ == BROADCAST_ID or s.id == id_:
                out.append((s, True))
            elif s.secondary_id <= MAX_ID and s.secondary_id == id_:
                out.append((s, False))
        return out

    def _dispatch(self, pkt: InstructionPacket) -> tuple[list[_Reply], list[VirtualServo]]:
        listening = self._listening()
        if not listening:
            self.stats.wrong_baud_packets += 1
            return [], []
        inst = pkt.instruction
        if inst in BUS_INSTRUCTIONS and pkt.id == BROADCAST_ID:
            return self._dispatch_bus(pkt, listening)
        replies: list[_Reply] = []
        touched = []
        broadcast_ping = pkt.id == BROADCAST_ID and inst == Instruction.PING
        for servo, _primary in self._addressed(pkt.id):
            status = servo.execute(pkt)
            touched.append(servo)
            status = servo.filter_reply(pkt, status)
            if status is not None:
                delay = servo.return_delay_s + (self.settings.broadcast_slot_s if broadcast_ping and replies else 0.0)
                replies.append(_Reply(status.encode(), delay))
        return replies, touched

    def _dispatch_bus(self, pkt: InstructionPacket, listening: list[VirtualServo]):
        inst, p = pkt.instruction, pkt.params
        if inst in BUS_WRITES:
            if inst == Instruction.SYNC_WRITE:
                address, _length, data = parse_sync_write(p)
                entries = [(id_, address, d) for id_, d in data.items()]
            else:
                entries = parse_bulk_write(p)
            writers = self._writers(listening)
            touched = []
            for id_, address, d in entries:
                for s in writers.get(id_, ()):
                    s.note_traffic()
                    s.bus_write(address, d)
                    touched.append(s)
            return [], touched
        by_id = {s.id: s for s in listening}
        if inst in SYNC_READS:
            address, length, ids = parse_sync_read(p)
            items = [(i, address, length) for i in ids]
        else:
            items = parse_bulk_read(p)
            if len({i for i, _, _ in items}) != len(items):
                log.debug("bulk read lists an ID twice; ignored")
                return [], []
        if inst in FAST_READS:
            return self._fast_read(items, by_id)
        # every listed servo reads (and publishes its present items) before any reply is built
        frames: list[tuple[VirtualServo | None, bytes]] = []
        for id_, address, length in items:
            s = by_id.get(id_)
            if s is None:
                frames.append((None, b""))
                continue
            s.note_traffic()
            frames.append((s, s.read_frame(address, length)))
        present = [s for s, _ in frames if s is not None]
        if not present:
            return [], []
        replies = []
        for s, frame in frames:
            if s is None:
                if self.settings.sync_chain_break:
                    break
                continue
            replies.append(_Reply(frame, s.return_delay_s))
        return replies, present

    def _fast_read(self, items: list[tuple[int, int, int]], by_id: dict[int, VirtualServo]):
        """Replies and servos read of a Fast Sync/Bulk Read of ``items`` ``(id, address, length)``:
        one combined frame, cut into each answering servo's slice."""
        if fast_status_length([n for _, _, n in items]) > MAX_LENGTH:
            raise CorruptPacketError("fast read reply would exceed the largest frame")
        statuses: list[tuple[VirtualServo | None, StatusPacket]] = []
        for id_, address, length in items:
            s = by_id.get(id_)
            if s is None:
                statuses.append((None, StatusPacket(id_ if id_ <= MAX_ID else 0, 0, bytes(length))))
                continue
            s.note_traffic()
            st = s.read_status(address, length)
            if len(st.params) != length:       # keep the combined frame's layout
                st = StatusPacket(st.id, st.error, bytes(length))
            statuses.append((s, st))
        present = [s for s, _ in statuses if s is not None]
        if not present:
            return [], []
        slices = FastStatus(tuple(st for _, st in statuses)).slices()
        replies = []
        for k, ((s, _), frame) in enumerate(zip(statuses, slices)):
            if s is None:
                if self.settings.sync_chain_break:
                    break
                continue
            replies.append(_Reply(frame, s.return_delay_s if k == 0 else 0.0, fast=True))
        return replies, present

    @staticmethod
    def _writers(listening: list[VirtualServo]) -> dict[int, list[VirtualServo]]:
        """The servos an ID in a Sync/Bulk Write addresses (its ID or Secondary ID), by ID."""
        out: dict[int, list[VirtualServo]] = {}
        for s in listening:
            out.setdefault(s.id, []).append(s)
            if s.secondary_id <= MAX_ID and s.secondary_id != s.id:
                out.setdefault(s.secondary_id, []).append(s)
        return out

    # --- transmit (outside the lock) ------------------------------------------------------------
    def _transmit(self, replies: list[_Reply], start_t: float, byte_t: float | None = None) -> None:
        """Send ``replies`` as the bus would after an instruction that ended at ``start_t``.

        Each reply is due its delay (Return Delay Time, broadcast slot, injected delay) after the
        previous one, plus its bytes with wire timing; the due times are fixed from ``start_t``
        before anything is sent. No reply is written before it is due; replies due within
        :data:`GROUP_WRITE_S` of each other share one write, and the one that ends the exchange
        is written on its own at its due time (so the client sees the exchange end on time).
        """
        if not replies:
            return
        if byte_t is None:
            byte_t = self._byte_time_s()
        if self._transmit_charged(replies, byte_t):
            return
        wire_byte_t = byte_t if self.wire_timing else 0.0
        extra_s = self.faults.delay_s
        due, t = [], start_t
        frames, gaps = [], []
        for r, frame in self._surviving(replies):
            t += r.delay_s + extra_s + len(frame) * wire_byte_t   # the last byte leaves the cable then
            due.append(t)
            frames.append(frame)
            gaps.append(r.delay_s + extra_s)
        n = len(frames)
        if not n:
            return
        if self.adapter is not None and self.wire_timing:
            due = self._through_adapter(start_t, gaps, frames, byte_t)
        i = 0
        while i < n:
            now = time.monotonic()
            j = i
            while j + 1 < n and (due[j + 1] <= now
                                 or (j + 1 < n - 1 and due[j + 1] - due[i] <= GROUP_WRITE_S)):
                j += 1
            if due[j] > now:
                self._sleep_until(due[j])
            self._write(b"".join(frames[i:j + 1]))
            i = j + 1
        # the pty hands written bytes to the reader through a kernel worker; on a busy core it
        # waits until this thread blocks, so give it the core now (one syscall, no spinning)
        os.sched_yield()

    def _surviving(self, replies: list[_Reply]):
        """``(reply, frame)`` for each reply fault injection lets through (``frame`` perhaps
        corrupted), drawing faults in reply order (a fast-read frame draws once); counts them."""
        faults = self.faults
        if faults.drop_rate <= 0 and faults.corrupt_rate <= 0:     # nothing to draw
            self.stats.replies_sent += len(replies)
            for r in replies:
                yield r, r.frame
            return
        fast_dropped = fast_drawn = False
        for r in replies:
            if r.fast:
                if not fast_drawn:
                    fast_dropped, fast_drawn = faults.should_drop(), True
                    if fast_dropped:
                        self.stats.replies_dropped += 1
                if fast_dropped:
                    continue
            elif faults.should_drop():
                self.stats.replies_dropped += 1
                continue
            frame, corrupted = faults.maybe_corrupt(r.frame)
            if corrupted:
                self.stats.replies_corrupted += 1
            self.stats.replies_sent += 1
            yield r, frame

    def _transmit_charged(self, replies: list[_Reply], byte_t: float) -> bool:
        """Offer the replies' wire time to the clock; if it charges it (lockstep), send them at
        once and return True. Fault draws happen in the same order as with wall pacing.

        With an adapter, the clock is also charged the time the adapter holds the last byte
        after it left the cable (``hold_s``); every reply's bytes count, a dropped one's too
        (its wire time is charged as well)."""
        extra_s, wire_s, answering, fast = self.faults.delay_s, 0, 0, 0
        latency = self.clock.reply_latency_s
        gaps = []
        for r in replies:
            wire_s += r.delay_s + extra_s + len(r.frame) * byte_t
            starts = not r.fast or not fast        # a combined fast-read frame answers once
            if r.fast:
                fast = 1
            else:
                answering += 1
            gaps.append((r.delay_s + extra_s + (latency if starts else 0.0), len(r.frame)))
        answering += fast
        hold_s, delivery = 0.0, None
        if self.adapter is not None:
            start = self.robot_time_s()
            delivery = self.adapter.plan(byte_arrivals(start, gaps, byte_t))
            hold_s = max(0.0, delivery.end_s - (start + wire_s + answering * latency))
        if not self.clock.on_replies(self, wire_s, answering, hold_s):
            return False
        if delivery is not None:
            self.adapter.commit(delivery)
        self._write(b"".join(frame for _, frame in self._surviving(replies)))
        return True

    def _through_adapter(self, start_t: float, gaps: list[float], frames: list[bytes],
                         byte_t: float) -> list[float]:
        """Wall time at which the host has each of ``frames`` (its last byte) through the
        adapter, the frames leaving the cable back to back from ``start_t`` after their ``gaps``."""
        delivery = self.adapter.plan(byte_arrivals(start_t, list(zip(gaps, map(len, frames))), byte_t))
        self.adapter.commit(delivery)
        ends, k = [], 0
        for f in frames:
            k += len(f)
            ends.append(delivery.times_s[k - 1])
        return ends

    def _write(self, data: bytes) -> None:
        if data:
            sent = self._pty.write(bytes(data))
            self.tx_bytes += sent
            self.stats.tx_overflow_bytes += len(data) - sent

    def _sleep_until(self, deadline: float) -> None:
        """Block until ``deadline`` (monotonic s), never before it; long waits end early when the
        bus closes. The calling thread gets fine timer slack first (:func:`precise_timers`)."""
        precise_timers()
        remaining = deadline - time.monotonic()
        if remaining > 2e-3:
            self._stop.wait(remaining)
        while (remaining := deadline - time.monotonic()) > 0 and not self._stop.is_set():
            time.sleep(remaining)

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
        with self._lock:
            self._tick(dt_s)

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

    def step_many(self, dt_s: float, n: int) -> None:
        """``n`` clock steps of ``dt_s`` simulated s; the same result as ``n`` calls of
        :meth:`step` (nothing from the bus can come in between). The lock is held for at most
        :data:`MAX_STEPS_PER_HOLD` steps at a time, and handed over when another thread waits."""
        while n > 0:
            k = min(n, MAX_STEPS_PER_HOLD)
            with self._lock:
                self._ticks(dt_s, k)
            n -= k
            if n and self.lock_wanted():
                time.sleep(HAND_OVER_S)

    def _tick(self, dt_s: float) -> None:
        for s in self.servos:
            s.advance(dt_s)
        if self.world is not None:
            self.world.step(dt_s)
        self.sim_time_s += dt_s
        self.stats.clock_ticks += 1

    def _ticks(self, dt_s: float, n: int) -> None:
        """``n`` :meth:`_tick` s. Where the servos do not interact within a step (no shared noise
        draws, a body that does not load the shafts), each servo runs all ``n`` steps at once
        (:meth:`VirtualServo.advance_many`) and the body follows from their recorded states."""
        traces = self._batch_traces() if n > 1 else None
        if traces is None:
            n -= self._coupled_ticks(dt_s, n)
            for _ in range(n):
                self._tick(dt_s)
            return
        for s in self.servos:
            s.advance_many(dt_s, n, traces)
        if self.world is not None:
            self.world.step_many(dt_s, n, traces)
        for _ in range(n):                  # the same float sum as n single ticks
            self.sim_time_s += dt_s
        self.stats.clock_ticks += n

    def _coupled_ticks(self, dt_s: float, n: int) -> int:
        """Up to ``n`` :meth:`_tick` s run by a world whose servos and body step together in one
        call (``world.run_coupled``, e.g. a robot on tyres); returns how many ran (0: none)."""
        run = self.world.run_coupled if n > 1 and self.world is not None else None
        done = 0
        while run is not None and done < n:
            ran = run(self.servos, dt_s, n - done)
            if not ran:
                break
            for _ in range(ran):            # the same float sum as single ticks
                self.sim_time_s += dt_s
            self.stats.clock_ticks += ran
            done += ran
        return done

    def _batch_traces(self) -> dict | None:
        """The trace lists for a batched run of steps (``{}`` without a world), or ``None`` if
        the steps must interleave servo by servo."""
        for s in self.servos:
            d = s.dynamics
            if d is not None and not d.batchable:
                return None
        if self.world is None:
            return {}
        return self.world.traces()

    def advance(self, dt_s: float) -> None:
        """Advance simulated time by ``dt_s`` s at once, in steps of at most ``1/clock.rate_hz``
        (tests and benches; works with any clock)."""
        with self._lock:
            steps = max(1, round(dt_s * self.clock.rate_hz))
            self._ticks(dt_s / steps, steps)
            for observer in self.observers:
                observer(self)

    # --- true state (never through the bus) ----------------------------------------------------
    @property
    def pose(self) -> tuple[float, float, float]:
        """True body pose ``(x_m, y_m, theta_rad)`` (needs a world)."""
        return self.true_state()[1]

    def true_state(self) -> tuple[float, tuple[float, float, float]]:
        """``(sim_time_s, (x_m, y_m, theta_rad))`` read under one lock (a coherent pair)."""
        if self.world is None:
            raise ConfigError("this emulated bus has no robot body, so no pose")
        with self._lock:
            return self.sim_time_s, self.world.pose

    @property
    def clock_stats(self) -> ClockStats:
        return self.clock.stats
