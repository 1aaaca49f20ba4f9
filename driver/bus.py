"""A Dynamixel Protocol 2.0 bus: every instruction, one lock, exceptions instead of codes.

::

    with Bus("/dev/ttyUSB0", 1_000_000) as bus:
        print(bus.ping(1))                                   # PingResult(id=1, model_number=1010, ...)
        bus.write(1, Reg.TORQUE_ENABLE, 1)
        pos = bus.read(1, Reg.PRESENT_POSITION)              # raw, sign-extended
        rad = bus.read_si(1, Reg.PRESENT_POSITION)           # rad
        state = bus.sync_read([1, 2], Reg.PRESENT_CURRENT, Reg.PRESENT_POSITION)

Values are raw integers (signed where the item is signed) unless a method says ``_si``.
Raw values are range-checked against the control table before anything is sent
(:class:`OutOfRangeError`; nothing is clamped). The model of each ID comes from the
``models`` argument, else from a Ping (cached), else ``default_model``.

Failures raise :mod:`driver.errors` exceptions: :class:`DxlTimeoutError` (ids,
instruction, timeout_s), :class:`CorruptPacketError`/:class:`ChecksumError`,
:class:`ServoError` (id, error_number, alert, hardware_error — Hardware Error Status is
read once when the alert bit is set), :class:`RegisterError`, :class:`TransportError`.
Replies from IDs that were not asked are ignored and counted in :attr:`Bus.stray_replies`.
"""
from __future__ import annotations

import contextlib
import math
import struct
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterable, Iterator, Mapping, Protocol, Sequence

from swerve.driver import packets as pk
from swerve.driver.control_table import ControlTable, HardwareError, Reg, Register, table_for
from swerve.driver.errors import (ConfigError, CorruptPacketError, DxlError, DxlTimeoutError,
                           RegisterError, ServoError)
from swerve.driver.packets import (BROADCAST_ID, ExpectedStatus, FastStatus, Instruction, InstructionPacket,
                                   StatusPacket, fast_status_bytes)
from swerve.driver.span_codec import STRUCT_CODES, span_decoder, span_values
from swerve.driver.transport import DEFAULT_MARGIN_S, Transport, packet_timeout_s

#: Bytes of a status packet without parameters (header 4, ID, LEN 2, 0x55, ERR, CRC 2).
STATUS_OVERHEAD = 11
#: Wall time a reply the gate says was sent may take to arrive, s (a loaded host delivers late).
GATE_WAIT_S = 30.0
#: Broadcast-ping slot budgeted per possible ID, s (what ROBOTIS host libraries allow).
BROADCAST_PING_SLOT_S = 0.003

RegLike = str | Reg

#: Reads whose replies form a chain in request order (a silent servo cuts off those after it).
_CHAINED_READS = frozenset((Instruction.SYNC_READ, Instruction.BULK_READ))
#: Sync Read and Bulk Write plans kept for reuse (the control loop repeats one of each).
_REQUEST_CACHE_SIZE = 32


class ReplyGate(Protocol):
    """A peer that can say how many bytes it has sent back (a lockstep emulator's control channel).

    With a gate, a reply the wall-clock timeout missed is not given up on until the peer has said
    it never sent it: the outcome of an exchange then depends only on what the peer did, not on
    how fast the host delivered it.
    """

    def bytes_sent(self) -> int:
        """Bytes the peer has written to the port since this bus opened it, counted after the
        peer has served every byte written to it so far."""


@dataclass(frozen=True)
class ExchangeSettings:
    """How a :class:`Bus` waits for replies and retries.

    ``retries``: extra attempts after a timeout or corrupt reply (never for Reboot, Factory Reset,
    Clear, Backup); ``timeout_margin_s``: slack added to every computed reply timeout, s (raise it
    for a software emulator on a loaded machine).
    """

    retries: int = 0
    timeout_margin_s: float = DEFAULT_MARGIN_S

    def __post_init__(self):
        if isinstance(self.retries, bool) or not isinstance(self.retries, int) or self.retries < 0:
            raise ValueError(f"retries must be a whole number >= 0, got {self.retries!r}")
        if not (math.isfinite(self.timeout_margin_s) and self.timeout_margin_s >= 0):
            raise ValueError(f"timeout margin must be a finite time >= 0 s, got {self.timeout_margin_s!r}")


