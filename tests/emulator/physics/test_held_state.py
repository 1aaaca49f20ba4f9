"""The compiled robot's arrays keep the servos' state between runs and store it back into the models
only when a reader asks (:meth:`CoupledArrays.store_back`): for any sequence of runs, reads and
changes from Python, every reader sees what it would see with the state stored back after every
run, bit for bit."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

from swerve.emulator.physics import jit
from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.physics.robot import RobotPhysics
from swerve.emulator.physics.steptest import table

pytestmark = pytest.mark.skipif(not jit.ENABLED, reason="numba is not installed (or SWERVE_NO_JIT is set)")

DT = 1e-3
_CONFIGS = {}


def _robot(profile: str, geometry) -> RobotPhysics:
    if profile not in _CONFIGS:
        _CONFIGS[profile] = load_config(resolve_emulator_config(profile))
    return RobotPhysics(_CONFIGS[profile], geometry, rng=np.random.default_rng(1))


def _items(geometry, goals: list[int], mode_flip: int) -> dict:
    """Raw items per servo ID: the drives in Velocity mode, the steering in Position mode with a
    profile (a new goal starts one), one servo in the other mode when ``mode_flip`` names it,
    torque on, the goals drawn."""
    out = {}
    for k, w in enumerate(geometry.wheels):
        drive_mode = u.MODE_POSITION if mode_flip == w.drive_id else u.MODE_VELOCITY
        out[w.drive_id] = table(torque_enable=1, operating_mode=drive_mode, goal_velocity=goals[k] // 4,
                                goal_position=2048 + goals[k], profile_acceleration=30)
        steer_mode = u.MODE_VELOCITY if mode_flip == w.steer_id else u.MODE_POSITION
        out[w.steer_id] = table(torque_enable=1, operating_mode=steer_mode, goal_position=w.center_pulse + goals[k],
                                goal_velocity=goals[k] // 8, position_d_gain=100 if goals[k] > 0 else 0,
                                profile_velocity=40, profile_acceleration=10)
    return out


def _observe(robot: RobotPhysics) -> list:
    """Everything a reader of the models sees (present items, state, true shaft), then the body."""
    out = []
    for sid, m in robot.servos.items():
        out.append((sid, m.outputs(), m.kernel_state(), m.position_pulse, m.velocity_radps, m.supply_current_a,
                    m.motor.load_torque_nm, m.supply_voltage_v, m.pending_hardware_error))
    out.append((robot.body.pose, robot.bus_voltage_v))
    return out


_op = st.one_of(
    st.tuples(st.just("run"), st.integers(1, 16), st.lists(st.integers(-600, 600), min_size=4, max_size=4),
              st.sampled_from([0, 2, 5]), st.booleans()),
    st.tuples(st.just("read"), st.integers(1, 8)),
    st.tuples(st.just("reboot"), st.integers(1, 8)),
    st.tuples(st.just("clear"), st.integers(1, 8)),
    st.tuples(st.just("block"), st.integers(1, 8), st.booleans()),
    st.tuples(st.just("load"), st.integers(1, 8), st.floats(-0.5, 0.5)),
    st.tuples(st.just("place"), st.integers(1, 8), st.floats(-3.0, 3.0)),
)


def _apply(robot: RobotPhysics, geometry, op, last: dict, eager: bool) -> object:
    """One operation; ``eager``: store the arrays' state back after every run (the reference)."""
    kind, sid = op[0], op[1]
    if kind == "run":
        _, n, goals, flip, same = op
        items = last["items"] if same and "items" in last else _items(geometry, goals, flip)
        runs = {m: (items[i], same and items is last.get("items")) for i, m in robot.servos.items()}
        last["items"] = items
        ran = robot.run_coupled(DT, n, runs)
        if eager:
            robot._coupled.store_back()
        return ran
    m = robot.servos[sid]
    if kind == "read":
        return m.outputs(), m.shaft_angle_rad
    if kind == "reboot":
        m.reboot()
    elif kind == "clear":
        m.clear_multi_turn()
    elif kind == "block":
        m.motor.blocked = op[2]
    elif kind == "load":
        m.external_load(op[2])
    else:
        m.set_shaft_angle(op[2])
    return None


@settings(max_examples=40, deadline=None)
@given(profile=st.sampled_from(["ideal", "realistic"]), ops=st.lists(_op, min_size=1, max_size=25))
@example(profile="realistic", ops=[("run", 3, [100, -100, 50, 0], 0, False), ("run", 13, [0, 0, 0, 0], 0, True),
                                   ("block", 2, True), ("run", 16, [600, 600, 600, 600], 2, False),
                                   ("read", 2), ("run", 1, [1, 2, 3, 4], 5, False)])
@example(profile="ideal", ops=[("run", 2, [10, 20, 30, 40], 0, False), ("reboot", 5),
                               ("run", 1, [10, 20, 30, 41], 0, False), ("run", 13, [10, 20, 30, 41], 0, True)])
def test_held_state_equals_state_stored_after_every_run(geometry, profile, ops):
    held, eager = _robot(profile, geometry), _robot(profile, geometry)
    last_held, last_eager = {}, {}
    for op in ops:
        assert _apply(held, geometry, op, last_held, False) == _apply(eager, geometry, op, last_eager, True)
    assert _observe(held) == _observe(eager)


def test_runs_without_a_reader_keep_the_state_in_the_arrays(geometry):
    """Between two runs nobody reads: nothing is stored back, and the second run starts from the
    arrays; a reader then sees the state of the last run."""
    robot = _robot("ideal", geometry)
    items = _items(geometry, [200, -200, 100, 0], 0)
    runs = {m: (items[i], False) for i, m in robot.servos.items()}
    robot.run_coupled(DT, 2, runs)
    arrays = robot._coupled
    versions = [m.state_version for m in robot.servos.values()]
    assert arrays.dirty
    robot.run_coupled(DT, 13, {m: (items[i], True) for i, m in robot.servos.items()})
    assert arrays.dirty and [m.state_version for m in robot.servos.values()] == versions
    model = next(iter(robot.servos.values()))
    current = float(arrays.fs[0, 0])
    assert model.motor.current_a == current         # the read stored the state back
    assert not arrays.dirty and model.state_version == versions[0] + 1
