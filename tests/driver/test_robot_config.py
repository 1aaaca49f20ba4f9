"""configs/robot.yaml loading and validation: every malformed input names its key."""
from __future__ import annotations

import copy
import math

import pytest
import yaml

from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import DEFAULT_PATH, load_robot_config, parse_robot_config

RAW = yaml.safe_load(DEFAULT_PATH.read_text())


def test_loads_shipped_config():
    cfg = load_robot_config()
    assert cfg.drive_ids == (1, 2, 3, 4)
    assert cfg.steer_ids == (5, 6, 7, 8)
    assert [w.drive_direction for w in cfg.wheels] == [1, 1, -1, -1]
    assert cfg.wheels[0].center_pulse == 2048
    assert cfg.link.baud == 1_000_000 and cfg.link.return_delay_us == 0
    assert cfg.model == "XH430-W210"
    assert cfg.drive.operating_mode == 1 and cfg.steering.operating_mode == 3
    assert cfg.drive_max_radps == pytest.approx(0.13 / 0.033)
    with pytest.raises(AttributeError):
        cfg.model = "x"  # frozen


def _mutate(path, value):
    doc = copy.deepcopy(RAW)
    node = doc
    for k in path[:-1]:
        node = node[k]
    if value is KeyError:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


BAD = [
    (("wheels", 2, "drive_id"), 1, r"wheels\[2\]\.drive_id: duplicate servo ID 1"),
    (("wheels", 0, "steer_id"), 300, r"wheels\[0\]\.steer_id: 300 is outside"),
    (("wheels", 1, "drive_id"), "two", r"wheels\[1\]\.drive_id: expected an integer"),
    (("wheels", 1, "x_m"), KeyError, r"wheels\[1\]\.x_m: missing"),
    (("wheels",), [], r"wheels: expected a list of exactly 4 items, got 0"),
    (("drive", "direction"), [1, 1, 0, -1], r"drive\.direction\[2\]: expected one of 1, -1, got 0"),
    (("steering", "center_pulse"), [2048, 2048, 5000, 2048], r"steering\.center_pulse\[2\]"),
    (("geometry", "wheel_radius_m"), -0.03, r"geometry\.wheel_radius_m: -0.03 is outside \[0.005, 1\] m"),
    (("geometry", "wheel_radius_m"), float("nan"), r"geometry\.wheel_radius_m: expected a finite number, got nan"),
    (("link", "baud"), 123, r"link\.baud: expected one of 9600, .* bps, got 123"),
    (("link", "return_delay_us"), 3, r"link\.return_delay_us"),
    (("link", "port"), None, r"link\.port"),
    (("model",), "xh430-w150", r"model: unknown servo model"),
    (("drive", "operating_mode"), "warp", r"drive\.operating_mode: expected one of current, velocity, .*'warp'"),
    (("drive", "operating_mode"), "position", r"drive\.operating_mode: drive servos must be in velocity"),
    (("drive", "gains", "velocity_q_gain"), 3, r"drive\.gains\.velocity_q_gain: not a gain register"),
    (("steering", "gains", "position_p_gain"), 99999, r"steering\.gains\.position_p_gain: 99999 is outside"),
    (("safety", "bus_watchdog_s"), 10, r"safety\.bus_watchdog_s"),
    (("safety",), KeyError, r"safety: missing"),
    (("limits", "v1_max_mps"), "fast", r"limits\.v1_max_mps: expected a number"),
]


@pytest.mark.parametrize("path, value, match", BAD, ids=[".".join(map(str, b[0])) + f"={b[1]!r}" for b in BAD])
def test_malformed_config_names_key(path, value, match):
    with pytest.raises(ConfigError, match=match):
        parse_robot_config(_mutate(path, value), "robot.yaml")


def test_not_a_mapping():
    with pytest.raises(ConfigError, match="top level"):
        parse_robot_config([1, 2], "robot.yaml")


def test_bad_yaml_and_missing_file(tmp_path):
    p = tmp_path / "robot.yaml"
    p.write_text("wheels: [unclosed\n")
    with pytest.raises(ConfigError, match="not valid YAML"):
        load_robot_config(p)
    with pytest.raises(ConfigError, match="cannot read robot config"):
        load_robot_config(tmp_path / "missing.yaml")


def test_watchdog_and_limits_are_si():
    cfg = load_robot_config()
    assert math.isclose(cfg.bus_watchdog_s, 0.1)
    assert cfg.steer_angle_max_rad == pytest.approx(math.pi / 2, abs=1e-4)
