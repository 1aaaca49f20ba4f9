"""Several physics ticks per call give exactly the state of one tick at a time.

Between two bus events the emulator runs each servo ``n`` ticks in one call
(:meth:`ServoModel.run`, :meth:`VirtualServo.advance_many`) and then the kinematic body from the
recorded wheel states (:meth:`Emulator.step_many`). Here two emulators built alike get the same
bus writes; one advances with ``emu.advance`` / the lockstep clock (batched), the other with
``emu.step`` once per tick (interleaved, servo after servo in every tick). Every state variable,
every published byte and the pose must be equal (``==``, not approximately). With numba installed
the ticks run compiled where they can (:mod:`swerve.emulator.physics.jit`); the same runs with the
plain-Python function must give the same bits.
"""
from __future__ import annotations

import dataclasses
import math
import os
import subprocess
import sys

import pytest

from swerve.configs import shipped
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.clock import LockstepPhysicsClock
from swerve.emulator.physics import coupled, jit, servo_model
from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import ContactParams, SupplyParams, load_config
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.physics.servo_model import ServoModel
from swerve.emulator.factory import build_emulator
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.timing import Frozen

RATE_HZ = 1000.0
CYCLE_S = 0.016
ROBOT_MODES = {i: u.MODE_VELOCITY if i <= 4 else u.MODE_POSITION for i in range(1, 9)}
#: Every operating mode on a bank of free shafts.
ALL_MODES = dict(enumerate((u.MODE_VELOCITY, u.MODE_POSITION, u.MODE_PWM, u.MODE_CURRENT,
                            u.MODE_EXTENDED_POSITION, u.MODE_CURRENT_POSITION, u.MODE_VELOCITY,
                            u.MODE_POSITION), start=1))
WATCHDOG_ID = 3        # stops being fed at cycle 40: its Bus Watchdog (60 ms) trips mid-cycle
TORQUE_OFF_ID = 4      # torque off at cycle 50, on again at cycle 58
STALLED_IDS = (1, 6)   # held shafts in the bank: the overload protection trips (realistic)


def _physics(profile: str, kinematic: bool, placement: str | None = None):
    cfg = load_config(resolve_emulator_config(profile))
    if kinematic:          # the realistic servos (friction, protection, tolerances) on the kinematic body
        cfg = dataclasses.replace(cfg, contact=ContactParams(enabled=False), supply=SupplyParams())
    if placement is not None:
        cfg = dataclasses.replace(cfg, firmware=dataclasses.replace(cfg.firmware, bessel_placement=placement))
    return cfg


def _emulator(profile: str, body: bool, noise: str | None = None, kinematic: bool = False,
              placement: str | None = None):
    robot = load_robot_config(shipped("robot.yaml"))
    emu = build_emulator(robot if body else None, _physics(profile, kinematic, placement),
                         ids=None if body else range(1, 9),
                         timing=Frozen(), rate_hz=RATE_HZ, noise=noise, body=BodySettings() if body else None)
    modes = ROBOT_MODES if body else ALL_MODES
    for s in emu.servos:
        _write(s, Reg.OPERATING_MODE, modes[s.id])
        if s.id == WATCHDOG_ID:
            _write(s, Reg.BUS_WATCHDOG, 3)
        _write(s, Reg.TORQUE_ENABLE, 1)
        if not body and s.id in STALLED_IDS:
            s.dynamics.model.motor.blocked = True
    return emu, modes


def _write(servo, reg, value: int) -> None:
    """A bus write (it may be refused, e.g. goals after a watchdog trip: alike on both emulators)."""
    t = servo.table[reg]
    servo.bus_write(t.address, int(value).to_bytes(t.size, "little", signed=True))


def _commands(emu, modes, k: int) -> None:
    """Cycle ``k``'s bus writes: goals in every mode, a profile change, torque off/on, traffic."""
    for s in emu.servos:
        mode = modes[s.id]
        if not (s.id == WATCHDOG_ID and k >= 40):
            s.note_traffic()
        if s.dynamics.model.motor.blocked:      # a stalled shaft pushed hard: overload
            if mode == u.MODE_VELOCITY:
                _write(s, Reg.GOAL_VELOCITY, 200)
            else:
                _write(s, Reg.GOAL_POSITION, 3048)
        elif mode == u.MODE_VELOCITY:
            _write(s, Reg.GOAL_VELOCITY, int(150 * math.sin(k / 5.0)) + (300 if 20 < k < 30 else 0))
        elif mode in u.POSITION_MODES:
            _write(s, Reg.GOAL_POSITION, 2048 + int(600 * math.sin(k / 7.0)))
            if k == 15:
                _write(s, Reg.PROFILE_VELOCITY, 100)
                _write(s, Reg.PROFILE_ACCELERATION, 20)
        elif mode == u.MODE_PWM:
            _write(s, Reg.GOAL_PWM, int(800 * math.sin(k / 4.0)))
        elif mode == u.MODE_CURRENT:
            _write(s, Reg.GOAL_CURRENT, int(900 * math.sin(k / 4.0)))
        if s.id == TORQUE_OFF_ID and k in (50, 58):
            _write(s, Reg.TORQUE_ENABLE, int(k == 58))
        if mode in u.POSITION_MODES and k == 25:        # the D and feed-forward terms from here on
            _write(s, Reg.POSITION_D_GAIN, 400)
            _write(s, Reg.FEEDFORWARD_1ST_GAIN, 80)
            _write(s, Reg.FEEDFORWARD_2ND_GAIN, 40)


