"""One virtual X-series servo: its memory, identity, timers, Bus Watchdog and hardware-error latch.

:class:`VirtualServo` holds the state the instructions act on and offers the changes they make
(:meth:`~VirtualServo.bus_write`, :meth:`~VirtualServo.read_status`, :meth:`~VirtualServo.reboot`,
...); what each instruction does with them, who is addressed and who answers is
:mod:`swerve.emulator.instructions`. It does no I/O and no timing. Physics plugs in through
:meth:`VirtualServo.advance` and the ``dynamics`` object (see :class:`Dynamics`).
Item units and ranges come from the model's control table (``configs/models/*.yaml``).
"""
from __future__ import annotations

import logging
import operator
import struct
from typing import Callable, Iterable, Mapping, Protocol

from swerve.driver.control_table import BAUD_RATES_BPS as BAUD_RATES
from swerve.driver.control_table import ControlTable, HardwareError, OperatingMode, Reg, baud_index, table_for
from swerve.driver.errors import ConfigError
from swerve.driver.packets import ALERT_BIT, MAX_ID, ErrorNumber, StatusPacket, status_frame
from swerve.emulator.memory import ServoMemory, WriteRejected

log = logging.getLogger(__name__)

#: Items the physics model returns (written into memory when the bus next reads).
DYNAMICS_OUTPUTS = ("present_pwm", "present_current", "present_velocity", "present_position",
                    "velocity_trajectory", "position_trajectory", "present_input_voltage",
                    "present_temperature", "moving", "moving_status")
_OUTPUT_COUNT = len(DYNAMICS_OUTPUTS)
#: The outputs a reading may publish alone when a read asks for nothing else (they lie back to
#: back on the X series: the Sync Read of a control cycle).
MOTION_OUTPUTS = ("present_current", "present_velocity", "present_position")
#: Items the Control Table Backup instruction stores besides the EEPROM area (e-Manual).
BACKUP_RAM_ITEMS = ("velocity_i_gain", "velocity_p_gain", "position_d_gain", "position_i_gain",
                    "position_p_gain", "feedforward_2nd_gain", "feedforward_1st_gain",
                    "profile_acceleration", "profile_velocity")

#: Items whose bus write has consequences beyond their bytes (:meth:`VirtualServo._after_write`).
_FOLLOWED_UP = frozenset((Reg.OPERATING_MODE, Reg.BUS_WATCHDOG))


class Dynamics(Protocol):
    """What the physics model must provide (e.g. :class:`swerve.emulator.physics.servo_adapter.ServoDynamics`).

    The servo calls :meth:`advance_many` every run of ticks and :meth:`outputs` only when
    someone reads a present item, so physics ticks cost no table writes. A model that steps one
    tick at a time subclasses :class:`StepDynamics` for the other members.
    """

    #: True if the servos' steps may run several at a time, servo after servo (the model draws
    #: nothing from a generator the servos share).
    batchable: bool

    def advance(self, dt_s: float, table: Mapping[str, int]) -> None:
        """Advance ``dt_s`` s given raw items by name."""

    def advance_many(self, dt_s: float, n: int, table: Mapping[str, int], traces=None) -> int:
        """Up to ``n`` (>= 1) steps of ``dt_s`` s under the raw items ``table``, stopping after a
        step that raised a Hardware Error (:meth:`take_hardware_error`); ``traces``: the
        per-step lists a batched run records for the body (see
        :meth:`swerve.emulator.stepping.World.traces`). Returns the steps run."""

    def take_hardware_error(self) -> int:
        """Hardware Error bits the physics raised since the last call (then cleared)."""

    def reading(self) -> object | None:
        """Draw whatever a new reading of the present items draws (sensor noise), for
        :meth:`motion` and :meth:`outputs`; ``None`` if the model reads only through
        :meth:`outputs` (nothing drawn then)."""

    def motion(self, reading: object) -> tuple[int, int, int]:
        """Raw :data:`MOTION_OUTPUTS` of ``reading`` (from :meth:`reading`): what :meth:`outputs`
        gives for it."""

    def outputs(self, reading: object | None = None) -> Mapping[str, int]:
        """Raw :data:`DYNAMICS_OUTPUTS` (any subset) as of the last :meth:`advance`, of
        ``reading`` (a new one if ``None``)."""

    def reboot(self) -> None:
        """The servo rebooted (RAM items back to their defaults)."""

    def clear_multi_turn(self) -> None:
        """The Clear instruction reset the multi-turn position to one turn."""


