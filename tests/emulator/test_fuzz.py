"""Random and mutated byte streams never crash or hang the emulator; a ping works right after.

2000 streams from a seeded RNG (reproducible): pure garbage, valid frames with random
instructions and parameters (valid CRC, so they reach the servos), bit-flipped, truncated and
spliced frames, and header fragments that leave the parser mid-frame.
"""
from __future__ import annotations

import random
import time

import serial

from swerve.driver import packets as pk
from swerve.driver.control_table import Reg
from swerve.emulator.factory import build_emulator
from swerve.emulator.server import Emulator

STREAMS = 2000
SEED = 20261122
INSTRUCTIONS = [int(i) for i in pk.Instruction if i != pk.Instruction.STATUS] + [0x00, 0x30, 0x7F, 0xFF]


def _valid_frame(rng: random.Random) -> bytes:
    id_ = rng.choice([1, 2, 3, 5, 8, 0xFE, 0xFE, rng.randrange(0, 253)])
    inst = rng.choice(INSTRUCTIONS)
    if inst in (pk.Instruction.REBOOT, pk.Instruction.FACTORY_RESET) and rng.random() < 0.8:
        inst = pk.Instruction.PING
    kind = rng.random()
    if kind < 0.3:
        params = rng.randbytes(rng.randrange(0, 12))
    elif kind < 0.6:       # plausible address/length heads
        params = rng.randrange(0, 700).to_bytes(2, "little") + rng.randrange(0, 80).to_bytes(2, "little")
        params += rng.randbytes(rng.randrange(0, 10))
    else:
        params = rng.randbytes(rng.randrange(0, 60))
    return pk.InstructionPacket(id_, inst, params).encode()


def _stream(rng: random.Random) -> bytes:
    kind = rng.randrange(6)
    if kind == 0:
        return rng.randbytes(rng.randrange(1, 64))
    frame = bytearray(_valid_frame(rng))
    if kind == 1:
        return bytes(frame)
    if kind == 2:                                        # bit flips (mostly bad CRC)
        for _ in range(rng.randrange(1, 4)):
            frame[rng.randrange(len(frame))] ^= 1 << rng.randrange(8)
        return bytes(frame)
    if kind == 3:                                        # truncated: parser left mid-frame
        return bytes(frame[:rng.randrange(1, len(frame))])
    if kind == 4:                                        # garbage around a good frame
        return rng.randbytes(rng.randrange(0, 8)) + bytes(frame) + rng.randbytes(rng.randrange(0, 8))
    return pk.HEADER + rng.randbytes(rng.randrange(0, 6))  # header fragment, huge LENGTH etc.


def _wait_quiet(emu: Emulator, quiet_s: float = 0.3, limit_s: float = 30.0) -> None:
    deadline = time.monotonic() + limit_s
    last, since = None, time.monotonic()
    while time.monotonic() < deadline:
        now = (emu.stats.packets_received, emu.stats.dropped_bytes, emu.stats.replies_sent)
        if now != last:
            last, since = now, time.monotonic()
        elif time.monotonic() - since >= quiet_s:
            return
        time.sleep(0.05)
    raise AssertionError("emulator never went quiet")


def test_fuzzed_streams_never_crash_or_hang():
    rng = random.Random(SEED)
    with build_emulator(ids=range(1, 9), model="xh430-w210", baud=1_000_000) as emu:
        with serial.Serial(emu.port, 1_000_000, timeout=0) as port:
            t0 = time.monotonic()
            for n in range(STREAMS):
                port.write(_stream(rng))
                if n % 50 == 0:
                    port.reset_input_buffer()
                    time.sleep(0.002)                   # let idle gaps happen too
            _wait_quiet(emu)
            elapsed = time.monotonic() - t0
            assert emu.running                          # the bus thread survived
            assert emu.stats.dispatch_errors == 0
            assert emu.stats.bad_frames > 0 and emu.stats.packets_received > 0
            # the fuzz may have renumbered, re-bauded or silenced servos: restore, then ping
            with emu.lock:
                for k, s in enumerate(emu.servos, start=1):
                    s.memory.load_defaults()
                    s.memory.set(Reg.ID, k)
                    s.memory.set(Reg.BAUD_RATE, 3)
                    s.reboot()
                    s.apply_pending()
            port.reset_input_buffer()
            port.timeout = 1.0
            for k in range(1, 9):
                port.write(pk.ping(k).encode())
                reply = port.read(14)
                st = pk.StatusPacket.decode(reply)
                assert (st.id, st.error, st.params[:2]) == (k, 0, (1010).to_bytes(2, "little"))
    assert elapsed < 60.0
