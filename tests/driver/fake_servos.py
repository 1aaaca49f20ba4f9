"""A small scripted servo responder on a pty, built from ``driver.packets`` (test helper).

Not the project emulator: a flat memory per ID, no physics, no timing model. It answers
Ping, Read, Write, Reg Write, Action, Reboot, Factory Reset, Clear, Sync/Bulk Read and
Write and the Fast variants, and has knobs for the failure cases the bus must handle.
"""
from __future__ import annotations

import os
import pty
import select
import threading
import tty

from swerve.driver import packets as pk
from swerve.driver.control_table import table_for
from swerve.driver.packets import BROADCAST_ID, FastStatus, Instruction, StatusPacket
from swerve.driver.parser import PacketParser


class FakeServos:
    """Servos ``ids`` of ``model`` behind a pty; ``port`` is the path to open."""

    def __init__(self, ids=range(1, 9), model="xh430-w210"):
        self.table = table_for(model)
        self.mem = {}
        for i in ids:
            m = bytearray(self.table.size)
            for r in self.table:
                m[r.address:r.address + r.size] = r.encode(r.default)
            m[7] = i
            self.mem[i] = m
        self.silent: set[int] = set()      # IDs that do not answer
        self.wrong_id: dict[int, int] = {}  # answer for ID k as ID v
        self.error_byte: dict[int, int] = {}  # error byte to put in replies
        self.corrupt_next = 0               # flip a CRC bit in the next n replies
        self.garbage_before = b""           # bytes sent before each reply
        self.received: list = []
        self.staged: dict[int, tuple[int, bytes]] = {}
        self._master, slave = pty.openpty()
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(2)
        os.close(self._master)
        os.close(self._slave)

    # helpers
    def set(self, id_, name, raw):
        r = self.table[name]
        self.mem[id_][r.address:r.address + r.size] = r.encode(raw)

    def get(self, id_, name):
        r = self.table[name]
        return r.decode(bytes(self.mem[id_][r.address:r.address + r.size]))

    def _send(self, data: bytes):
        os.write(self._master, data)

    def _status(self, id_, params=b""):
        out = StatusPacket(self.wrong_id.get(id_, id_), self.error_byte.get(id_, 0), params).encode()
        if self.corrupt_next:
            self.corrupt_next -= 1
            out = out[:-1] + bytes((out[-1] ^ 0x01,))
        return self.garbage_before + out

    def _run(self):
        parser = PacketParser()
        while not self._stop.is_set():
            r, _, _ = select.select([self._master], [], [], 0.05)
            if not r:
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:
                return
            for p in parser.feed(data):
                if isinstance(p, pk.InstructionPacket):
                    self.received.append(p)
                    self._handle(p)

    def _alive(self, i):
        return i in self.mem and i not in self.silent

    def _handle(self, p):
        inst, params = p.instruction, p.params
        targets = [i for i in self.mem if p.id in (i, BROADCAST_ID) and self._alive(i)]
        reply = p.id != BROADCAST_ID
        if inst == Instruction.PING:
            for i in sorted(targets):
                self._send(self._status(i, self.mem[i][0:2] + self.mem[i][6:7]))
        elif inst == Instruction.READ:
            a, n = pk.parse_address_length(params)
            for i in targets:
                if reply:
                    self._send(self._status(i, bytes(self.mem[i][a:a + n])))
        elif inst in (Instruction.WRITE, Instruction.REG_WRITE):
            a, data = int.from_bytes(params[:2], "little"), params[2:]
            for i in targets:
                if inst == Instruction.WRITE:
                    self.mem[i][a:a + len(data)] = data
                else:
                    self.staged[i] = (a, data)
                if reply:
                    self._send(self._status(i))
        elif inst == Instruction.ACTION:
            for i in targets:
                if i in self.staged:
                    a, data = self.staged.pop(i)
                    self.mem[i][a:a + len(data)] = data
                if reply:
                    self._send(self._status(i))
        elif inst in (Instruction.REBOOT, Instruction.FACTORY_RESET, Instruction.CLEAR,
                      Instruction.CONTROL_TABLE_BACKUP):
            for i in targets:
                if reply:
                    self._send(self._status(i))
                if inst == Instruction.REBOOT:
                    self.mem[i][70] = 0
                    self.error_byte.pop(i, None)
        elif inst in (Instruction.SYNC_READ, Instruction.FAST_SYNC_READ):
            a, n, ids = pk.parse_sync_read(params)
            self._group_read(inst == Instruction.FAST_SYNC_READ, [(i, a, n) for i in ids])
        elif inst in (Instruction.BULK_READ, Instruction.FAST_BULK_READ):
            self._group_read(inst == Instruction.FAST_BULK_READ, pk.parse_bulk_read(params))
        elif inst == Instruction.SYNC_WRITE:
            a, n, data = pk.parse_sync_write(params)
            for i, d in data.items():
                if self._alive(i):
                    self.mem[i][a:a + n] = d
        elif inst == Instruction.BULK_WRITE:
            for i, a, d in pk.parse_bulk_write(params):
                if self._alive(i):
                    self.mem[i][a:a + len(d)] = d

    def _group_read(self, fast, items):
        entries = []
        for i, a, n in items:
            if not self._alive(i):
                break  # servos after a silent one stay silent too
            entries.append(StatusPacket(i, self.error_byte.get(i, 0), bytes(self.mem[i][a:a + n])))
        if fast:
            if entries:
                self._send(FastStatus(tuple(entries)).encode())
        else:
            for e in entries:
                self._send(self._status(e.id, e.params))