class StepDynamics:
    """The :class:`Dynamics` members of a model that steps one :meth:`advance` at a time, raises
    no Hardware Error and keeps no state a reboot or Clear would reset; a subclass defines
    ``advance`` and ``outputs``."""

    batchable = False

    def advance_many(self, dt_s: float, n: int, table: Mapping[str, int], traces=None) -> int:
        """One :meth:`advance` (the servo asks again for the rest)."""
        self.advance(dt_s, table)
        return 1

    def take_hardware_error(self) -> int:
        return 0

    def reading(self) -> None:
        """No reading in parts: :meth:`outputs` draws its own."""
        return None

    def reboot(self) -> None:
        pass

    def clear_multi_turn(self) -> None:
        pass


class VirtualServo:
    """A servo on the emulated bus.

    Parameters
    ----------
    table : ControlTable
        Model control table (from :func:`driver.control_table.table_for`).
    id_ : int
        Initial ID (written to the ID item as if configured earlier).
    baud_bps : int
        Initial line speed (written to the Baud Rate item).
    dynamics : Dynamics, optional
        Physics model; ``None`` keeps Present* items static.
    limit_error : ErrorNumber
        Error returned for a value beyond a limit item (UNCONFIRMED; default Data Limit Error).
    """

    def __init__(self, table: ControlTable, id_: int, baud_bps: int = 1_000_000, *,
                 dynamics: Dynamics | None = None, limit_error: ErrorNumber = ErrorNumber.DATA_LIMIT):
        self.table = table
        self.memory = ServoMemory(table, limit_error=limit_error)
        self.memory.publisher = self._publish
        self.memory.published = frozenset((Reg.REALTIME_TICK, *DYNAMICS_OUTPUTS))
        # all published items in one write when the table holds them back to back (the outputs
        # in address order, so the packer needs no reordering)
        self._pack_published = None
        if all(n in table for n in DYNAMICS_OUTPUTS):
            in_order = sorted(DYNAMICS_OUTPUTS, key=lambda n: table[n].address)
            self._output_values = operator.itemgetter(*in_order)      # one tuple from the dict
            self._pack_published = self.memory.packer((Reg.REALTIME_TICK, *in_order))
            # a read of the motion items alone writes only them (when they lie back to back)
            self._pack_motion = self.memory.packer(MOTION_OUTPUTS)
            if self._pack_motion is not None:
                regs = [table[n] for n in MOTION_OUTPUTS]
                self.memory.publish_in_parts(min(r.address for r in regs), max(r.address + r.size for r in regs),
                                             self._publish_motion)
        self._view = self.memory.view()
        self._identity_end = max(table[n].address + table[n].size for n in (Reg.ID, Reg.SECONDARY_ID, Reg.BAUD_RATE))
        self._identity_raw = b""
        self._torque_address = table[Reg.TORQUE_ENABLE].address
        self._return_delay_address = _byte_item(table, Reg.RETURN_DELAY_TIME)
        self._return_delay_unit_s = table[Reg.RETURN_DELAY_TIME].scale
        self._watchdog_unit_s = table[Reg.BUS_WATCHDOG].scale
        self._tick_wrap_ms = table[Reg.REALTIME_TICK].max + 1     # Realtime Tick counts ms and wraps
        self._hardware_error_address = _byte_item(table, Reg.HARDWARE_ERROR_STATUS)
        self.memory.set(Reg.ID, id_)
        self.memory.set(Reg.BAUD_RATE, baud_index(baud_bps))
        self.dynamics = dynamics
        self._registered: tuple[int, bytes] | None = None
        self._backup: tuple[bytes, dict[str, int]] | None = None
        self._tick_ms = 0.0
        self._since_traffic_s = 0.0
        self._latched = False            # a Shutdown fault happened: torque stays off until reboot
        self.apply_pending()

    # --- identity used by the bus (changes take effect after the status reply) -------------------
    def apply_pending(self) -> None:
        """Make ID, Secondary ID and Baud Rate changes effective (after the reply went out)."""
        raw = self.memory.stored_bytes(self._identity_end)
        if raw == self._identity_raw:
            return                      # none of the three items changed since the last call
        self._identity_raw = raw
        self.id = self.memory.get(Reg.ID)
        self.secondary_id = self.memory.get(Reg.SECONDARY_ID)
        self.baud_bps = BAUD_RATES[self.memory.get(Reg.BAUD_RATE)]

    @property
    def model_number(self) -> int:
        return self.memory.get(Reg.MODEL_NUMBER)

    @property
    def return_delay_s(self) -> float:
        """Return Delay Time (9) in seconds (its unit from the model table, 2 us on the X series)."""
        return self.memory.byte(self._return_delay_address) * self._return_delay_unit_s

    @property
    def firmware_version(self) -> int:
        return self.memory.get(Reg.FIRMWARE_VERSION)

    @property
    def status_return_level(self) -> int:
        return self.memory.get(Reg.STATUS_RETURN_LEVEL)

    # --- test access (bypass the bus rules) ---------------------------------------------------
    def read(self, name: str) -> int:
        """Raw value of item ``name``, as the memory holds it."""
        return self.memory.get(name)

    def write(self, name: str, raw: int) -> None:
        """Store raw ``raw`` in item ``name`` without the bus rules (for tests and physics)."""
        self.memory.set(name, raw)
        self.apply_pending()

    # --- status helpers -----------------------------------------------------------------------
    def _error_byte(self, number: ErrorNumber = ErrorNumber.NONE) -> int:
        alert = ALERT_BIT if self.memory.byte(self._hardware_error_address) else 0
        return int(number) | alert

    def status(self, number: ErrorNumber = ErrorNumber.NONE, params: bytes = b"",
               reply_id: int | None = None) -> StatusPacket:
        """A status packet from this servo, with the Alert bit while a hardware error is latched."""
        return StatusPacket(self.id if reply_id is None else reply_id, self._error_byte(number), params)

    def _read(self, address: int, length: int) -> tuple[int, bytes]:
        """``(error byte, data)`` of the status a Read of ``length`` bytes at ``address`` produces."""
        m = self.memory
        try:
            data = m.read(address, length)
        except WriteRejected as exc:
            log.debug("ID %d read rejected: %s", self.id, exc)
            return self._error_byte(exc.number), b""
        return ALERT_BIT if m.byte(self._hardware_error_address) else 0, data     # _error_byte(), inline

    def read_status(self, address: int, length: int) -> StatusPacket:
        """The status a Read (or one Sync/Bulk Read entry) produces."""
        return StatusPacket(self.id, *self._read(address, length))

    def read_frame(self, address: int, length: int) -> bytes:
        """:meth:`read_status` as the frame on the wire, without building the packet (a Sync or
        Bulk Read entry; the ID is this servo's, 0..252 by the ID item's range)."""
        return status_frame(self.id, *self._read(address, length))

    def plain_read_reply(self, address: int, end: int) -> tuple[bytes, float]:
        """A Sync/Bulk Read entry of the bytes ``address .. end-1``, a range the memory's
        :meth:`~swerve.emulator.memory.ServoMemory.plain_range` accepted, in one call:
        :meth:`note_traffic`, then ``(read_frame(address, end - address), return_delay_s)``
        (the frame as on the wire, the Return Delay Time in s)."""
        self._since_traffic_s = 0.0
        m = self.memory
        data = m.read_plain(address, end)
        frame = status_frame(self.id, ALERT_BIT if m.byte(self._hardware_error_address) else 0, data)
        return frame, m.byte(self._return_delay_address) * self._return_delay_unit_s

    def bus_write(self, address: int, data: bytes) -> ErrorNumber:
        """A Write (or Sync/Bulk Write entry) with every rule; returns the error number."""
        torque = self._torque_address
        if address <= torque < address + len(data) and self._latched and data[torque - address] == 1:
            return ErrorNumber.RESULT_FAIL   # torque cannot come back before a reboot (UNCONFIRMED no.)
        try:
            changed = self.memory.write(address, data)
        except WriteRejected as exc:
            log.debug("ID %d write rejected: %s", self.id, exc)
            return exc.number
        if not _FOLLOWED_UP.isdisjoint(changed):
            self._after_write(changed)
        return ErrorNumber.NONE

    def _after_write(self, changed: list[str]) -> None:
        m = self.memory
        if Reg.OPERATING_MODE in changed:   # mode change resets profile and goal limits (e-Manual)
            m.set(Reg.PROFILE_VELOCITY, 0)
            m.set(Reg.PROFILE_ACCELERATION, 0)
            m.set(Reg.GOAL_PWM, m.get(Reg.PWM_LIMIT))
            if Reg.GOAL_CURRENT in self.table:     # models without a current sensor lack both
                m.set(Reg.GOAL_CURRENT, m.get(Reg.CURRENT_LIMIT))
        if Reg.BUS_WATCHDOG in changed:
            m.watchdog_tripped = False
            self._since_traffic_s = 0.0

    # --- state changes the instructions make (:mod:`swerve.emulator.instructions`) ----------------
    def register_write(self, address: int, data: bytes) -> ErrorNumber:
        """Reg Write: check ``data`` at ``address`` against the current memory now (so the host
        learns of a bad value at once) and hold it for :meth:`action`; the error number."""
        try:
            self.memory.copy().write(address, data)
        except WriteRejected as exc:
            return exc.number
        self._registered = (address, bytes(data))
        self.memory.set(Reg.REGISTERED_INSTRUCTION, 1)
        return ErrorNumber.NONE

    def action(self) -> ErrorNumber:
        """Action: write what :meth:`register_write` holds; Instruction Error if nothing is held."""
        if self._registered is None:
            return ErrorNumber.INSTRUCTION
        address, data = self._registered
        self._registered = None
        self.memory.set(Reg.REGISTERED_INSTRUCTION, 0)
        err = self.bus_write(address, data)
        if err:
            log.debug("ID %d: registered write failed at Action: %s", self.id, err.name)
        return ErrorNumber.NONE

    def factory_reset(self, option: int) -> None:
        """Factory Reset with ``option`` (``RESET_ALL`` / ``RESET_EXCEPT_ID`` / ``RESET_EXCEPT_ID_BAUD``), then a reboot."""
        self.memory.factory_reset(option)
        self.reboot(keep_ram=False)

    def clear_multi_turn(self) -> ErrorNumber:
        """Clear: Present Position back into one turn (Result Fail while moving); the error number."""
        if self.memory.get(Reg.MOVING):
            return ErrorNumber.RESULT_FAIL
        self.memory.set(Reg.PRESENT_POSITION, self.memory.get(Reg.PRESENT_POSITION) % self.table.pulses_per_rev)
        if self.dynamics is not None:
            self.dynamics.clear_multi_turn()
        return ErrorNumber.NONE

    @property
    def torque_enabled(self) -> bool:
        return bool(self.memory.get(Reg.TORQUE_ENABLE))

    @property
    def has_backup(self) -> bool:
        """True once :meth:`store_backup` ran (the backup outlives reboots)."""
        return self._backup is not None

    def store_backup(self) -> None:
        """Control Table Backup (store): the EEPROM area and :data:`BACKUP_RAM_ITEMS`."""
        self._backup = (self.memory.eeprom_bytes(),
                        {n: self.memory.get(n) for n in BACKUP_RAM_ITEMS if n in self.table})
        if Reg.BACKUP_READY in self.table:
            self.memory.set(Reg.BACKUP_READY, 1)

    def restore_backup(self) -> None:
        """Control Table Backup (restore): the stored EEPROM area back, then a reboot."""
        self.memory.restore_eeprom(self._backup[0])
        self.reboot()

    # --- lifecycle ------------------------------------------------------------------------------
    def reboot(self, keep_ram: bool = False) -> None:
        """What a Reboot does: RAM to defaults (torque off, errors cleared), EEPROM kept."""
        if not keep_ram:
            self.memory.reset_ram()
        self._registered = None
        self._latched = False
        self._since_traffic_s = 0.0
        if self._backup is not None and Reg.BACKUP_READY in self.table:
            self.memory.set(Reg.BACKUP_READY, 1)
        startup = self.memory.get(Reg.STARTUP_CONFIGURATION) if Reg.STARTUP_CONFIGURATION in self.table else 0
        if startup & 0x02 and self._backup is not None:
            for name, value in self._backup[1].items():
                self.memory.set(name, value)
        if startup & 0x01:
            self.memory.set(Reg.TORQUE_ENABLE, 1)
        if self.dynamics is not None:
            self.dynamics.reboot()
        self.memory.stale = True         # present items from the physics again, not the defaults

    def raise_hardware_error(self, bits: int) -> None:
        """Latch Hardware Error Status ``bits``; bits also set in Shutdown (63) drop torque."""
        m = self.memory
        m.publish()
        m.set(Reg.HARDWARE_ERROR_STATUS, m.get(Reg.HARDWARE_ERROR_STATUS) | (bits & 0xFF))
        if bits & m.get(Reg.SHUTDOWN):
            self._latched = True
            m.set(Reg.TORQUE_ENABLE, 0)
            m.set(Reg.PRESENT_PWM, 0)

    def note_traffic(self) -> None:
        """An instruction for this servo arrived: restart the Bus Watchdog timer."""
        self._since_traffic_s = 0.0

    def advance(self, dt_s: float) -> None:
        """Advance simulated time by ``dt_s`` s: Realtime Tick, Bus Watchdog, then ``dynamics``.

        Present items are written only when read next (:meth:`ServoMemory.publish`).
        """
        self.advance_many(dt_s, 1)

    def advance_many(self, dt_s: float, n: int, traces=None) -> None:
        """``n`` steps of :meth:`advance` with the same result, several at a time where nothing
        can change the input items in between: :meth:`Dynamics.advance_many` runs the steps up
        to the next Bus Watchdog trip or physics-raised Hardware Error in one call (``traces``:
        passed through, see :meth:`~swerve.emulator.physics.servo_adapter.ServoDynamics.advance_many`);
        a :class:`StepDynamics` runs one at a time.
        """
        m = self.memory
        dyn = self.dynamics
        done = 0
        while done < n:
            self._advance_timers(dt_s)                  # the first step of this run, as one tick
            if dyn is None:
                m.stale = True
                done += 1
                continue
            ran = dyn.advance_many(dt_s, 1 + self._quiet_steps(dt_s, n - done - 1) if n - done > 1 else 1,
                                   self._view, traces)
            self._advance_quiet_timers(dt_s, ran - 1)
            if done + ran > 1:                          # an earlier step of this call left the items stale
                m.stale = True
            done += ran
            bits = dyn.take_hardware_error()
            if bits:                                    # the physics tripped a protection: latch it
                self.raise_hardware_error(bits)
            m.stale = True

    def begin_steps(self, dt_s: float, most: int) -> int:
        """The first of up to ``most`` steps whose physics runs elsewhere (coupled with the other
        servos: :meth:`~swerve.emulator.physics.robot_world.RobotWorld.run_coupled`): this step's
        timers (the Bus Watchdog may trip), then how many steps, this one included, pass
        before the watchdog may trip. Finish with :meth:`end_steps`."""
        self._advance_timers(dt_s)
        return 1 + self._quiet_steps(dt_s, most - 1) if most > 1 else 1

    def end_steps(self, dt_s: float, ran: int, bits: int) -> None:
        """After ``ran`` steps begun by :meth:`begin_steps` (as :meth:`advance_many`): the timers
        of the steps after the first, then latch the Hardware Error ``bits`` the physics raised."""
        self._advance_quiet_timers(dt_s, ran - 1)
        if ran > 1:                     # an earlier step left the items stale
            self.memory.stale = True
        if bits:
            self.raise_hardware_error(bits)
        self.memory.stale = True

    def _advance_quiet_timers(self, dt_s: float, steps: int) -> None:
        """The timers of ``steps`` steps known not to trip the watchdog (:meth:`_quiet_steps`)."""
        if steps > 0:
            self._tick_ms, self._since_traffic_s = quiet_timers(self._tick_ms, self._since_traffic_s, dt_s, steps,
                                                                float(self._tick_wrap_ms))

    def _advance_timers(self, dt_s: float) -> None:
        """Realtime Tick and the Bus Watchdog for one step (the watchdog may trip)."""
        self._tick_ms = (self._tick_ms + dt_s * 1e3) % self._tick_wrap_ms
        self._since_traffic_s += dt_s
        if self._since_traffic_s > self._watchdog_unit_s and not self.memory.watchdog_tripped:
            self._check_watchdog()      # the shortest watchdog time is one unit: cheap gate first

    def _quiet_steps(self, dt_s: float, most: int) -> int:
        """How many of the next ``most`` steps pass without the Bus Watchdog tripping."""
        m = self.memory
        if most <= 0 or m.watchdog_tripped:
            return max(most, 0)
        since = self._since_traffic_s
        if since + (most + 1) * dt_s < self._watchdog_unit_s * (1.0 - 1e-9):
            return most                 # within the shortest watchdog time (1 unit), whatever the item says
        wd = m.get(Reg.BUS_WATCHDOG)
        if wd <= 0 or not m.get(Reg.TORQUE_ENABLE):
            return most
        limit = wd * self._watchdog_unit_s
        if since + (most + 1) * dt_s < limit * (1.0 - 1e-9):
            return most                 # far from the limit (the margin covers the sums' round-off)
        for k in range(most):           # the same float sums as the steps will make
            since += dt_s
            if since > self._watchdog_unit_s and since > limit:
                return k
        return most

    def _check_watchdog(self) -> None:
        m = self.memory
        wd = m.get(Reg.BUS_WATCHDOG)
        if wd > 0 and m.get(Reg.TORQUE_ENABLE) and self._since_traffic_s > wd * self._watchdog_unit_s:
            m.watchdog_tripped = True
            m.set(Reg.BUS_WATCHDOG, -1)
            m.set(Reg.GOAL_VELOCITY, 0)          # stop; physics also sees bus_watchdog == -1
            m.set(Reg.GOAL_PWM, 0)
            if m.get(Reg.OPERATING_MODE) in (OperatingMode.POSITION, OperatingMode.EXTENDED_POSITION,
                                             OperatingMode.CURRENT_BASED_POSITION):
                m.set(Reg.GOAL_POSITION, m.get(Reg.PRESENT_POSITION))

    def _publish_motion(self) -> object | None:
        """Write a new reading's :data:`MOTION_OUTPUTS` only and return the reading (the memory's
        part publisher, :meth:`ServoMemory.publish_in_parts`); ``None`` after writing every item
        (a model without readings in parts, or a value that does not fit)."""
        dyn = self.dynamics
        reading = dyn.reading() if dyn is not None else None
        if reading is None:
            self._publish(None)
            return None
        try:
            self._pack_motion(dyn.motion(reading))
        except struct.error:
            self._publish(reading)      # item by item: the same values, or the same error
            return None
        return reading

    def _publish(self, reading: object | None = None) -> None:
        """Write Realtime Tick and the dynamics' present items of ``reading`` (a new one if
        ``None``; the memory's ``publisher``)."""
        m = self.memory
        dyn = self.dynamics
        outputs = {} if dyn is None else dyn.outputs() if reading is None else dyn.outputs(reading)
        if self._pack_published is not None and len(outputs) == _OUTPUT_COUNT:
            try:                        # a value that is not an int raises struct.error
                self._pack_published([int(self._tick_ms), *self._output_values(outputs)])
                return
            except (KeyError, struct.error):
                pass                    # item by item below: the same values, or the same error
        m.set(Reg.REALTIME_TICK, int(self._tick_ms))
        if self.dynamics is not None:
            for name in DYNAMICS_OUTPUTS:
                if name in outputs:
                    m.set(name, int(outputs[name]))