def _model_state(m: ServoModel) -> tuple:
    mo, p = m.motor, m.profile
    return (mo.current_a, mo.speed_radps, mo.angle_rad, mo.stuck, mo.friction_torque_nm,
            m.velocity_filter.y, m.velocity_filter.dy, m.reference_filter.y, m.reference_filter.dy,
            p.position, p.velocity, p.acceleration, p.ongoing, p.profile_type, m.loop.integral,
            m.temperature_c, m.duty, m._wrap_pulse, m._goal_pulse, m._hold_position,
            m.protection.overload_timer_s if m.protection is not None else None)


def _snapshot(emu) -> list:
    """Everything observable: the present items as the bus reads them, latched errors, the
    watchdog, Realtime Tick, every physics state variable, the pose and the clock."""
    table = emu.servos[0].table
    first = table[Reg.PRESENT_PWM].address
    length = table[Reg.PRESENT_TEMPERATURE].address + 1 - first
    out = [emu.sim_time_s, emu.stats.clock_ticks, emu.world.pose if emu.world is not None else None]
    for s in emu.servos:
        out.append((s.id, s.read_status(first, length).params, s.memory.get(Reg.REALTIME_TICK),
                    s.memory.get(Reg.HARDWARE_ERROR_STATUS), s.memory.get(Reg.BUS_WATCHDOG),
                    s.memory.get(Reg.TORQUE_ENABLE), _model_state(s.dynamics.model)))
    return out


class CountingKernel:
    """A :class:`~swerve.emulator.physics.native.NativeKernel` whose bound calls append the ticks
    they are asked for to ``calls``."""

    def __init__(self, kernel, calls: list):
        self.kernel = kernel
        self.calls = calls

    def load(self) -> None:
        self.kernel.load()

    def bind(self, *arrays):
        bound = self.kernel.bind(*arrays)

        def call(n, dt_s):
            self.calls.append(n)
            return bound(n, dt_s)
        return call


def _runs(monkeypatch, advance_batched, **build) -> tuple[list, list, tuple[int, int]]:
    """The same commands on two emulators: batched steps vs one :meth:`Emulator.step` per tick.
    Returns both snapshot lists and the numbers of multi-tick runs: servo after servo
    (:meth:`ServoModel.run`) and, with numba on a robot body, of the whole robot
    (:func:`~swerve.emulator.physics.coupled.robot_ticks`)."""
    servo_runs, robot_runs = [], []
    original = ServoModel.run

    def counting(self, dt_s, table, n=1, **kwargs):
        servo_runs.append(n)
        return original(self, dt_s, table, n, **kwargs)

    monkeypatch.setattr(ServoModel, "run", counting)
    if coupled.ROBOT_TICKS is not None:
        monkeypatch.setattr(coupled, "ROBOT_TICKS", CountingKernel(coupled.ROBOT_TICKS, robot_runs))
    batched, stepped = _emulator(**build), _emulator(**build)
    steps = round(CYCLE_S * RATE_HZ)
    a, b = [], []
    for k in range(70):
        for (emu, modes), out in ((batched, a), (stepped, b)):
            _commands(emu, modes, k)
            if emu is batched[0]:
                advance_batched(emu, k)
            else:
                for _ in range(steps):
                    emu.step(1.0 / RATE_HZ)
            out.append(_snapshot(emu))
    return a, b, (sum(1 for n in servo_runs if n > 1), sum(1 for n in robot_runs if n > 1))


def _by_advance(emu, k):
    emu.advance(CYCLE_S)


@pytest.mark.parametrize("profile", ["ideal", "realistic"])
@pytest.mark.parametrize("body", [True, False], ids=["robot", "bank"])
def test_batched_ticks_equal_single_ticks(monkeypatch, profile, body):
    a, b, (servo_runs, robot_runs) = _runs(monkeypatch, _by_advance, profile=profile, body=body, kinematic=True)
    # the batched path did run: the robot in one compiled call with numba, else servo after servo
    assert (robot_runs if body and jit.ENABLED else servo_runs) > 0
    assert a == b