@dataclass(frozen=True)
class PingResult:
    """A servo that answered Ping: ``id``, ``model_number``, catalogue ``model`` name, ``firmware``."""

    id: int
    model_number: int
    model: str
    firmware: int


def _ping_result(st: StatusPacket) -> PingResult:
    if len(st.params) != 3:
        raise CorruptPacketError(f"ping reply from ID {st.id} has {len(st.params)} parameter bytes, expected 3")
    number, fw = struct.unpack("<HB", st.params)
    try:
        model = table_for(number).model
    except ConfigError:
        model = f"unknown ({number})"
    return PingResult(st.id, number, model, fw)


class Bus:
    """One serial bus of Protocol 2.0 servos.

    ``port``: URL for :func:`serial.serial_for_url`; ``baud``: bps. ``models``: known
    model (name or number) per ID; ``default_model`` for IDs neither given nor pinged
    (``None``: ping to find out). ``retries`` and ``timeout_margin_s``: the
    :class:`ExchangeSettings` (:attr:`exchange`; :meth:`exchanging` applies others for a block).
    ``return_delay_us``: the servos' Return Delay Time (servo default 500 us).
    """

    def __init__(self, port: str, baud: int = 1_000_000, *,
                 models: Mapping[int, str | int] | None = None,
                 default_model: str | int | None = None, retries: int = 0,
                 return_delay_us: float = 500.0, timeout_margin_s: float = DEFAULT_MARGIN_S,
                 latency_timer_ms: float | None = None):
        #: How exchanges wait and retry (:class:`ExchangeSettings`).
        self.exchange = ExchangeSettings(int(retries), float(timeout_margin_s))
        self.port = port
        self.baud = int(baud)
        self.return_delay_us = float(return_delay_us)
        self._lock = threading.Lock()
        self._tables: dict[int, ControlTable] = {i: table_for(m) for i, m in (models or {}).items()}
        self._default = table_for(default_model) if default_model is not None else None
        self._transport = Transport(port, baud)
        self.latency_timer_ms = (self._transport.latency_timer_ms if latency_timer_ms is None
                                 else float(latency_timer_ms))
        #: Replies from IDs that were not addressed (ignored), and frames dropped as corrupt.
        self.stray_replies = 0
        self.corrupt_frames = 0
        self.drained_bytes = 0      # late bytes discarded after a failed exchange
        self._unsettled = False     # last exchange failed: drain before the next one
        self._gate: ReplyGate | None = None
        # per-request plans: sync reads (_SyncReadPlan) and bulk write layouts (BulkWritePlan)
        self._plans: dict[tuple, tuple] = {}

    # --- lifecycle ---------------------------------------------------------------------------

    def close(self) -> None:
        """Close the port (idempotent)."""
        self._transport.close()

    def __enter__(self) -> "Bus":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Bus({self.port!r}, {self.baud})"

    @property
    def retries(self) -> int:
        """Extra attempts after a timeout or corrupt reply (:attr:`exchange`)."""
        return self.exchange.retries

    @property
    def timeout_margin_s(self) -> float:
        """Slack added to every computed reply timeout, s (:attr:`exchange`)."""
        return self.exchange.timeout_margin_s

    @contextlib.contextmanager
    def exchanging(self, settings: ExchangeSettings) -> Iterator["Bus"]:
        """Use ``settings`` for the exchanges inside the ``with`` block (e.g. retries while the
        servos are set up), then the bus's own again, also when the block raises."""
        saved, self.exchange = self.exchange, settings
        try:
            yield self
        finally:
            self.exchange = saved

    @property
    def bytes_written(self) -> int:
        """Bytes sent to the port since it was opened (what a lockstep clock's barrier counts)."""
        return self._transport.bytes_written

    @property
    def bytes_received(self) -> int:
        """Bytes that came in on the port since it was opened (read or discarded unread)."""
        return self._transport.bytes_received

    def gate_replies(self, gate: ReplyGate | None) -> None:
        """Ask ``gate`` before an exchange gives up on a reply (``None``: the timeout decides)."""
        self._gate = gate

    def call_after_write(self, callback: Callable[[], None] | None) -> None:
        """Call ``callback()`` each time an instruction's bytes have been sent, before its reply
        is awaited (a lockstep clock announces them to its emulator then); None: stop."""
        self._transport.after_write = callback

    # --- models ------------------------------------------------------------------------------

    def table(self, id_: int) -> ControlTable:
        """Control table of servo ``id_`` (given, cached from Ping, default, or pinged now)."""
        t = self._tables.get(id_) or self._default
        if t is None:
            self.ping(id_)
            t = self._tables[id_]
        return t

    def set_model(self, id_: int, model: str | int | ControlTable) -> None:
        """Declare the model of servo ``id_`` (name, number or table) so no Ping is needed."""
        self._tables[id_] = model if isinstance(model, ControlTable) else table_for(model)
        self._plans.clear()

    def register(self, id_: int, reg: RegLike) -> Register:
        """The :class:`Register` named ``reg`` for servo ``id_`` (RegisterError if unknown)."""
        return self.table(id_)[reg]

    def _learn(self, res: PingResult) -> None:
        try:
            self._tables[res.id] = table_for(res.model_number)
            self._plans.clear()
        except ConfigError:
            pass

    # --- the transaction core ----------------------------------------------------------------

    def timeout_s(self, nbytes: int, nreplies: int = 1) -> float:
        """Reply timeout for ``nbytes`` on the wire and ``nreplies`` return delays, s."""
        return packet_timeout_s(self.baud, nbytes, self.return_delay_us * max(1, nreplies),
                                self.latency_timer_ms, self.timeout_margin_s)

    def _exchange(self, pkt: InstructionPacket, expect: Sequence[int], reply_bytes: int,
                  *, window_s: float | None = None, until_all: bool = True,
                  check: bool = True, frame: bytes | None = None,
                  fast_lengths: Sequence[int] | None = None,
                  statuses: Mapping[int, ExpectedStatus] | None = None) -> dict[int, StatusPacket]:
        """Send ``pkt`` and collect one status per ID in ``expect`` (lock held by caller).

        Returns ``{id: status}``. Raises DxlTimeoutError for IDs that stayed silent (or
        the corrupt-frame error if one arrived instead), ServoError for an error byte
        when ``check``. ``until_all=False`` (broadcast ping) listens for the whole window.
        ``frame``: ``pkt`` already encoded. ``fast_lengths``: the data lengths of a fast
        read; the combined reply is returned as ``{0xFE: FastStatus}``. ``statuses``: the replies
        expected, decoded by their cached heads (:meth:`PacketParser.expect_statuses`).
        """
        transport = self._transport
        if frame is None:
            frame = pkt.encode()
        timeout = 0.0
        if expect or self._unsettled:
            timeout = window_s if window_s is not None else self.timeout_s(len(frame) + reply_bytes,
                                                                          len(expect))
        if self._unsettled:  # the last exchange failed: let late replies land before sending
            self.drained_bytes += transport.drain_quiet(self.timeout_margin_s, 10 * timeout)
            self._unsettled = False
        transport.parser.expect_fast(fast_lengths)
        if statuses is not None:
            transport.parser.expect_statuses(statuses)
        transport.write(frame)
        if not expect:
            return {}
        wanted = set(expect)
        got: dict[int, StatusPacket] = {}
        deadline = time.monotonic() + timeout
        corrupt: list[CorruptPacketError] = []
        erred = False               # a reply carries an error byte
        due: int | None = None      # bytes the gate says were sent; all of them are in when reached
        while not wanted <= got.keys():
            if due is not None and transport.bytes_received >= due:
                batch = transport.parser.flush() if transport.parser.pending else []
            else:
                batch = transport.read_packets(deadline)
            if transport.parser.errors:
                errs = transport.parser.take_errors()
                self.corrupt_frames += len(errs)
                corrupt += errs
            if not batch:
                if due is not None and transport.bytes_received >= due:
                    break
                if time.monotonic() >= deadline:
                    if self._gate is None or due is not None:
                        break
                    due = self._gate.bytes_sent()
                    deadline = time.monotonic() + GATE_WAIT_S
                continue
            for p in batch:
                if isinstance(p, StatusPacket):
                    i = p.id
                    if i in wanted and i not in got:
                        got[i] = p
                        if p.error:
                            erred = True
                    else:
                        self.stray_replies += 1
                elif isinstance(p, FastStatus):
                    if fast_lengths is not None and BROADCAST_ID not in got:
                        got[BROADCAST_ID] = p
                    else:
                        self.stray_replies += 1
                # anything else is our own echo (loop://, half-duplex adapters) or another host's
        if fast_lengths is not None:
            transport.parser.expect_fast(None)
        if statuses is not None:
            transport.parser.expect_statuses(None)
        missing = [] if len(got) == len(wanted) else [i for i in expect if i not in got]
        if ((missing and until_all) or corrupt) and not (due is not None and transport.bytes_received >= due):
            self._unsettled = True      # a late reply may still come (a gate said none will)
        if missing and until_all:
            if corrupt:
                err = corrupt[-1]
                err.args = (f"{err} (reply to {pkt.name} from ID {', '.join(map(str, missing))})",)
                raise err
            # Sync/Bulk Read replies come in request order, each servo waiting for the one
            # before it: when every ID after the first silent one is silent too, they were
            # cut off behind it
            chained = (pkt.instruction in _CHAINED_READS
                       and list(expect[len(expect) - len(missing):]) == missing)
            raise DxlTimeoutError(missing, pkt.instruction, timeout, cut_off=chained)
        if check and erred:
            for i in expect:
                if i in got and got[i].error:
                    self._raise_status(got[i], pkt.instruction)
        return got

    def _raise_status(self, st: StatusPacket, instruction: int) -> None:
        hw = None
        if st.alert:
            try:
                table = self._tables.get(st.id) or self._default
                address = table[Reg.HARDWARE_ERROR_STATUS].address if table else 70
                data = self._read_raw(st.id, address, 1, check=False)
                hw = HardwareError.describe(data[0])
            except DxlError:
                hw = None
        raise ServoError(st.id, st.error, instruction, hw)

    def _with_retries(self, fn, *args, retry: bool = True, **kw):
        attempts = 1 + (self.retries if retry else 0)
        with self._lock:
            for n in range(attempts):
                try:
                    result = fn(*args, **kw)
                except (DxlTimeoutError, CorruptPacketError):
                    if n == attempts - 1:
                        raise
                    continue
                if n:  # a retry answered; the failed try's late replies may still be coming
                    self._unsettled = True
                return result

    def _read_raw(self, id_: int, address: int, length: int, *, check: bool = True) -> bytes:
        got = self._exchange(pk.read(id_, address, length), [id_], STATUS_OVERHEAD + length,
                             check=check)
        data = got[id_].params
        if len(data) != length:
            if got[id_].error and not check:
                return data.ljust(length, b"\0")
            raise CorruptPacketError(f"read reply from ID {id_} carries {len(data)} bytes, expected {length}")
        return data

    def _simple(self, pkt: InstructionPacket, *, check: bool = True, ignore_alert: bool = False) -> None:
        expect = [] if pkt.id == BROADCAST_ID else [pkt.id]
        got = self._exchange(pkt, expect, STATUS_OVERHEAD, check=False)
        if check and expect:
            st = got[pkt.id]
            err = st.error & ~pk.ALERT_BIT if ignore_alert else st.error
            if err:
                self._raise_status(st, pkt.instruction)

    # --- ping and scan ----------------------------------------------------------------------

    def ping(self, id_: int) -> PingResult:
        """Ping one servo; learns (caches) its model. Raises DxlTimeoutError if absent."""
        if not 0 <= id_ <= pk.MAX_ID:
            raise ValueError(f"invalid servo ID {id_} for ping (0..252)")

        def once():
            got = self._exchange(pk.ping(id_), [id_], STATUS_OVERHEAD + 3, check=False)
            return _ping_result(got[id_])

        res = self._with_retries(once)
        self._learn(res)
        return res

    def broadcast_ping(self, ids: Iterable[int] | None = None) -> dict[int, PingResult]:
        """Broadcast Ping; every servo answering within the window, ``{id: PingResult}``.

        ``ids`` only bounds the listening window (3 ms per ID up to the highest) and lets
        the call return early once all of them have answered.
        """
        ids = sorted(set(range(0, pk.MAX_ID + 1) if ids is None else ids))
        top = (ids[-1] + 1) if ids else pk.MAX_ID + 1
        window = self.timeout_s(10 + 14 * top, top) + BROADCAST_PING_SLOT_S * top
        with self._lock:
            got = self._exchange(pk.ping(BROADCAST_ID), ids, (STATUS_OVERHEAD + 3) * len(ids),
                                 window_s=window, until_all=False, check=False)
            # _exchange returns once all listed IDs answered; replies from unlisted IDs are strays
        out = {}
        for i, st in sorted(got.items()):
            try:
                res = _ping_result(st)
            except CorruptPacketError:
                continue
            self._learn(res)
            out[i] = res
        return out

    def scan(self, ids: Iterable[int] = range(0, pk.MAX_ID + 1), *, broadcast: bool = True) -> list[PingResult]:
        """Find servos among ``ids``: broadcast ping first, then a unicast ping of each ID
        it did not find (collisions or servos that ignore broadcast). Sorted by ID."""
        ids = sorted(set(ids))
        found: dict[int, PingResult] = {}
        if broadcast and ids:
            found.update(self.broadcast_ping(ids))
        for i in ids:
            if i in found:
                continue
            try:
                found[i] = self.ping(i)
            except (DxlTimeoutError, CorruptPacketError):
                pass
        return [found[i] for i in sorted(found)]

    # --- read / write ------------------------------------------------------------------------

    def read_bytes(self, id_: int, address: int, length: int) -> bytes:
        """Raw bytes from ``address``; the building block of :meth:`read`."""
        return self._with_retries(self._read_raw, id_, address, length)

    def read(self, id_: int, reg: RegLike) -> int:
        """Raw value of ``reg`` on servo ``id_`` (sign-extended where the item is signed)."""
        r = self.register(id_, reg)
        return r.decode(self.read_bytes(id_, r.address, r.size))

    def read_si(self, id_: int, reg: RegLike) -> float:
        """``reg`` in SI units (``Register.unit``: rad, rad/s, A, V, s ...)."""
        r = self.register(id_, reg)
        return r.to_si(self.read(id_, reg))

    def hardware_error(self, id_: int) -> int:
        """Hardware Error Status (70) bits, read even while the alert bit is set."""
        r = self.register(id_, Reg.HARDWARE_ERROR_STATUS)
        return r.decode(self._with_retries(self._read_raw, id_, r.address, r.size, check=False))

    def _writable(self, id_: int, reg: RegLike) -> Register:
        """The :class:`Register` ``reg`` of servo ``id_``; RegisterError if it is read-only."""
        r = self.register(id_, reg)
        if not r.writable:
            raise RegisterError(f"{r.name} is read-only (servo ID {id_})")
        return r

    def _encode_write(self, id_: int, reg: RegLike, raw: int) -> tuple[Register, bytes]:
        r = self._writable(id_, reg)
        return r, r.encode(r.check_raw(int(raw)))

    def write_bytes(self, id_: int, address: int, data: bytes) -> None:
        """Write raw bytes at ``address`` (no range checks); broadcast ID is silent."""
        self._with_retries(self._simple, pk.write(id_, address, data))

    def write(self, id_: int, reg: RegLike, raw: int) -> None:
        """Write raw value ``raw`` to ``reg`` (range-checked; OutOfRangeError, never clamped)."""
        r, data = self._encode_write(id_, reg, raw)
        self.write_bytes(id_, r.address, data)

    def write_si(self, id_: int, reg: RegLike, value: float) -> None:
        """Write ``value`` in SI units (``Register.unit``); raises if out of range."""
        r = self.register(id_, reg)
        self.write(id_, reg, r.from_si(value))

    def reg_write(self, id_: int, reg: RegLike, raw: int) -> None:
        """Reg Write: stage ``raw`` for ``reg``, executed by :meth:`action`."""
        r, data = self._encode_write(id_, reg, raw)
        self._with_retries(self._simple, pk.reg_write(id_, r.address, data))

    def action(self, id_: int = BROADCAST_ID) -> None:
        """Action: execute staged Reg Writes (broadcast by default: no reply)."""
        self._with_retries(self._simple, pk.action(id_), retry=False)

    def reboot(self, id_: int) -> None:
        """Reboot (clears a latched hardware error; the servo answers, then restarts ~1 s)."""
        self._with_retries(self._simple, pk.reboot(id_), retry=False, ignore_alert=True)

    def factory_reset(self, id_: int, option: int = pk.ResetOption.EXCEPT_ID_BAUD) -> None:
        """Factory Reset (``option``: ResetOption; default keeps ID and baud rate)."""
        self._with_retries(self._simple, pk.factory_reset(id_, option), retry=False)
        self._tables.pop(id_, None)
        self._plans.clear()

    def clear(self, id_: int) -> None:
        """Clear multi-turn position (only when stopped, else ServoError Result Fail)."""
        self._with_retries(self._simple, pk.clear(id_), retry=False)

    def backup(self, id_: int, restore: bool = False) -> None:
        """Control Table Backup: store (default) or restore (torque must be off)."""
        self._with_retries(self._simple, pk.control_table_backup(id_, restore), retry=False)

    # --- group instructions ------------------------------------------------------------------

    def _group_table(self, ids: Sequence[int]) -> ControlTable:
        if not ids:
            raise ValueError("no servo IDs given")
        if len(set(ids)) != len(ids):
            raise ValueError(f"duplicate IDs in {list(ids)}")
        tables = {self.table(i).model for i in ids}
        t = self.table(ids[0])
        if len(tables) > 1:
            raise ConfigError(f"sync read/write over different models {sorted(tables)}: use bulk")
        return t

    @staticmethod
    def _decode_span(table: ControlTable, address: int, data: bytes) -> dict[str, int]:
        return span_decoder(table, address, len(data))(data)

    def sync_read(self, ids: Sequence[int], first: RegLike, last: RegLike | None = None,
                  fast: bool = False) -> dict[int, dict[str, int]]:
        """Sync Read (or Fast Sync Read) of ``first``..``last`` from every ID, one request.

        Returns ``{id: {register name: raw}}`` for every register fully inside the span.
        """
        ids = tuple(ids)
        names, rows = self.sync_read_rows(ids, first, last, fast)
        return {i: dict(zip(names, row)) for i, row in zip(ids, rows)}

    def sync_read_rows(self, ids: Sequence[int], first: RegLike, last: RegLike | None = None,
                       fast: bool = False) -> tuple[tuple[str, ...], list[tuple[int, ...]]]:
        """:meth:`sync_read` as ``(names, rows)``: the names of the registers fully inside the
        span in address order, and per ID (in the order of ``ids``) a tuple of their raw values
        in that order. No dict is built: the form for a loop that reads the same span each cycle.
        """
        key = (tuple(ids), first, last, fast)
        plan = self._plans.get(key)
        if plan is None:
            plan = self._sync_read_plan(key[0], first, last, fast)
            if len(self._plans) >= _REQUEST_CACHE_SIZE:
                self._plans.clear()
            self._plans[key] = plan
        data = self._with_retries(self._sync_read_once, plan)
        values = plan.values
        return plan.names, [values(d) for d in data]

    def _sync_read_plan(self, ids: tuple[int, ...], first: RegLike, last: RegLike | None,
                        fast: bool) -> "_SyncReadPlan":
        t = self._group_table(ids)
        address, length = t.span(first, last if last is not None else first)
        pkt = pk.sync_read(address, length, ids, fast=fast)
        return _SyncReadPlan(ids, length, *span_values(t, address, length), pkt, pkt.encode(),
                             None if fast else {i: ExpectedStatus.of(i, length) for i in ids},
                             (STATUS_OVERHEAD + length) * len(ids))

    def _sync_read_once(self, plan: "_SyncReadPlan") -> list[bytes]:
        """The data of each ID's reply, in the order of the plan's IDs."""
        ids, length = plan.ids, plan.length
        if plan.statuses is None:
            return self._fast_exchange(plan.packet, [(i, length) for i in ids], plan.frame)
        got = self._exchange(plan.packet, ids, plan.reply_bytes, frame=plan.frame, statuses=plan.statuses)
        out = [got[i].params for i in ids]
        for i, data in zip(ids, out):
            if len(data) != length:
                raise CorruptPacketError(f"sync read reply from ID {i} carries "
                                         f"{len(data)} bytes, expected {length}")
        return out

    def _fast_exchange(self, pkt: InstructionPacket, items: list[tuple[int, int]],
                       frame: bytes | None = None) -> list[bytes]:
        """Send a fast sync/bulk read and split the single combined reply: the data of each
        entry, in the order of ``items``."""
        ids = [i for i, _ in items]
        lengths = [n for _, n in items]
        reply_bytes = fast_status_bytes(lengths)
        try:
            got = self._exchange(pkt, [BROADCAST_ID], reply_bytes, check=False, frame=frame,
                                 fast_lengths=lengths)
        except DxlTimeoutError as exc:
            k = self._transport.parser.fast_entries_received
            if k is not None and k < len(ids):
                # the servos send their slices in turn: the first missing slice names the culprit
                raise DxlTimeoutError(ids[k:], pkt.instruction, exc.timeout_s,
                                      f"the combined reply stopped after {k} of {len(ids)} slices; "
                                      f"ID {ids[k]} is missing or does not support fast reads",
                                      cut_off=True) from None
            raise DxlTimeoutError(ids, pkt.instruction, exc.timeout_s,
                                  "the combined reply was incomplete: one of these servos is "
                                  "missing or does not support fast reads") from None
        except CorruptPacketError as exc:
            raise CorruptPacketError(f"fast read reply for IDs {ids} is malformed: {exc}") from None
        out = []
        for (i, _), e in zip(items, got[BROADCAST_ID].entries):
            if e.id != i:
                raise CorruptPacketError(f"fast read reply lists ID {e.id} where ID {i} was expected")
            if e.error:
                self._raise_status(e, pkt.instruction)
            out.append(e.params)
        return out

    def sync_write(self, reg: RegLike, values: Mapping[int, int]) -> None:
        """Sync Write raw ``values`` ``{id: raw}`` to ``reg`` (no reply; range-checked first)."""
        ids = list(values)
        self._group_table(ids)
        data = {}
        for i, raw in values.items():
            r, data[i] = self._encode_write(i, reg, raw)
        self._with_retries(self._simple, pk.sync_write(r.address, r.size, data))

    def bulk_read(self, items: Mapping[int, RegLike | tuple[RegLike, RegLike]],
                  fast: bool = False) -> dict[int, dict[str, int]]:
        """Bulk Read (or Fast Bulk Read): ``{id: reg}`` or ``{id: (first, last)}``, one request.

        Returns ``{id: {register name: raw}}``.
        """
        spans = []
        for i, what in items.items():
            first, last = what if isinstance(what, tuple) else (what, what)
            t = self.table(i)
            spans.append((i, t) + t.span(first, last))
        pkt = pk.bulk_read([(i, a, n) for i, _, a, n in spans], fast=fast)

        def once():
            if fast:
                return dict(zip(items, self._fast_exchange(pkt, [(i, n) for i, _, _, n in spans])))
            ids = [i for i, *_ in spans]
            got = self._exchange(pkt, ids, sum(STATUS_OVERHEAD + n for *_, n in spans))
            for i, _, _, n in spans:
                if len(got[i].params) != n:
                    raise CorruptPacketError(f"bulk read reply from ID {i} carries "
                                             f"{len(got[i].params)} bytes, expected {n}")
            return {i: got[i].params for i in ids}

        raw = self._with_retries(once)
        return {i: self._decode_span(t, a, raw[i]) for i, t, a, _ in spans}

    def bulk_write(self, items: Mapping[int, Mapping[RegLike, int]]) -> None:
        """Bulk Write ``{id: {reg: raw, ...}}`` (each ID's registers must be contiguous), no reply."""
        key = ("bulk write",) + tuple((i, tuple(regs)) for i, regs in items.items())
        plan = self._plans.get(key)
        if plan is None:
            plan = self.bulk_write_plan(key[1:])
            if len(self._plans) >= _REQUEST_CACHE_SIZE:
                self._plans.clear()
            self._plans[key] = plan
        self.bulk_write_values(plan, [items[i][name] for i, name in plan.names])

    def bulk_write_plan(self, items: Sequence[tuple[int, Sequence[RegLike]]]) -> "BulkWritePlan":
        """The :class:`BulkWritePlan` of a Bulk Write of ``items``, ``(id, (reg, ...))`` per servo;
        raises for a read-only or non-contiguous register, or an ID that is invalid or listed twice."""
        entries, names, regs = [], [], []
        for i, group in items:
            found = sorted(((name, self._writable(i, name)) for name in group), key=lambda nr: nr[1].address)
            if not found:
                raise ValueError(f"bulk write for ID {i} names no register")
            start = end = found[0][1].address
            for _, r in found:
                if r.address != end:
                    raise ValueError(f"bulk write for ID {i}: {r.name} is not contiguous with the "
                                     f"registers before it")
                end += r.size
            entries.append((i, start, end - start, len(found)))
            names += [(i, name) for name, _ in found]
            regs += [r for _, r in found]
        pk.bulk_write([(i, start, bytes(n)) for i, start, n, _ in entries])     # checks the IDs
        return BulkWritePlan.build(entries, tuple(names), tuple(regs))

    def bulk_write_values(self, plan: "BulkWritePlan", values: Sequence[int]) -> None:
        """Send the Bulk Write of ``plan`` with raw ``values``, one per register in the plan's order
        (:attr:`BulkWritePlan.names`); each is range-checked first (OutOfRangeError, nothing sent)."""
        self._with_retries(self._simple, pk.InstructionPacket(BROADCAST_ID, Instruction.BULK_WRITE,
                                                              plan.params(values)))


