"""A servo's input plan brought up to date for new goals equals the plan derived afresh."""
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swerve.emulator.physics import servo_model
from swerve.emulator.physics import units as u
from swerve.emulator.physics.servo_adapter import INPUTS
from swerve.emulator.physics.servo_model import ServoModel

DT = 1e-3
MODES = (u.MODE_CURRENT, u.MODE_VELOCITY, u.MODE_POSITION, u.MODE_EXTENDED_POSITION, u.MODE_CURRENT_POSITION,
         u.MODE_PWM)
GOALS = st.fixed_dictionaries({"goal_velocity": st.integers(-2000, 2000),
                               "goal_position": st.integers(-1_048_575, 1_048_575)})


@st.composite
def input_items(draw) -> dict[str, int]:
    """Every input item a :class:`ServoDynamics` hands the model, in each mode, limits and goals
    drawn (a tripped watchdog too)."""
    items = {name: draw(st.integers(0, 200)) for name in INPUTS}
    items.update(operating_mode=draw(st.sampled_from(MODES)), torque_enable=draw(st.integers(0, 1)),
                 drive_mode=draw(st.sampled_from((0, 1, 4, 5))), homing_offset=draw(st.integers(-1000, 1000)),
                 bus_watchdog=draw(st.sampled_from((0, 5, u.WATCHDOG_TRIPPED))),
                 min_position_limit=draw(st.integers(0, 2000)), max_position_limit=draw(st.integers(2000, 4095)),
                 goal_pwm=draw(st.integers(-885, 885)), pwm_limit=draw(st.integers(0, 885)),
                 goal_current=draw(st.integers(-1193, 1193)), current_limit=draw(st.integers(0, 1193)),
                 **draw(GOALS))
    return items


def _model(cfg) -> ServoModel:
    return ServoModel(cfg.steering_motor, cfg.gear_ratio("xh430-w210"), cfg.supply_voltage_v, cfg.firmware)


def _state(model: ServoModel, items: dict[str, int], same: bool) -> tuple:
    plan, _, inputs = model.begin_run(DT, items, same)
    return tuple(getattr(plan, name) for name in type(plan).__slots__), inputs[1]


CHANGES = st.one_of(GOALS, st.builds(lambda k, v: {k: v}, st.sampled_from(INPUTS), st.integers(-3000, 3000)))


@settings(max_examples=300, deadline=None)
@given(input_items(), CHANGES, st.booleans())
@example({**{n: 0 for n in INPUTS}, "operating_mode": u.MODE_POSITION, "torque_enable": 1, "max_position_limit": 4095,
          "velocity_limit": 100}, {"goal_velocity": 0, "goal_position": 5000}, False)
def test_new_items_give_the_plan_and_inputs_derived_afresh(cfg, items, change, other_dict):
    """``begin_run`` after a change of the goals or of any one input item (in a new dict, or the
    same dict changed in place) equals a model that derives the plan from the new items alone."""
    warm, fresh = _model(cfg), _model(cfg)
    _state(warm, items, False)
    if other_dict:
        items = {**items, **change}
    else:
        items.update(change)
    assert _state(warm, items, False) == _state(fresh, dict(items), False)


def test_a_change_beyond_the_goals_derives_the_plan_afresh(cfg):
    items = {**{n: 0 for n in INPUTS}, "operating_mode": u.MODE_VELOCITY, "torque_enable": 1, "velocity_limit": 100,
             "goal_velocity": 50}
    warm = _model(cfg)
    first = warm.begin_run(DT, items, False)[0]
    assert warm.begin_run(DT, {**items, "goal_velocity": 80}, False)[0] is first     # kept, new goal
    assert first.velocity_goal == 80.0
    changed = warm.begin_run(DT, {**items, "velocity_limit": 60}, False)[0]
    assert changed is not first and changed.velocity_goal == 50.0
    assert servo_model._PLAN_ITEMS({**items, "velocity_limit": 60}) == warm._plan_base
