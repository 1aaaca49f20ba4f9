"""The per-step adapter between one servo's memory and its physics model (the servo's ``dynamics``).

:class:`ServoDynamics` implements :class:`swerve.emulator.servo.Dynamics` for a
:class:`~swerve.emulator.physics.servo_model.ServoModel`: each clock step it hands the model the
servo's input items (decoded in one pass from the stored bytes, only when they changed) and,
when the bus reads a present item, the model's outputs go back into memory.
"""
from __future__ import annotations

from typing import Mapping

from swerve.driver.span_codec import items_struct
from swerve.emulator.physics.servo_model import ServoModel
from swerve.emulator.servo import VirtualServo

#: Control-table items ServoModel.step reads (its docstring); all lie below address 120.
INPUTS = ("torque_enable", "operating_mode", "drive_mode", "goal_pwm", "goal_current", "goal_velocity",
           "goal_position", "profile_acceleration", "profile_velocity", "velocity_i_gain",
           "velocity_p_gain", "position_d_gain", "position_i_gain", "position_p_gain",
           "feedforward_1st_gain", "feedforward_2nd_gain", "pwm_limit", "current_limit",
           "velocity_limit", "max_position_limit", "min_position_limit", "moving_threshold",
           "homing_offset", "bus_watchdog", "temperature_limit", "max_voltage_limit", "min_voltage_limit")


class ServoDynamics:
    """Adapter between one :class:`VirtualServo` and its :class:`ServoModel` (the ``dynamics``).

    Speed, not semantics: ``memory.view()`` decodes an item per access. This adapter decodes the
    ~24 input items in one pass from the stored bytes below the first output item
    (:meth:`ServoMemory.stored_bytes`), and only when those bytes changed.
    """

    def __init__(self, model: ServoModel, servo: VirtualServo):
        self.model = model
        self._servo = servo
        self._memory = servo.memory
        names, fmt = items_struct(servo.table, INPUTS)    # address order, gaps as pad bytes, from byte 0
        self._names = list(names)
        self._end = fmt.size
        self._unpack = fmt.unpack_from
        self._raw = b""
        self._items: dict[str, int] = {}

    def inputs(self) -> dict[str, int]:
        """The input items (raw, signed where signed), decoded afresh only if their bytes changed
        (then a new dict: an unchanged one is the same object)."""
        raw = self._memory.stored_bytes(self._end)
        if raw != self._raw:
            self._raw = raw
            self._items = dict(zip(self._names, self._unpack(raw)))
        return self._items

    def advance(self, dt_s: float, table: Mapping[str, int]) -> None:
        """One physics step under the servo's current input items."""
        self.advance_many(dt_s, 1, table)
        bits = self.take_hardware_error()
        if bits:                                    # the physics tripped a protection: latch it
            self._servo.raise_hardware_error(bits)

    def advance_many(self, dt_s: float, n: int, table: Mapping[str, int],
                     traces: Mapping[ServoModel, tuple] | None = None) -> int:
        """Up to ``n`` physics steps under the current input items (:meth:`ServoModel.run`; read
        from the stored bytes, not from the item view ``table``); stops after a step that raised
        a Hardware Error bit (:meth:`take_hardware_error`, for the caller to latch).
        ``traces[model]``: the ``(speeds, positions)`` lists the model appends to per step, if
        present. Returns the steps run."""
        speeds, positions = traces.get(self.model, (None, None)) if traces else (None, None)
        items, same = self.current_inputs()
        return self.model.run(dt_s, items, n, same_inputs=same, speeds=speeds, positions=positions)

    def current_inputs(self) -> tuple[dict[str, int], bool]:
        """``(items, same)``: :meth:`inputs`, and whether they are the mapping of the last call."""
        items = self._items
        return self.inputs(), self._items is items

    def take_hardware_error(self) -> int:
        """Hardware Error bits the physics raised since the last call (then cleared)."""
        return self.model.take_hardware_error() if self.model.pending_hardware_error else 0

    @property
    def batchable(self) -> bool:
        """True if steps may run several at a time, servo after servo: no sensor noise, whose
        draws from the shared generator would then come in another order."""
        s = self.model.sensors
        return not (s.position_noise_std_pulse or s.current_noise_std_a or s.voltage_noise_std_v)

    def reading(self) -> tuple | None:
        """A new reading's sensor noise draws (:meth:`ServoModel.reading`; ``None`` before the first step)."""
        return self.model.reading()

    def motion(self, reading: tuple) -> tuple[int, int, int]:
        """Present Current, Velocity and Position of ``reading`` (:meth:`ServoModel.motion`)."""
        return self.model.motion(reading)

    def outputs(self, reading: tuple | None = None) -> dict[str, int]:
        """Present items as of the last step (at rest before the first), of ``reading`` (a new one if ``None``)."""
        return self.model.outputs(reading)

    def reboot(self) -> None:
        self.model.reboot()
        self._raw = b""

    def clear_multi_turn(self) -> None:
        self.model.clear_multi_turn()
