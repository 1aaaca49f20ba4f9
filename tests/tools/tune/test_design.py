"""Gain design on the emulator's servo model with Table 1 parameters."""
import math

import numpy as np
import pytest

from swerve.emulator.physics.params import load_config
from swerve.tools.tune.gain_search import (DesignError, Plant, Spec, design_position, design_velocity,
                               predict_velocity)


@pytest.fixture(scope="module")
def cfg():
    return load_config("configs/emulator.yaml")


def test_velocity_design_meets_the_default_spec(cfg):
    plant = Plant(cfg.drive_motor, 212.6, cfg.supply_voltage_v, cfg.firmware)
    d = design_velocity(plant, Spec(), p_grid=(100, 200, 300))
    assert set(d.gains) == {"velocity_p_gain", "velocity_i_gain"}
    assert 0 < d.velocity.true.overshoot_pct <= 2.0
    assert d.velocity.reported.overshoot_pct <= 2.0
    # faster than the e-Manual defaults on the same model
    default = predict_velocity(plant, {"velocity_p_gain": 100, "velocity_i_gain": 1920}, Spec().velocity_step_radps)
    assert d.velocity.true.settle_s < default.true.settle_s


def test_position_design_does_not_overshoot(cfg):
    plant = Plant(cfg.steering_motor, 212.6, cfg.supply_voltage_v, cfg.firmware)
    spec = Spec()
    d = design_position(plant, spec)
    assert d.gains["position_i_gain"] == d.gains["position_d_gain"] == 0
    assert np.max(d.position.y_true - spec.position_step_rad) <= spec.position_overshoot_max_rad
    assert d.position.reported.overshoot_pct == 0.0
    assert math.isfinite(d.position.true.settle_s)


def test_unreachable_velocity_settle_is_a_clear_error(cfg):
    plant = Plant(cfg.drive_motor, 212.6, cfg.supply_voltage_v, cfg.firmware)
    with pytest.raises(DesignError, match=r"no velocity gains meet the spec .*settle <= 5 ms.*fastest found"):
        design_velocity(plant, Spec(velocity_settle_max_s=0.005), p_grid=(100, 200))


def test_unreachable_position_settle_is_a_clear_error(cfg):
    plant = Plant(cfg.steering_motor, 212.6, cfg.supply_voltage_v, cfg.firmware)
    with pytest.raises(DesignError, match="no Position P gain meets the spec"):
        design_position(plant, Spec(position_settle_max_s=0.01))


@pytest.mark.parametrize("kw", [{"velocity_overshoot_max": 0.0}, {"velocity_overshoot_max": 1.5},
                                {"margin": 0.0}], ids=["zero", "over-one", "margin"])
def test_impossible_spec_values_are_refused(kw):
    with pytest.raises(DesignError):
        Spec(**kw)
