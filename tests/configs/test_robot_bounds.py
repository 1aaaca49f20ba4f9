"""Every number of the robot file has a physical range, the README states it, the loader checks it.

The table is :func:`swerve.driver.robot_config.robot_bounds`. The tests check that it covers every
number of the shipped file, that configs/README.md lists it unchanged, and (hypothesis) that for
every key any value outside its range (nan, inf, 1e300, 1e-300, negative, just past an end, a
float for an integer) is refused with one line ``FILE:LINE: KEY: ...`` pointing at that key, while
values inside it load.
"""
from __future__ import annotations

import copy
import math
import re
from pathlib import Path

import pytest
import yaml
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swerve.configs import shipped
from swerve.core.errors import ConfigError
from swerve.configs.loader import parse_yaml_text
from swerve.driver.control_table import REFERENCE_MODEL, table_for
from swerve.driver.robot_config import parse_robot_config, robot_bounds

BOUNDS = robot_bounds(table_for(REFERENCE_MODEL))
RAW = yaml.safe_load(Path(shipped("robot.yaml")).read_text())
README = Path(shipped("robot.yaml")).with_name("README.md")
FILE = "robot.yaml"


def _numbers(node, path=()):
    """Dotted table keys of every number in ``node`` (list items as ``[]``, gains as ``*``)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numbers(v, path + (k,))
    elif isinstance(node, list):
        for v in node:
            yield from _numbers(v, path + ("[]",))
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        parts = ["*" if i == len(path) - 1 and path[-2:-1] == ("gains",) else p for i, p in enumerate(path)]
        yield ".".join(parts).replace(".[]", "[]")


def test_every_number_of_the_robot_file_has_a_range():
    assert set(_numbers(RAW)) <= set(BOUNDS), set(_numbers(RAW)) - set(BOUNDS)
    optional = {k for k in BOUNDS if k.endswith(("profile_velocity", "profile_acceleration"))}
    assert set(BOUNDS) - optional <= set(_numbers(RAW))


def test_readme_states_the_loader_ranges():
    rows = dict(re.findall(r"^\| `([^`]+)` \| ([^|]+?) \|", README.read_text(), re.M))
    assert {k: rows.get(k) for k in BOUNDS} == {k: b.describe() for k, b in BOUNDS.items()}


def _place(key: str, index: int) -> tuple:
    """A concrete path in ``RAW`` for table key ``key`` (``index`` picks the list item or gain)."""
    parts: list = []
    for part in key.split("."):
        name, brackets = part.removesuffix("[]"), part.endswith("[]")
        if name == "*":
            gains = list(_get(RAW, tuple(parts)))
            parts.append(gains[index % len(gains)])
            continue
        parts.append(name)
        if brackets:
            parts.append(index % 4)
    return tuple(parts)


def _get(node, path):
    for p in path:
        node = node[p]
    return node


def _with(path: tuple, value) -> str:
    doc = copy.deepcopy(RAW)
    _get(doc, path[:-1])[path[-1]] = value
    return yaml.safe_dump(doc, sort_keys=False)


def _dotted(path: tuple) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else p)
    return out


def _outside(b):
    """Values outside bound ``b`` (nan, inf, huge, tiny, negative, just past each end, wrong type)."""
    extreme = st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300, 1e-300, -1e-300, -1.0])
    past = st.one_of(st.floats(max_value=b.lo, exclude_max=True, allow_nan=False),
                     st.floats(min_value=b.hi, exclude_min=True, allow_nan=False))
    ints = st.one_of(st.integers(max_value=int(math.ceil(b.lo)) - 1), st.integers(min_value=int(b.hi) + 1),
                     st.sampled_from([10**30, -10**30]))
    if b.allowed is not None:
        return st.one_of(extreme, ints, st.floats(allow_nan=False)).filter(lambda v: v not in b.allowed)
    if b.integer:
        return st.one_of(extreme, ints, st.floats(min_value=b.lo, max_value=b.hi).filter(lambda v: v != int(v)))
    values = st.one_of(extreme, past, ints)
    if b.step:
        values = st.one_of(values, st.floats(b.lo, b.hi).filter(lambda v: v % b.step))
    return values.filter(lambda v: not (b.lo <= v <= b.hi) or isinstance(v, float) and math.isnan(v)
                         or (b.step and v % b.step))


def _cases(values):
    """``(key, index, value)``: any key of the table, a list item or gain, a value from ``values(bound)``."""
    key = st.sampled_from(sorted(BOUNDS))
    return key.flatmap(lambda k: st.tuples(st.just(k), st.integers(0, 7), values(BOUNDS[k])))


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(case=_cases(_outside))
@example(case=("geometry.wheel_radius_m", 0, 1e-300))
@example(case=("limits.steer_rate_max_radps", 0, 1e-300))
@example(case=("safety.max_consecutive_timeouts", 0, 10**30))
@example(case=("safety.max_consecutive_timeouts", 0, 1e30))
def test_a_number_outside_its_range_is_one_line_naming_file_line_key(case):
    key, index, value = case
    path = _place(key, index)
    text = _with(path, value)
    with pytest.raises(ConfigError) as err:
        parse_robot_config(parse_yaml_text(text, FILE))
    msg = str(err.value)
    assert "\n" not in msg
    m = re.match(rf"^{FILE}:(\d+): (\S+): ", msg)
    assert m and m[2] == _dotted(path), msg
    assert err.value.key == _dotted(path) and err.value.file == FILE
    line = text.splitlines()[int(m[1]) - 1]
    leaf = path[-1]
    assert (f"{leaf}:" in line) if isinstance(leaf, str) else line.lstrip().startswith("- "), (line, msg)


def _inside(b):
    if b.allowed is not None:
        return st.sampled_from(b.allowed)
    if b.integer:
        return st.integers(int(math.ceil(b.lo)), int(b.hi))
    if b.step:
        return st.integers(0, int(b.hi // b.step)).map(lambda k: float(k * b.step))
    return st.floats(b.lo, b.hi)


@settings(max_examples=200, deadline=None)
@given(case=_cases(_inside))
def test_a_number_inside_its_range_loads(case):
    key, index, value = case
    path = _place(key, index)
    if key.startswith("wheels[].") and key.endswith("_id"):
        taken = {w[k] for w in RAW["wheels"] for k in ("drive_id", "steer_id")} - {_get(RAW, path)}
        if value in taken:
            value = next(v for v in range(253) if v not in taken)
    try:
        cfg = parse_robot_config(parse_yaml_text(_with(path, value), FILE))
    except ConfigError as exc:        # the one cross-key rule: the wheel speed cap vs the servo
        assert key in ("limits.v1_max_mps", "geometry.wheel_radius_m"), exc
        assert "above the drive servo's Velocity Limit" in str(exc)
        return
    assert cfg.drive_max_radps <= BOUNDS["limits.steer_rate_max_radps"].hi


def test_wheel_speed_cap_beyond_the_servo_is_refused():
    text = _with(("limits", "v1_max_mps"), 5.0)
    with pytest.raises(ConfigError, match=r"robot.yaml:\d+: limits.v1_max_mps: 5 m/s on a 0.033 m wheel is "
                                          r"151.5 rad/s, above the drive servo's Velocity Limit 24.53 rad/s"):
        parse_robot_config(parse_yaml_text(text, FILE))


def test_an_integer_too_long_to_convert_is_one_line():
    text = _with(("safety", "max_consecutive_timeouts"), 7).replace(
        "max_consecutive_timeouts: 7", "max_consecutive_timeouts: " + "9" * 5000)
    with pytest.raises(ConfigError, match=r"^robot.yaml: not a usable YAML value: Exceeds the limit"):
        parse_robot_config(parse_yaml_text(text, FILE))
