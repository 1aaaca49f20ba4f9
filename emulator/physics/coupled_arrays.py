"""The arrays of the compiled robot kernel, kept from one run of ticks to the next.

:func:`.coupled.robot_ticks` works on arrays (:mod:`.coupled` lays them out). Building them
afresh for every run between two bus events cost several times the kernel itself, so
:class:`CoupledArrays` allocates them once per robot: the wheels' and the body's constants are
filled at construction, each servo's discretised plant and input coefficients only when the
servo derived new ones (the same tuple object otherwise). The servos' state stays in the arrays
from one run to the next (:attr:`dirty`) and goes back into the models only when a reader asks:
each model's state attributes call :meth:`CoupledArrays.store_back` when read or set
(:attr:`ServoModel.holder`), so a lockstep cycle's three runs store it back once, for the
present items of the read. After a reader, the next run copies a model's state in again only
if Python code changed it (a reboot, a Clear, a tick stepped from Python:
:attr:`ServoModel.state_version`), and the supply and loads from the models; the goals' flags go
in every run, one flat assignment per array. The body's state goes back after every run (the
true pose is published after each).
"""
from __future__ import annotations

import struct
from typing import Mapping, Sequence

import numpy as np

from . import coupled
from .body import RobotBody
from .contact import ContactBody
from .servo_model import ServoModel


