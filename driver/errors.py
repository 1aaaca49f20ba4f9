"""One exception hierarchy for the whole project.

Every error a user can cause (bad bytes, a missing servo, a malformed file) is a
:class:`SwerveError`; the ``swerve`` command prints its message and exits non-zero
instead of showing a traceback. Errors carry their facts as fields::

    SwerveError
    ├── ConfigError (ValueError)
    └── DxlError
        ├── TransportError (IOError)
        │   └── PortInUseError                   port
        ├── DxlTimeoutError (TimeoutError)      ids, first_missing, instruction, timeout_s
        ├── CorruptPacketError (ValueError)
        │   └── ChecksumError                    expected, actual, frame
        ├── ServoError                           id, error_number, alert, hardware_error
        ├── RegisterError (KeyError)
        └── OutOfRangeError (ValueError)         register, value, low, high
"""
from __future__ import annotations

from swerve.core.errors import ConfigError, SwerveError
from swerve.driver.protocol import ErrorNumber, StatusError, instruction_name

__all__ = ["SwerveError", "ConfigError", "DxlError", "TransportError", "PortInUseError",
           "DxlTimeoutError",
           "CorruptPacketError", "ChecksumError", "ServoError", "RegisterError", "OutOfRangeError"]


class DxlError(SwerveError):
    """Base of Dynamixel communication and servo errors."""


class TransportError(DxlError, IOError):
    """The serial port could not be opened, written or read."""


class PortInUseError(TransportError):
    """Another program holds the serial port's lock; ``port`` names it."""

    def __init__(self, message: str, *, port: str):
        super().__init__(message)
        self.port = port


class DxlTimeoutError(DxlError, TimeoutError):
    """No (complete) reply arrived before the deadline.

    Attributes: ``ids`` every servo ID that did not answer, in request order;
    ``first_missing`` the first of them; ``cut_off`` True when the others are the servos
    queued behind it in a Sync/Bulk Read reply chain (each waits for the reply before its
    own, so one silent servo silences all later ones); ``instruction`` the instruction
    code sent; ``timeout_s`` the deadline used.
    """

    def __init__(self, ids, instruction: int, timeout_s: float, detail: str = "", *,
                 cut_off: bool = False):
        self.ids = tuple(ids)
        self.first_missing = self.ids[0] if self.ids else None
        self.cut_off = bool(cut_off) and len(self.ids) > 1
        self.instruction = int(instruction)
        self.timeout_s = float(timeout_s)
        what = f"{instruction_name(self.instruction)} within {self.timeout_s * 1e3:.1f} ms"
        if self.cut_off:
            rest = self.ids[1:]
            who = (f"ID {rest[0]} queued behind it in the reply chain was" if len(rest) == 1 else
                   f"IDs {', '.join(map(str, rest))} queued behind it in the reply chain were")
            msg = f"servo ID {self.first_missing} stopped answering ({what}); {who} cut off"
        else:
            msg = f"no reply from servo ID {', '.join(map(str, self.ids)) or '-'} to {what}"
        super().__init__(msg + (f" ({detail})" if detail else ""))


class CorruptPacketError(DxlError, ValueError):
    """Bytes that should have been a packet were not one (bad header, length, ID...)."""


class ChecksumError(CorruptPacketError):
    """A frame's CRC-16 did not match: ``expected`` (computed) vs ``actual`` (received)."""

    def __init__(self, expected: int, actual: int, frame: bytes = b""):
        self.expected = expected
        self.actual = actual
        self.frame = bytes(frame)
        super().__init__(f"CRC mismatch: computed 0x{expected:04X}, received 0x{actual:04X}"
                         + (f" in frame {self.frame.hex(' ')}" if frame else ""))


class ServoError(DxlError):
    """A servo answered with a non-zero error byte.

    Attributes: ``id``; ``error_number`` (:class:`driver.protocol.ErrorNumber`, 0 if only the
    alert bit is set); ``alert`` (a hardware fault is latched); ``hardware_error`` (the
    decoded Hardware Error Status bits, when they were read, else ``None``).
    """

    def __init__(self, id: int, error_byte: int, instruction: int | None = None,
                 hardware_error=None, context: str = ""):
        st = StatusError.from_byte(error_byte)
        self.id = int(id)
        self.error_byte = int(error_byte)
        self.error_number = st.number
        self.alert = st.alert
        self.instruction = instruction
        self.hardware_error = hardware_error
        parts = []
        if st.number != ErrorNumber.NONE:
            parts.append(st.number.description)
        if st.alert:
            hw = f": {hardware_error}" if hardware_error is not None else ""
            parts.append(f"hardware alert{hw} (reboot the servo to clear it)")
        what = f" to {instruction_name(instruction)}" if instruction is not None else ""
        super().__init__(f"servo ID {self.id} answered{what} with error: {'; '.join(parts)}"
                         + (f" [{context}]" if context else ""))


class RegisterError(DxlError, KeyError):
    """An unknown register name or address for this model."""

    def __str__(self) -> str:  # KeyError quotes its message otherwise
        return str(self.args[0]) if self.args else "unknown register"


class OutOfRangeError(DxlError, ValueError):
    """A value (SI or raw) does not fit the register's range; nothing is clamped."""

    def __init__(self, register: str, value, low, high, unit: str = ""):
        self.register = register
        self.value = value
        self.low = low
        self.high = high
        u = f" {unit}" if unit else ""
        super().__init__(f"{register} = {value}{u} is outside [{low}, {high}]{u}")