def test_batched_ticks_trip_the_watchdog_protection_and_torque_off_as_single_ticks(monkeypatch):
    """The bank's realistic run exercises every split of a batch: the cases happened."""
    a, b, _ = _runs(monkeypatch, _by_advance, profile="realistic", body=False)
    assert a == b
    final = {row[0]: row for row in a[-1][3:]}
    assert final[WATCHDOG_ID][4] == -1                       # the watchdog tripped
    assert all(final[i][3] for i in STALLED_IDS)             # Overload latched on the held shafts
    assert any({r[0]: r for r in snap[3:]}[TORQUE_OFF_ID][5] == 0 for snap in a)   # torque was off


def test_lockstep_clock_runs_batches_equal_to_single_ticks(monkeypatch):
    """The lockstep clock moves time to arbitrary instants (bus exchanges): uneven batches."""
    clock = LockstepPhysicsClock(RATE_HZ)

    def by_clock(emu, k):
        for t in (0.0003, 0.0041, 0.0107, 0.016):          # instants inside the cycle
            clock.advance_to(emu, k * CYCLE_S + t)

    a, b, runs = _runs(monkeypatch, by_clock, profile="ideal", body=True)
    assert sum(runs) > 0
    assert a == b


@pytest.mark.parametrize("profile", ["ideal", "realistic"])
def test_unbatchable_worlds_step_tick_by_tick(monkeypatch, profile):
    """Sensor noise (shared draws), tyre forces and supply sag keep the per-tick interleaving:
    no servo runs several ticks alone (the compiled robot steps them all tick by tick)."""
    noise = "position=0.5,current=0.002,seed=4" if profile == "ideal" else None
    a, b, (servo_runs, robot_runs) = _runs(monkeypatch, _by_advance, profile=profile, body=True, noise=noise)
    assert servo_runs == 0
    assert robot_runs == 0 if noise else robot_runs > 0 or not jit.ENABLED
    assert a == b


def test_lockstep_jump_equals_single_ticks():
    """A jump of 0.35 s: several holds of the lock (MAX_STEPS_PER_HOLD) and a watchdog trip."""
    clock = LockstepPhysicsClock(RATE_HZ)
    batched, stepped = _emulator("ideal", True), _emulator("ideal", True)
    for emu, modes in (batched, stepped):
        _commands(emu, modes, 3)
    clock.advance_to(batched[0], 0.35)
    for _ in range(350):
        stepped[0].step(1.0 / RATE_HZ)
    snap = _snapshot(batched[0])
    assert snap == _snapshot(stepped[0])
    assert {r[0]: r for r in snap[3:]}[WATCHDOG_ID][4] == -1       # the watchdog tripped during the jump


def _compiled_runs(monkeypatch, **build) -> tuple[list, list, tuple[int, int]]:
    """The same commands on two emulators, both batched (``emu.advance``): one with the compiled
    kernels (servo ticks, the robot's ticks), one with the plain-Python function. Returns both
    snapshot lists and the numbers of compiled calls of each kernel."""
    servo_kernel = servo_model._COMPILED_TICKS
    calls = [], []

    def counting_servo(*args):
        calls[0].append(args[0])
        return servo_kernel(*args)

    counting_servo.signatures = servo_kernel.signatures     # what ServoModel.prepare looks at
    snaps = []
    for compiled_kernels in ((counting_servo, CountingKernel(coupled.ROBOT_TICKS, calls[1])), (None, None)):
        monkeypatch.setattr(servo_model, "_COMPILED_TICKS", compiled_kernels[0])
        monkeypatch.setattr(coupled, "ROBOT_TICKS", compiled_kernels[1])
        emu, modes = _emulator(**build)
        out = []
        for k in range(70):
            _commands(emu, modes, k)
            emu.advance(CYCLE_S)
            out.append(_snapshot(emu))
        snaps.append(out)
    return snaps[0], snaps[1], (len(calls[0]), len(calls[1]))


@pytest.mark.skipif(not jit.ENABLED, reason="numba is not installed (or SWERVE_NO_JIT is set)")
@pytest.mark.parametrize("placement", ["velocity_feedback", "reference", "none"])
@pytest.mark.parametrize("body", [True, False], ids=["robot", "bank"])
def test_compiled_ticks_equal_python_ticks(monkeypatch, body, placement):
    """Every mode, the watchdog's hold, torque off and on, profiles, D and feed-forward gains:
    every state variable, published byte and the pose equal (``==``) both ways."""
    kernel = servo_model._COMPILED_TICKS
    compiled, python, (servo_calls, robot_calls) = _compiled_runs(monkeypatch, profile="ideal", body=body,
                                                                  placement=placement)
    assert len(kernel.signatures) == 1          # every run of every mode: one specialisation
    if body:                                    # the robot's kernel ran every cycle
        assert robot_calls >= 70
    else:   # the servo kernel ran every servo every cycle, but the held shafts (Python: motor.step)
        assert servo_calls >= 70 * (8 - len(STALLED_IDS))
    assert compiled == python


