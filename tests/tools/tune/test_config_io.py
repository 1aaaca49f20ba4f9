"""--write-config edits only the gains line of a copy of the robot config."""
import shutil
from pathlib import Path

import pytest

from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import load_robot_config
from swerve.tools.tune.config_io import update_gains_text, write_gains

ROBOT = Path("configs/robot.yaml")


def test_only_the_gains_line_changes(tmp_path):
    path = tmp_path / "robot.yaml"
    shutil.copy(ROBOT, path)
    before = path.read_text().splitlines()
    write_gains(path, "drive", {"velocity_p_gain": 200, "velocity_i_gain": 4214})
    after = path.read_text().splitlines()
    changed = [(a, b) for a, b in zip(before, after) if a != b]
    assert len(before) == len(after) and len(changed) == 1
    assert "# control-table units" in changed[0][1]
    cfg = load_robot_config(path)
    assert dict(cfg.drive.gains) == {"velocity_p_gain": 200, "velocity_i_gain": 4214}
    assert dict(cfg.steering.gains) == dict(load_robot_config(ROBOT).steering.gains)


def test_steering_gains_merge_with_existing(tmp_path):
    text = update_gains_text(ROBOT.read_text(), "steering", {"position_p_gain": 1301})
    assert "gains: {position_p_gain: 1301, position_i_gain: 0, position_d_gain: 0}" in text


def test_out_of_range_gain_leaves_the_file_alone(tmp_path):
    path = tmp_path / "robot.yaml"
    shutil.copy(ROBOT, path)
    with pytest.raises(ConfigError):
        write_gains(path, "drive", {"velocity_p_gain": 99999})
    assert path.read_text() == ROBOT.read_text()


def test_missing_block_is_reported():
    with pytest.raises(ConfigError, match="no top-level 'drive:' block"):
        update_gains_text("name: x\n", "drive", {"velocity_p_gain": 1})
