"""The firmware's protection from the physics: Hardware Error Status (70) bits a servo raises itself.

e-Manual, Hardware Error Status: bit 0 Input Voltage ("applied voltage is out of the range of
operating voltage set in the Control Table", i.e. Min/Max Voltage Limit 34/32), bit 2 Overheating
("internal temperature is out of the range of operating temperature set in the Control Table",
Temperature Limit 31), bit 5 Overload ("persistent load that exceeds maximum output"). The
servo then latches the bit, sets the Alert bit (0x80) in every status, and drops torque for
bits set in Shutdown (63); only Reboot clears it (``emulator.servo.VirtualServo``).

How long a load must persist is not published. **Assumed:** a leaky timer that counts up while
``|i| > overload_current_a`` and down otherwise, tripping at ``overload_time_s``.
"""
from __future__ import annotations

from typing import Mapping

from swerve.driver.control_table import HardwareError

from .jit import jitable
from .params import ProtectionParams

OVERLOAD, OVERHEATING, INPUT_VOLTAGE = HardwareError.OVERLOAD, HardwareError.OVERHEATING, HardwareError.INPUT_VOLTAGE

#: Control-table defaults of the X series (docs/reference/protocol.md §3), raw units.
DEFAULT_LIMITS = {"temperature_limit": 80, "max_voltage_limit": 160, "min_voltage_limit": 95}


class Protection:
    """Fault detector of one servo; :meth:`update` returns bits detected for the first time.

    Parameters
    ----------
    params : ProtectionParams
        Overload threshold and time.
    """

    def __init__(self, params: ProtectionParams):
        self.params = params
        self.overload_timer_s = 0.0
        self.raised = 0                 # bits reported since the last reboot

    def reset(self) -> None:
        """Reboot: timers and reported bits cleared."""
        self.overload_timer_s = 0.0
        self.raised = 0

    def update(self, dt_s: float, current_a: float, temperature_c: float, voltage_v: float,
               table: Mapping[str, int]) -> int:
        """Advance the timers by ``dt_s``; return newly detected Hardware Error Status bits (0: none).

        ``table`` may hold the raw limit items (Temperature Limit in °C, voltage limits in 0.1 V);
        missing items take the e-Manual defaults.
        """
        p = self.params
        new, self.overload_timer_s, self.raised = protection_step(
            dt_s, current_a, temperature_c, voltage_v, self.overload_timer_s, self.raised, p.overload_current_a,
            p.overload_time_s, *limits(table))
        return new


def limits(table: Mapping[str, int]) -> tuple[float, float, float]:
    """``(temperature limit °C, min, max voltage limit in 0.1 V)`` from the raw items ``table``,
    the e-Manual defaults where an item is missing, as floats (exact: small integers)."""
    return (float(table.get("temperature_limit", DEFAULT_LIMITS["temperature_limit"])),
            float(table.get("min_voltage_limit", DEFAULT_LIMITS["min_voltage_limit"])),
            float(table.get("max_voltage_limit", DEFAULT_LIMITS["max_voltage_limit"])))


@jitable
def protection_step(dt_s, current_a, temperature_c, voltage_v, timer_s, raised, overload_current_a,
                    overload_time_s, temperature_limit, min_voltage, max_voltage):
    """:meth:`Protection.update` on plain numbers: returns ``(new bits, timer_s, raised)``."""
    bits = 0
    if abs(current_a) > overload_current_a:
        timer_s += dt_s
        if timer_s >= overload_time_s:
            bits |= OVERLOAD
    else:
        timer_s = max(0.0, timer_s - dt_s)
    if temperature_c > temperature_limit:
        bits |= OVERHEATING
    volts_raw = voltage_v * 10.0
    if not (min_voltage <= volts_raw <= max_voltage):
        bits |= INPUT_VOLTAGE
    return bits & ~raised, timer_s, raised | bits
