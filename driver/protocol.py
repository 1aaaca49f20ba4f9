"""Dynamixel Protocol 2.0 constants: frame limits, instruction codes, error numbers.

Pure data, imported by both :mod:`swerve.driver.packets` (the codec) and
:mod:`swerve.driver.errors` (whose messages name instructions and error numbers).
Facts: ROBOTIS e-Manual, "Protocol 2.0" (https://emanual.robotis.com/docs/en/dxl/protocol2/),
summarised in ``docs/reference/protocol.md``.
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import IntEnum

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC

#: Largest whole packet (header through CRC) a Protocol 2.0 device is sent or answers with,
#: bytes: dynamixel-sdk ``protocol2_packet_handler.py`` ``TXPACKET_MAX_LEN = RXPACKET_MAX_LEN
#: = 1 * 1024``; ``rxPacket`` drops a header whose LENGTH exceeds it.
MAX_PACKET_BYTES = 1024
#: Bytes before the INST byte: header (4), ID, LEN_L, LEN_H.
PREFIX_BYTES = 7
#: Largest LENGTH field accepted: a longer one cannot belong to a packet a servo buffers,
#: so the parser rejects it from the header alone.
MAX_LENGTH = MAX_PACKET_BYTES - PREFIX_BYTES

ALERT_BIT = 0x80


class Instruction(IntEnum):
    """Instruction codes (the byte after LENGTH)."""

    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REG_WRITE = 0x04
    ACTION = 0x05
    FACTORY_RESET = 0x06
    REBOOT = 0x08
    CLEAR = 0x10
    CONTROL_TABLE_BACKUP = 0x20
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83
    FAST_SYNC_READ = 0x8A
    BULK_READ = 0x92
    BULK_WRITE = 0x93
    FAST_BULK_READ = 0x9A


def instruction_name(code: int | None) -> str:
    """Human name of an instruction code, e.g. ``"SYNC_READ (0x82)"``."""
    if code is None:
        return "?"
    try:
        return f"{Instruction(code).name} (0x{code:02X})"
    except ValueError:
        return f"unknown instruction 0x{code:02X}"


class ResetOption(IntEnum):
    """Factory Reset (0x06) parameter."""

    ALL = 0xFF
    EXCEPT_ID = 0x01
    EXCEPT_ID_BAUD = 0x02


#: Clear (0x10) parameters: option 0x01 (multi-turn position) and the fixed key ``44 58 4C 22``.
CLEAR_MULTI_TURN = b"\x01DXL\x22"
#: Control Table Backup (0x20) key after the store/restore byte.
BACKUP_KEY = b"CTRL"


class ErrorNumber(IntEnum):
    """Error number in bits 0–6 of a status packet's ERR byte."""

    NONE = 0x00
    RESULT_FAIL = 0x01
    INSTRUCTION = 0x02
    CRC = 0x03
    DATA_RANGE = 0x04
    DATA_LENGTH = 0x05
    DATA_LIMIT = 0x06
    ACCESS = 0x07

    @property
    def description(self) -> str:
        """One-line meaning, paraphrasing the e-Manual."""
        return _ERROR_TEXT.get(self, f"error {int(self)}")


_ERROR_TEXT = {
    ErrorNumber.NONE: "no error",
    ErrorNumber.RESULT_FAIL: "result fail (instruction could not be processed)",
    ErrorNumber.INSTRUCTION: "instruction error (undefined instruction, or Action without Reg Write)",
    ErrorNumber.CRC: "CRC error (the servo received a corrupted packet)",
    ErrorNumber.DATA_RANGE: "data range error (value outside the item's range)",
    ErrorNumber.DATA_LENGTH: "data length error (fewer bytes than the item's size)",
    ErrorNumber.DATA_LIMIT: "data limit error (value outside the configured limit)",
    ErrorNumber.ACCESS: "access error (read-only/undefined address, or EEPROM write with torque on)",
}


@dataclass(frozen=True)
class StatusError:
    """Decoded ERR byte: the error number and the hardware alert bit."""

    number: ErrorNumber
    alert: bool

    @classmethod
    def from_byte(cls, err: int) -> "StatusError":
        num = err & 0x7F
        try:
            number = ErrorNumber(num)
        except ValueError:  # undefined numbers count as a failure, never as success
            number = ErrorNumber.RESULT_FAIL if num else ErrorNumber.NONE
        return cls(number, bool(err & ALERT_BIT))

    def to_byte(self) -> int:
        return int(self.number) | (ALERT_BIT if self.alert else 0)

    @property
    def ok(self) -> bool:
        return self.number == ErrorNumber.NONE and not self.alert
