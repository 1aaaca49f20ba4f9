"""configs/emulator.yaml loader."""
import copy
from pathlib import Path

import pytest
import yaml

from swerve.driver.errors import ConfigError
from swerve.emulator.physics.params import load_config, parse_config

ROOT = Path(__file__).resolve().parents[3]
DOC = yaml.safe_load((ROOT / "configs" / "emulator.yaml").read_text())


def test_shipped_config_loads_table_1(cfg):
    assert cfg.drive_motor.resistance_ohm == 9.24 and cfg.steering_motor.inertia_kg_m2 == 6e-8
    assert cfg.gear_ratio("XH430-W210") == 212.6 and cfg.rate_hz >= 1000
    assert cfg.firmware.bessel_cutoff_radps == 32.8 and cfg.body.total_mass_kg == 4.75


def _broken(path, value):
    doc = copy.deepcopy(DOC)
    *parents, leaf = path
    node = doc
    for key in parents:
        node = node[key]
    if value is KeyError:
        del node[leaf]
    else:
        node[leaf] = value
    return doc


@pytest.mark.parametrize("path, value, match", [
    (("motors", "drive", "resistance_ohm"), KeyError, r"motors\.drive\.resistance_ohm: missing"),
    (("motors", "steering", "inductance_h"), -1.0, r"motors\.steering\.inductance_h"),
    (("physics", "rate_hz"), 500, r"physics\.rate_hz: 500 is outside \[1000, "),
    (("bessel", "placement"), "output", r"bessel\.placement"),
    (("body", "load_enabled"), "yes", r"body\.load_enabled"),
    (("paper_spec_gains", "velocity_p_gain"), 1.5, r"paper_spec_gains\.velocity_p_gain"),
    (("gear_ratios", "xh430-w210"), "fast", r"gear_ratios\.xh430-w210"),
], ids=["missing", "negative", "slow-rate", "placement", "bool", "gain", "gear"])
def test_malformed_config_names_the_key(path, value, match):
    with pytest.raises(ConfigError, match=match):
        parse_config(_broken(path, value))


def test_unknown_model_and_missing_file(cfg, tmp_path):
    with pytest.raises(ConfigError, match="xm999"):
        cfg.gear_ratio("xm999")
    with pytest.raises(ConfigError, match="cannot read"):
        load_config(tmp_path / "nope.yaml")