@dataclass(frozen=True)
class _SyncReadPlan:
    """A Sync Read (or Fast Sync Read) of the same span from the same IDs, worked out once: the
    register ``names`` wholly inside the ``length``-byte span and ``values(data) -> raws`` for
    one ID's data (:func:`span_values`), the request ``packet`` and its ``frame``, the replies
    expected (``statuses`` per ID; ``None`` for a fast read) and their bytes on the wire."""

    ids: tuple[int, ...]
    length: int
    names: tuple[str, ...]
    values: Callable[[bytes], tuple[int, ...]]
    packet: InstructionPacket
    frame: bytes
    statuses: dict[int, ExpectedStatus] | None
    reply_bytes: int


@dataclass(frozen=True)
class BulkWritePlan:
    """A Bulk Write of the same registers each time (the control loop's goals), worked out once.

    ``names``: ``(id, reg)`` of each value, in the order :meth:`params` takes them (per servo, in
    address order); ``regs``: their :class:`Register`. The parameters (per servo ID, start address,
    length, then its items, little-endian, two's complement where signed) are packed by one
    ``struct`` format, each value's raw range checked against a precomputed bound first: what
    :meth:`Register.check_raw` and :meth:`Register.encode` do item by item (a value outside the
    bound goes to them, which raise OutOfRangeError).
    """

    names: tuple[tuple[int, RegLike], ...]
    regs: tuple[Register, ...]
    _pack: Callable[..., bytes]
    _args: tuple[int, ...]                   # the pack's arguments, 0 where a value goes
    _slots: tuple[int, ...]                  # where each value goes in them
    _bounds: tuple[tuple[int, int], ...]     # each value's raw range; (1, 0) to check by register

    @classmethod
    def build(cls, entries: Sequence[tuple[int, int, int, int]], names: tuple, regs: tuple[Register, ...]
              ) -> "BulkWritePlan":
        """The plan of ``entries`` (``(id, start, length, count)`` per servo) holding ``regs`` in
        turn, ``count`` of them per servo."""
        fmt, args, slots = ["<"], [], []
        own = iter(regs)
        for i, start, n, count in entries:
            fmt.append("BHH")
            args += [i, start, n]
            for _, r in zip(range(count), own):
                fmt.append(STRUCT_CODES[r.size, r.signed])
                slots.append(len(args))
                args.append(0)
        bounds = []
        for r in regs:
            lo, hi = r.raw_bounds()
            bits = 8 * r.size
            lo, hi = (max(lo, -(1 << (bits - 1))), min(hi, (1 << (bits - 1)) - 1)) if r.signed else \
                (max(lo, 0), min(hi, (1 << bits) - 1))
            bounds.append((1, 0) if r.allowed is not None else (lo, hi))
        return cls(names, regs, struct.Struct("".join(fmt)).pack, tuple(args), tuple(slots), tuple(bounds))

    def params(self, values: Sequence[int]) -> bytes:
        """The Bulk Write's parameters for raw ``values`` (one per register, in :attr:`names` order)."""
        if len(values) != len(self.regs):
            raise ValueError(f"bulk write plan takes {len(self.regs)} values, got {len(values)}")
        args = list(self._args)
        for at, v, (lo, hi), r in zip(self._slots, values, self._bounds, self.regs):
            v = int(v)
            if not lo <= v <= hi:
                r.encode(r.check_raw(v))
            args[at] = v
        return self._pack(*args)