@pytest.mark.slow
@pytest.mark.skipif(not jit.ENABLED, reason="numba is not installed (or SWERVE_NO_JIT is set)")
@pytest.mark.parametrize("body", [True, False], ids=["robot", "bank"])
def test_the_emulator_loads_the_compiled_kernel_when_built(body):
    """Built, the emulator has its kernel loaded (a first tick would stall the bus for its load
    or compile), and running needs nothing more: the robot's native kernel, loaded from the
    kernel cache without importing numba (a first build may compile it); a bank of servos,
    the servos' numba kernel with one specialisation."""
    code = ("import sys; from swerve.configs import shipped; from swerve.driver.robot_config import load_robot_config; "
            "from swerve.emulator.physics.params import load_config; "
            "from swerve.emulator.physics.servo_model import _COMPILED_TICKS as k; "
            "from swerve.emulator.physics.coupled import ROBOT_TICKS as r; "
            "from swerve.emulator.factory import build_emulator; from swerve.emulator.body_settings import BodySettings; "
            "from swerve.emulator.timing import Frozen; "
            "robot = load_robot_config(shipped('robot.yaml')); "
            f"emu = build_emulator(robot if {body} else None, load_config(shipped('emulator.yaml')), "
            f"body=BodySettings() if {body} else None, ids=None if {body} else range(1, 9), timing=Frozen(), "
            "rate_hz=1000.0); "
            "state = lambda: print(r.loaded, r.hit, 'numba' in sys.modules, len(k.signatures)); "
            "state(); emu.advance(0.016); state()")

    def run() -> list[str]:
        return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()

    first, again = run(), run()
    if body:
        assert first[:1] == first[4:5] == ["True"]
        assert again == ["True", "True", "False", "0"] * 2
    else:
        assert first == again == ["False", "None", "True", "1"] * 2


def test_no_jit_switch_selects_the_python_function():
    """``SWERVE_NO_JIT=1``: no compiled kernel, the ticks run as plain Python."""
    code = ("from swerve.emulator.physics import jit, servo_model; "
            "print(jit.ENABLED, servo_model._COMPILED_TICKS)")
    out = subprocess.run([sys.executable, "-c", code], env={**os.environ, "SWERVE_NO_JIT": "1"},
                         capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "None"]


STALLED_DRIVE_ID = 2    # a held drive shaft on the robot: its overload protection trips


@pytest.mark.skipif(not jit.ENABLED, reason="numba is not installed (or SWERVE_NO_JIT is set)")
@pytest.mark.parametrize("kinematic", [False, True], ids=["tyres", "kinematic"])
@pytest.mark.parametrize("stall", [False, True], ids=["free", "stalled"])
def test_coupled_ticks_equal_single_ticks(monkeypatch, stall, kinematic):
    """The compiled coupled loop (:func:`swerve.emulator.physics.coupled.robot_ticks`: servos,
    backlash, tyre forces and supply sag, or the kinematic body, in one call) against one tick
    at a time: velocity and
    position modes, profile changes, the watchdog's trip, torque off and on, D and feed-forward
    gains; with a held drive shaft also the overload protection (the run stops at the tick it
    trips). Every state variable, published byte and the pose equal (``==``)."""
    calls = []
    monkeypatch.setattr(coupled, "ROBOT_TICKS", CountingKernel(coupled.ROBOT_TICKS, calls))
    build = _emulator

    def emulator(*args, **kwargs):
        emu, modes = build(*args, **kwargs)
        if stall:
            {s.id: s for s in emu.servos}[STALLED_DRIVE_ID].dynamics.model.motor.blocked = True
        return emu, modes

    monkeypatch.setitem(globals(), "_emulator", emulator)
    a, b, _ = _runs(monkeypatch, _by_advance, profile="realistic", body=True, kinematic=kinematic)
    assert len(calls) >= 70 and max(calls) > 1       # the coupled loop ran every cycle
    assert a == b
    final = {row[0]: row for row in a[-1][3:]}
    assert final[WATCHDOG_ID][4] == -1                 # the watchdog tripped
    if stall:
        assert final[STALLED_DRIVE_ID][3]              # Overload latched
