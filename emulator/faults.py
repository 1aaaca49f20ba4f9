"""Fault injection for the emulated bus: lost, corrupted and late replies, vanishing servos,
latched hardware errors.

Text form (``swerve emulate --faults``), comma-separated ``key=value``::

    drop=0.05,corrupt=0.01,delay=0.002,vanish=3+4,hwerror=5:overload+overheating,seed=7

``drop``/``corrupt`` are fractions (0..1) of status packets; ``delay`` is extra seconds before
every reply; ``vanish`` lists IDs that do not answer or execute anything; ``hwerror`` latches
Hardware Error Status bits on an ID (names: input_voltage, overheating, motor_encoder,
electrical_shock, overload, or an integer); ``seed`` makes drop/corrupt reproducible.
"""
from __future__ import annotations

import random
from typing import Callable

from swerve.core.options import parse_key_values
from swerve.driver.errors import ConfigError

from swerve.emulator.servo import hardware_error_bits

#: Keys of the ``--faults`` text form.
FAULT_KEYS = ("drop", "corrupt", "delay", "vanish", "hwerror", "seed")


class Faults:
    """Live fault settings of one emulator; safe to change while it runs.

    ``drop_rate``, ``corrupt_rate`` (fractions) and ``delay_s`` are plain attributes.
    """

    def __init__(self, drop_rate: float = 0.0, corrupt_rate: float = 0.0, delay_s: float = 0.0,
                 seed: int | None = None):
        self.drop_rate = float(drop_rate)
        self.corrupt_rate = float(corrupt_rate)
        self.delay_s = float(delay_s)
        self.vanished: set[int] = set()
        self.pending_hw_errors: dict[int, int] = {}
        self._rng = random.Random(seed)
        self._raise_hook: Callable[[int, int], None] | None = None
        self._check()

    def _check(self) -> None:
        for name, v in (("drop_rate", self.drop_rate), ("corrupt_rate", self.corrupt_rate)):
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"fault {name} = {v} must be within 0..1")
        if self.delay_s < 0:
            raise ConfigError(f"fault delay_s = {self.delay_s} must be >= 0")

    # --- servo faults -----------------------------------------------------------------------
    def vanish(self, id_: int) -> None:
        """Servo ``id_`` stops answering and executing (as if unplugged); memory is kept."""
        self.vanished.add(int(id_))

    def restore(self, id_: int) -> None:
        """Undo :meth:`vanish`."""
        self.vanished.discard(int(id_))

    def raise_hardware_error(self, id_: int, bits: int | str) -> None:
        """Latch hardware error ``bits`` (int or names) on servo ``id_`` until it is rebooted."""
        b = hardware_error_bits(bits)
        if self._raise_hook is None:
            self.pending_hw_errors[int(id_)] = self.pending_hw_errors.get(int(id_), 0) | b
        else:
            self._raise_hook(int(id_), b)

    def apply(self, what: str, *args) -> None:
        """The fault operation named ``what`` (``vanish``, ``restore``, ``raise_hardware_error``)
        with ``args``, as a control channel or a parent process asks for it by name."""
        operations = {"vanish": self.vanish, "restore": self.restore,
                      "raise_hardware_error": self.raise_hardware_error}
        if what not in operations:
            raise ConfigError(f"unknown fault {what!r} (one of {', '.join(operations)})")
        operations[what](*args)

    def attach(self, hook: Callable[[int, int], None]) -> None:
        """Connect to an emulator (called by :class:`emulator.server.Emulator`)."""
        self._raise_hook = hook
        pending, self.pending_hw_errors = self.pending_hw_errors, {}
        for id_, bits in pending.items():
            hook(id_, bits)

    # --- reply faults -------------------------------------------------------------------------
    def should_drop(self) -> bool:
        return self.drop_rate > 0 and self._draw() < self.drop_rate

    def maybe_corrupt(self, frame: bytes) -> tuple[bytes, bool]:
        """``(frame, corrupted?)``: flips one bit of a random byte with ``corrupt_rate``."""
        if self.corrupt_rate <= 0 or self._draw() >= self.corrupt_rate:
            return frame, False
        i = self._rng.randrange(len(frame))
        bit = 1 << self._rng.randrange(8)
        out = bytearray(frame)
        out[i] ^= bit
        return bytes(out), True

    def _draw(self) -> float:
        return self._rng.random()      # only the bus thread draws (no lock needed)

    @classmethod
    def parse(cls, text: str | None) -> "Faults":
        """Build from the ``--faults`` text form (module docstring); raises ConfigError."""
        faults = cls()
        if not text:
            return faults
        seed = None
        hw: list[tuple[int, str]] = []
        for key, value in parse_key_values(text, "--faults", FAULT_KEYS):
            try:
                if key == "drop":
                    faults.drop_rate = float(value)
                elif key == "corrupt":
                    faults.corrupt_rate = float(value)
                elif key == "delay":
                    faults.delay_s = float(value)
                elif key == "seed":
                    seed = int(value)
                elif key == "vanish":
                    for v in value.split("+"):
                        faults.vanish(int(v))
                else:
                    id_, _, bits = value.partition(":")
                    hw.append((int(id_), bits))
            except ValueError as exc:
                if isinstance(exc, ConfigError):
                    raise
                raise ConfigError(f"--faults item {key}={value!r}: {exc}") from None
        faults._rng = random.Random(seed)
        faults._check()
        for id_, bits in hw:
            try:
                faults.raise_hardware_error(id_, bits)
            except ValueError as exc:
                raise ConfigError(f"--faults hwerror={id_}:{bits}: {exc}") from None
        return faults