class CoupledArrays:
    """The inputs and state of :func:`.coupled.robot_ticks` for one robot, reused across runs.

    Parameters
    ----------
    models : sequence of ServoModel
        The servos, in the order the supply sums their currents.
    wheel_rows : sequence of (int, int)
        Per wheel, the indices in ``models`` of its drive and steering servo.
    wheel_frames : sequence of tuple
        Per wheel: drive and steering directions (±1.0), steering centre (pulse), radius (m),
        steering offset (rad).
    body : RobotBody or ContactBody
        The body the wheels move.
    body_floats : tuple of float
        Half the steering backlash (rad), supply voltage (V) and internal resistance (Ω), the
        servos' total idle current (A) (the first four of :data:`.coupled.BODY_FLOATS`).
    supply_on : bool
        Whether the servos' currents sag the bus voltage.
    """

    def __init__(self, models: Sequence[ServoModel], wheel_rows: Sequence[tuple[int, int]],
                 wheel_frames: Sequence[tuple], body: RobotBody | ContactBody, body_floats: tuple[float, ...],
                 supply_on: bool):
        count, wheels = len(models), len(wheel_rows)
        self.models = list(models)
        self.body = body
        self.contact = isinstance(body, ContactBody)
        self.fs = np.zeros((count, len(coupled.FLOATS)))
        self.ints = np.zeros((count, len(coupled.INTS)), np.int64)
        self.servo_i = np.zeros((count, len(coupled.SERVO_INTS)), np.int64)
        self.servo_f = np.zeros((count, len(coupled.SERVO_FLOATS)))
        self.out_i = np.zeros((count, 2), np.int64)
        self.v_meas = np.zeros(count)
        self.wheel_i = np.array(wheel_rows, np.int64).reshape(wheels, 2)
        if self.contact:
            p = body.params
            place = (body._x, body._y, body._limits)
            fit = ([0.0] * wheels,) * 6
            body_consts = (float(p.lateral_stiffness_ratio), float(p.slip_stiffness_n_s_per_m), body.mass_kg,
                           body.yaw_inertia_kg_m2)
        else:
            place = ([0.0] * wheels,) * 3
            fit = body.fit_rows
            body_consts = (0.0,) * 4
        self.wheel_f = np.array([*zip(*wheel_frames), *place, *fit], float).reshape(len(coupled.WHEEL_FLOATS), wheels)
        self.wheel_out = np.zeros((len(coupled.WHEEL_OUT), wheels))
        self.backlash = np.zeros(wheels)
        self.body_f = np.array((*body_floats, *body_consts), float)
        self.flags = np.array((0, supply_on, self.contact), np.int64)
        self.pose = np.zeros(7)
        self.stats = np.zeros(2, np.int64)
        self.unused = np.zeros(1)
        self.plants: np.ndarray | None = None     # (servos, plant coefficients), at the first run
        self.inputs: np.ndarray | None = None
        self._plant_of: list = [None] * count     # the model's plant / input tuples the rows hold
        self._input_of: list = [None] * count
        # the per-run copies in: one struct.pack_into per array (native doubles / int64, C order),
        # which converts a list of Python numbers in less than half the time NumPy's assignment takes
        self._packers = tuple((struct.Struct(f"{a.size}{'d' if a.dtype == np.float64 else 'q'}").pack_into, a)
                              for a in (self.fs, self.ints, self.servo_i, self.servo_f))
        # one servo's state into its rows of ``fs`` and ``ints`` (pack, array, bytes per row)
        self._row_packers = tuple((struct.Struct(f"{a.shape[1]}{'d' if a.dtype == np.float64 else 'q'}").pack_into,
                                   a, a.itemsize * a.shape[1]) for a in (self.fs, self.ints))
        self._versions: list[int | None] = [None] * count   # each model's state_version the rows hold
        self._pack_input_row = None     # one servo's input coefficients into its row of ``inputs``
        self._ticks = None              # the kernel bound to these arrays, once ``plants`` exists
        #: True while the arrays hold servo state newer than the models' (:meth:`store_back`).
        self.dirty = False
        self._last_plans: list = []     # the last run's plans, their goal positions then, and items, per servo
        self._last_goals: list = []
        self._raised = True             # the last run raised Hardware Error bits (the column needs clearing)
        self._backlash_out: object = self     # the wheel angles the last run returned (none yet)
        self._last_tables: list = []
        self._blocked = [False] * count     # each motor's ``blocked`` at the last run the models were read for
        for m in self.models:           # the models' held attributes ask these arrays first
            if m.holder is not None:
                m.holder.store_back()
            m.holder = self

    def run(self, dt_s: float, n: int, runs: Mapping[ServoModel, tuple[Mapping[str, int], bool]],
            backlash: list[float] | None) -> tuple[int, list[float] | None]:
        """Up to ``n`` ticks of ``dt_s`` s of every servo and the body in one call of
        :data:`.coupled.ROBOT_TICKS` (see :meth:`RobotPhysics.run_coupled`): the models' state in
        (unless these arrays hold it still), the kernel, the body's state back into the body and
        the raised Hardware Error bits into the models; the servos' state stays here until a
        reader asks (:meth:`store_back`). ``runs[model]``: its raw input items and whether they
        are those of its last run. ``backlash``: the wheel angles behind the steering backlash
        (rad), ``None`` before the first step. Returns the ticks run and the wheel angles behind
        the backlash after them (``backlash`` if there is none)."""
        models = self.models
        held = self.dirty               # nothing read or changed a model since the last run
        plans, goals, plants, inputs, servo_i, servo_f, tables = [], [], [], [], [], [], []
        last_plans, last_goals, blocked = self._last_plans, self._last_goals, self._blocked
        for k, m in enumerate(models):
            table, same = runs[m]
            plan, plant, inp = m.begin_run(dt_s, table, same)
            plants.append(plant)
            inputs.append(inp)
            plans.append(plan)
            goals.append(plan.goal_position)
            tables.append(table)
            if held:                    # the last run's plan is the model's (ServoModel.run_flags)
                switched = plan.key != last_plans[k].key
                servo_i += (plan.homing, blocked[k], switched, switched or plan.goal_position != last_goals[k])
            else:
                motor = m.motor
                blocked[k] = motor.blocked
                servo_i += (plan.homing, blocked[k], *m.run_flags(plan))
                servo_f += (float(m.encoder_offset_pulse), m.supply_voltage_v, motor.load_torque_nm)
        self._load_coefficients(plants, inputs)
        (pack_i, servo_i_array), (pack_f, servo_f_array) = self._packers[2:]
        pack_i(servo_i_array, 0, *servo_i)
        if not held:                    # else the state, supply and loads are those the last run left
            self._load_state()
            pack_f(servo_f_array, 0, *servo_f)
        if self._raised:                # else the kernel left the bits column at 0
            self.out_i[:, 0] = 0
        half = self.body_f[0]
        if backlash is not self._backlash_out:     # else the array and flag hold it
            if backlash is not None:
                self.backlash[:] = backlash
            self.flags[0] = backlash is not None
        body = self.body
        if self.contact:
            self.pose[:] = (body.x_m, body.y_m, body.theta_rad, *body._twist, body.slip_energy_j)
            self.stats[:] = (body.saturated_steps, body.wheel_steps)
        else:
            self.pose[:] = (body.x_m, body.y_m, body.theta_rad, *body._twist, 0.0)
        self.dirty = True               # from the kernel's first write on, the arrays hold the newest state
        self._last_plans, self._last_goals, self._last_tables = plans, goals, tables
        if self._ticks is None:
            self._ticks = coupled.ROBOT_TICKS.bind(
                self.plants, self.inputs, self.servo_i, self.servo_f, self.fs, self.ints, self.out_i, self.v_meas,
                self.wheel_i, self.wheel_f, self.backlash, self.wheel_out, self.body_f, self.flags, self.pose,
                self.stats, self.unused)
        ran = self._ticks(n, dt_s)
        bits = self.out_i[:, 0].tolist()
        self._raised = any(bits)
        if self._raised:
            for m, b in zip(models, bits):
                if b:
                    m.pending_hardware_error |= b
        x, y, theta, vx, vy, w, energy = self.pose.tolist()
        body.x_m, body.y_m, body.theta_rad, body._twist = x, y, theta, (vx, vy, w)
        speeds, angles, slip, fx, fy, flong = self.wheel_out.tolist()
        if self.contact:
            body.slip_energy_j = energy
            body.saturated_steps, body.wheel_steps = self.stats.tolist()
            body._slip, body._fx, body._fy, body._flong = slip, fx, fy, flong
        else:
            body._fit = (tuple(speeds), tuple(angles), (vx, vy, w))
        self._backlash_out = self.backlash.tolist() if half > 0.0 else backlash
        return ran, self._backlash_out

    def store_back(self) -> None:
        """Store the servos' state the last run left (state, supply and load, last Present
        Position and measured velocity, the run's items and plan) into the models
        (:meth:`ServoModel.finish_run`), if it is not there yet. Called by a model's held
        attributes when read or set (:class:`~.servo_model.StateHolder`)."""
        if not self.dirty:
            return
        self.dirty = False
        fs_l, ints_l, out_l, vm_l, sf_l = (a.tolist() for a in (self.fs, self.ints, self.out_i, self.v_meas,
                                                                 self.servo_f))
        for k, (m, table, plan, goal) in enumerate(zip(self.models, self._last_tables, self._last_plans,
                                                       self._last_goals)):
            # (a plan's goal may have changed in place since: ServoModel.begin_run, _InputPlan.set_goals)
            m.finish_run(table, (plan.key, goal, plan.mode, plan.torque, plan.sign), 0, fs_l[k], ints_l[k],
                         out_l[k][1], vm_l[k])
            m.supply_voltage_v_, m.motor_.load_torque_nm = sf_l[k][1], sf_l[k][2]
        self._versions = [m.state_version for m in self.models]

    def bus_voltage_v(self) -> float:
        """The supply voltage the servos saw at the last run's last tick, V."""
        return float(self.servo_f[0, 1])

    def _load_state(self) -> None:
        """The state of every model whose :attr:`ServoModel.state_version` changed since its rows
        were written (all of them at the first run) into ``fs`` and ``ints``."""
        models, versions = self.models, self._versions
        stale = [k for k, m in enumerate(models) if m.state_version != versions[k]]
        if len(stale) == len(models):       # one flat assignment per array
            floats, ints = [], []
            for m in models:
                f, i = m.kernel_state()
                floats += f
                ints += i
            for (pack, array), values in zip(self._packers, (floats, ints)):
                pack(array, 0, *values)
            return
        for k in stale:
            for (pack, array, row_bytes), values in zip(self._row_packers, models[k].kernel_state()):
                pack(array, k * row_bytes, *values)

    def _load_coefficients(self, plants: list[tuple], inputs: list[tuple]) -> None:
        """Each servo's plant and input coefficients (:meth:`ServoModel.begin_run`'s ``plant[3]``
        and ``inputs[1]``) into their rows: all at the first run, then the rows whose tuple changed."""
        if self.plants is None:
            self.plants, self.inputs = np.array([p[3] for p in plants]), np.array([i[1] for i in inputs])
            row = self.inputs.shape[1]
            self._pack_input_row = (struct.Struct(f"{row}d").pack_into, 8 * row)
        else:
            pack, row_bytes = self._pack_input_row
            for k, (plant, inp, old_plant, old_inp) in enumerate(zip(plants, inputs, self._plant_of, self._input_of)):
                if plant is not old_plant:
                    self.plants[k] = plant[3]
                if inp is not old_inp:
                    pack(self.inputs, k * row_bytes, *inp[1])
        self._plant_of, self._input_of = plants, inputs