#: The last :func:`quiet_timers` call, ``(arguments, result)`` (one tuple: set atomically).
_last_quiet_timers: list[tuple] = [((), ())]


def quiet_timers(tick_ms: float, since_s: float, dt_s: float, steps: int, wrap_ms: float) -> tuple[float, float]:
    """Realtime Tick (ms, wrapping at ``wrap_ms``) and the time since the last instruction (s)
    after ``steps`` steps of ``dt_s`` s, with the float sums the steps make one by one.

    The servos of a bus usually share both timers (they hear the same instructions), so the
    last call's result is kept and returned for the same arguments (the same floats give the
    same sums)."""
    args = (tick_ms, since_s, dt_s, steps, wrap_ms)
    last, result = _last_quiet_timers[0]
    if args == last:
        return result
    d_ms = dt_s * 1e3
    for _ in range(steps):
        tick_ms += d_ms                 # (t + d) % wrap, which is t + d below the wrap
        if tick_ms >= wrap_ms:
            tick_ms %= wrap_ms
        since_s += dt_s
    result = (tick_ms, since_s)
    _last_quiet_timers[0] = (args, result)
    return result


def _byte_item(table: ControlTable, name: str) -> int:
    """Address of item ``name``, which must be an unsigned one-byte item (X series: e-Manual)."""
    reg = table[name]
    if reg.size != 1 or reg.signed:
        raise ConfigError(f"{table.model}: {name} must be an unsigned 1-byte item, not {reg.size} bytes")
    return reg.address


def hardware_error_bits(spec: str | int) -> int:
    """Bits from an int or names like ``"overload+overheating"`` (see :class:`HardwareError`)."""
    if isinstance(spec, int):
        return spec
    names = {n.replace(" ", "_"): b for b, n in HardwareError.NAMES.items()}
    names.update({"voltage": HardwareError.INPUT_VOLTAGE, "encoder": HardwareError.MOTOR_ENCODER,
                  "overheat": HardwareError.OVERHEATING, "shock": HardwareError.ELECTRICAL_SHOCK})
    bits = 0
    for part in str(spec).replace(",", "+").split("+"):
        part = part.strip().lower()
        if not part:
            continue
        if part.isdigit() or part.startswith("0x"):
            bits |= int(part, 0)
        elif part in names:
            bits |= names[part]
        else:
            raise ValueError(f"unknown hardware error {part!r}; use one of {', '.join(sorted(names))}")
    return bits


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


__all__ = ["VirtualServo", "Dynamics", "StepDynamics", "BAUD_RATES", "baud_index", "hardware_error_bits",
           "make_servos"]
