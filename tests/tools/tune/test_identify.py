"""Identification on data simulated with the emulator's ServoModel (noise, quantisation, jitter)."""
from dataclasses import replace

import numpy as np
import pytest

from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import MotorParams, load_config
from swerve.tools.tune.identify import FITTED, identify, simulate_open_loop

from .simdata import NOISE, PLAN, pwm_record

GEAR = 212.6
PRIOR = MotorParams(resistance_ohm=8.0, inductance_h=3e-3, back_emf_v_s_per_rad=0.012,
                    torque_nm_per_a=0.0067, friction_nm_s_per_rad=3e-7, inertia_kg_m2=9e-8)
LSB = dict(position_lsb_rad=u.RAD_PER_PULSE, current_lsb_a=u.AMP_PER_CURRENT_UNIT)


@pytest.fixture(scope="module")
def table1():
    return load_config("configs/emulator.yaml")


@pytest.mark.parametrize("variant", ["drive", "steering"])
def test_recovers_table1_within_5_percent_with_noise(table1, variant):
    truth = getattr(table1, f"{variant}_motor")
    rec = pwm_record(truth, GEAR, PLAN, seed=1)
    ident = identify([rec], GEAR, PRIOR, **LSB)
    for name in FITTED:
        est = ident.estimates[name]
        assert est.identified
        assert est.value == pytest.approx(getattr(truth, name), rel=0.05), name
        assert est.ci_low < est.value < est.ci_high
    assert not ident.estimates["inductance_h"].identified
    assert not ident.estimates["torque_nm_per_a"].identified
    assert ident.residual_rms["position_pulse"] < 1.5
    assert ident.extra["reduced_chi2"] == pytest.approx(1.0, abs=0.5)


def test_thirty_percent_more_inertia_is_seen(table1):
    base = table1.steering_motor
    heavy = replace(base, inertia_kg_m2=1.3 * base.inertia_kg_m2)
    j = [identify([pwm_record(p, GEAR, PLAN, seed=2)], GEAR, PRIOR, **LSB).params.inertia_kg_m2
         for p in (base, heavy)]
    assert j[1] / j[0] == pytest.approx(1.3, rel=0.05)


def test_exact_solution_matches_the_emulator_motor_without_noise(table1):
    from swerve.emulator.physics.params import SensorParams
    p = table1.drive_motor
    rec = pwm_record(p, GEAR, PLAN, sensors=SensorParams(), dt_s=5e-5)
    sim = simulate_open_loop(p, GEAR, rec.t_s, rec.switch_t_s, rec.voltage_v)
    assert np.max(np.abs(sim["current_a"] - rec.current_a)) < 2 * u.AMP_PER_CURRENT_UNIT
    assert np.max(np.abs(sim["angle_rad"] - rec.position_rad)) < 2 * u.RAD_PER_PULSE


def test_a_record_without_rest_samples_is_refused(table1):
    rec = pwm_record(table1.drive_motor, GEAR, PLAN)
    bad = replace(rec, switch_t_s=rec.switch_t_s - 1.0)
    with pytest.raises(ValueError, match="rest samples"):
        identify([bad], GEAR, PRIOR, **LSB)


@pytest.mark.parametrize("error_s", [0.02, 0.08, -0.05], ids=["20ms-late", "80ms-late", "50ms-early"])
def test_a_mistimed_write_is_relocated_from_the_current_jump(table1, error_s):
    truth = table1.steering_motor
    rec = pwm_record(truth, GEAR, PLAN, seed=3)
    logged = rec.switch_t_s.copy()
    logged[2] += error_s                      # a late or retried reply put this write elsewhere
    bad = replace(rec, switch_t_s=logged, switch_std_s=np.full(logged.shape, 1e-3))
    ident = identify([bad], GEAR, PRIOR, **LSB)
    for name in FITTED:
        assert ident.estimates[name].value == pytest.approx(getattr(truth, name), rel=0.05), name
    assert ident.switch_t_s[0][2] == pytest.approx(rec.switch_t_s[2], abs=2e-3)


# ---- gearbox friction (the realistic profile) --------------------------------------------------
#: The pipeline's open-loop plan at 50 % duty: +-442 and +-265 PWM counts with braking between.
PLAN4 = [(0.05, 0), (0.2, 442), (0.08, 0), (0.2, -442), (0.08, 0), (0.2, 265), (0.08, 0), (0.2, -265), (0.1, 0)]


@pytest.fixture(scope="module")
def realistic():
    return load_config("configs/emulator-realistic.yaml")


def _coulomb_only(friction):
    return replace(friction, static_nm=friction.coulomb_nm)          # no Stribeck rise at rest


def test_exact_solution_with_coulomb_friction_matches_the_emulator_motor(realistic):
    from swerve.emulator.physics.params import SensorParams
    p, fr = realistic.drive_motor, _coulomb_only(realistic.drive_friction)
    rec = pwm_record(p, GEAR, PLAN, sensors=SensorParams(), dt_s=5e-5, friction=fr)
    sim = simulate_open_loop(p, GEAR, rec.t_s, rec.switch_t_s, rec.voltage_v, fr.coulomb_nm)
    settled = np.min(np.abs(rec.t_s[:, None] - rec.switch_t_s[None, :]), axis=1) > 2e-3
    assert np.max(np.abs(sim["current_a"] - rec.current_a)[settled]) < 2 * u.AMP_PER_CURRENT_UNIT
    assert np.max(np.abs(sim["angle_rad"] - rec.position_rad)) < 2 * u.RAD_PER_PULSE
    brake = (rec.t_s > 0.28) & (rec.t_s < 0.3)                     # late in the first brake: stopped
    assert np.all(sim["speed_radps"][brake] == 0.0)


@pytest.mark.parametrize("seed", [1, 2])
@pytest.mark.parametrize("variant", ["drive", "steering"])
def test_coulomb_friction_is_identified_without_bias(realistic, variant, seed):
    truth, fr = getattr(realistic, f"{variant}_motor"), _coulomb_only(getattr(realistic, f"{variant}_friction"))
    rec = pwm_record(truth, GEAR, PLAN4, seed=seed, friction=fr)
    viscous = identify([rec], GEAR, PRIOR, **LSB, coulomb=False)
    assert viscous.params.friction_nm_s_per_rad > 1.5 * truth.friction_nm_s_per_rad   # the bias it removes
    ident = identify([rec], GEAR, PRIOR, **LSB)
    for name in ("resistance_ohm", "back_emf_v_s_per_rad", "inertia_kg_m2"):
        assert ident.estimates[name].value == pytest.approx(getattr(truth, name), rel=0.03), name
    assert ident.params.friction_nm_s_per_rad == pytest.approx(truth.friction_nm_s_per_rad, rel=0.10)
    assert ident.coulomb_nm == pytest.approx(fr.coulomb_nm, rel=0.10)
    assert ident.residual_rms["position_pulse"] < 0.7 < viscous.residual_rms["position_pulse"]


@pytest.mark.parametrize("variant", ["drive", "steering"])
def test_realistic_gearbox_friction_bias_is_bounded(realistic, variant):
    """Coulomb + Stribeck + viscous on the output (the realistic profile): the fitted ``Tc`` lies
    between the Coulomb and the static torque and ``b`` absorbs the Stribeck slope (low by < 30 %)."""
    truth, fr = getattr(realistic, f"{variant}_motor"), getattr(realistic, f"{variant}_friction")
    rec = pwm_record(truth, GEAR, PLAN4, seed=1, friction=fr)
    viscous = identify([rec], GEAR, PRIOR, **LSB, coulomb=False)
    assert viscous.params.friction_nm_s_per_rad > 1.5 * truth.friction_nm_s_per_rad
    ident = identify([rec], GEAR, PRIOR, **LSB)
    for name in ("resistance_ohm", "back_emf_v_s_per_rad", "inertia_kg_m2"):
        assert ident.estimates[name].value == pytest.approx(getattr(truth, name), rel=0.03), name
    assert 0.70 < ident.params.friction_nm_s_per_rad / truth.friction_nm_s_per_rad < 1.0
    assert fr.coulomb_nm < ident.coulomb_nm < fr.static_nm + 0.002
    assert ident.residual_rms["position_pulse"] < 0.7
    assert ident.residual_rms["current_a"] < 1.2 * NOISE.current_noise_std_a
