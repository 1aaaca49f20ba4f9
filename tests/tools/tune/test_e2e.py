"""``swerve tune`` end to end on the emulator: experiments over the pty through driver.bus.Bus,
identification, design and verification; bad input leaves the torque off. The emulator runs in
lockstep (it owns time), so every run samples at the same robot instants and the verdicts do
not depend on the host's speed."""
import contextlib
import json
import math
import shutil
from pathlib import Path

import pytest
import yaml

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.physics.params import load_config
from swerve.tools import cli
from swerve.tools.tune.command import TUNE_LOCKSTEP_TIMEOUT_MARGIN_S
from swerve.tools.run.lockstep import LockstepLoopClock
from swerve.tools.tune.gain_search import DesignError, Spec
from swerve.emulator.timing import Lockstep
from swerve.tools.tune.emulated import make_emulator
from swerve.tools.tune.experiments import Limits, NotMovingError, StallError
from swerve.tools.tune.pipeline import tune_servo

pytestmark = pytest.mark.slow
ROBOT, EMULATOR = Path("configs/robot.yaml"), Path("configs/emulator.yaml")
FITTED = ("resistance_ohm", "back_emf_v_s_per_rad", "inertia_kg_m2", "friction_nm_s_per_rad")


def _tune(tmp_path, *extra):
    out = tmp_path / "out"
    code = cli.main(["tune", "--emulate", "--noise", "--seed", "7", "--out", str(out), "--no-progress", *extra])
    return code, out


def test_drive_servo_recovers_table1_and_meets_the_spec(tmp_path, capsys):
    robot = tmp_path / "robot.yaml"
    shutil.copy(ROBOT, robot)
    code, out = _tune(tmp_path, "--id", "1", "--config", str(robot), "--write-config")
    assert code == 0, capsys.readouterr().err
    res = json.loads((out / "tune_1.json").read_text())
    truth = load_config(EMULATOR).drive_motor
    for name in FITTED:
        p = res["identification"]["parameters"][name]
        assert p["value"] == pytest.approx(getattr(truth, name), rel=0.05), name
        assert p["identified"]
    for name in ("inductance_h", "torque_nm_per_a"):
        assert not res["identification"]["parameters"][name]["identified"]
    assert res["meets_spec"]
    assert res["steps"]["after"]["measured"]["overshoot_pct"] <= 2.0 + 1.0    # + 1 LSB of 100 units
    assert (out / "pwm_1.png").stat().st_size > 0 and (out / "step_1.png").stat().st_size > 0
    assert yaml.safe_load((out / "tune_1.yaml").read_text())["gains"] == res["gains"]
    assert dict(load_robot_config(robot).drive.gains) == res["gains"]


def test_thirty_percent_more_inertia_is_identified(tmp_path, capsys):
    doc = yaml.safe_load(EMULATOR.read_text())
    j0 = doc["motors"]["steering"]["inertia_kg_m2"]
    doc["motors"]["steering"]["inertia_kg_m2"] = 1.3 * j0
    heavy = tmp_path / "emulator.yaml"
    heavy.write_text(yaml.safe_dump(doc))
    code, out = _tune(tmp_path, "--id", "5", "--emulator-config", str(heavy))
    assert code == 0, capsys.readouterr().err
    res = json.loads((out / "tune_5.json").read_text())
    j = res["identification"]["parameters"]["inertia_kg_m2"]
    assert j["value"] == pytest.approx(1.3 * j0, rel=0.05)
    assert j["ci_low"] > 1.15 * j0                     # clearly not the Table 1 value
    assert res["meets_spec"]


def test_missing_id_is_one_clear_line(tmp_path, capsys):
    code, _ = _tune(tmp_path, "--id", "9", "--mode", "drive")
    assert code == 2
    assert "servo ID 9 does not answer" in capsys.readouterr().err


@pytest.fixture
def rc():
    return load_robot_config(ROBOT)


@contextlib.contextmanager
def _session(rc, cfg, **kw):
    """``(emulator, bus, clock)``: the emulator in lockstep and a bus on it; tuning with ``clock``
    runs on robot time, the same on a busy or an idle host."""
    with make_emulator(rc, cfg, timing=Lockstep(), **kw) as emu, LockstepLoopClock(emu.control.path) as clock, \
            Bus(emu.port, emu.baud, retries=3, timeout_margin_s=TUNE_LOCKSTEP_TIMEOUT_MARGIN_S) as bus:
        clock.attach(bus)
        yield emu, bus, clock


def test_servo_that_does_not_move_leaves_torque_off(rc):
    with _session(rc, None) as (emu, bus, clock):     # no physics: a dead motor
        mode = emu.servo(1).read("operating_mode")
        with pytest.raises(NotMovingError, match="servo ID 1 did not move"):
            tune_servo(bus, 1, "drive", Spec(), load_config(EMULATOR).drive_motor,
                       limits=Limits(speed_max_radps=rc.drive_max_radps), clock=clock)
        assert emu.servo(1).read("torque_enable") == 0
        assert emu.servo(1).read("operating_mode") == mode       # put back


def test_stall_is_detected_and_torque_left_off(rc):
    cfg = load_config(EMULATOR)
    with _session(rc, cfg) as (emu, bus, clock):
        emu.servo(1).dynamics.model.external_load(0.0, 10.0)         # a blocked wheel: huge load inertia
        with pytest.raises(StallError, match="servo ID 1 stalled"):
            tune_servo(bus, 1, "drive", Spec(), cfg.drive_motor, limits=Limits(speed_max_radps=rc.drive_max_radps),
                       clock=clock)
        assert emu.servo(1).read("torque_enable") == 0


def test_unreachable_spec_keeps_original_gains_and_torque_off(rc):
    cfg = load_config(EMULATOR)
    with _session(rc, cfg, noise=True, seed=1) as (emu, bus, clock):
        before = {g: emu.servo(1).read(g) for g in ("velocity_p_gain", "velocity_i_gain")}
        with pytest.raises(DesignError, match="no velocity gains meet the spec.*torque is off"):
            tune_servo(bus, 1, "drive", Spec(velocity_settle_max_s=0.005), cfg.drive_motor,
                       limits=Limits(speed_max_radps=rc.drive_max_radps), clock=clock)
        assert emu.servo(1).read("torque_enable") == 0
        assert {g: emu.servo(1).read(g) for g in before} == before
        assert bus.read(1, Reg.BUS_WATCHDOG) == 0


def test_range_limit_stops_the_experiment(rc):
    cfg = load_config(EMULATOR)
    center = 2048 * 2 * math.pi / 4096
    with _session(rc, cfg) as (emu, bus, clock):
        with pytest.raises(Exception, match="safe range|no room"):
            tune_servo(bus, 5, "steering", Spec(), cfg.steering_motor, center_rad=center,
                       limits=Limits(position_min_rad=center - 0.01, position_max_rad=center + 0.01), clock=clock)
        assert emu.servo(5).read("torque_enable") == 0


def test_gains_failing_verification_are_not_kept(rc, monkeypatch):
    import swerve.tools.tune.pipeline as pipeline

    monkeypatch.setattr(pipeline, "check_spec", lambda *a, **k: (False, ["forced failure"]))
    cfg = load_config(EMULATOR)
    center = 2048 * 2 * math.pi / 4096
    with _session(rc, cfg, noise=True, seed=2) as (emu, bus, clock):
        before = emu.servo(5).read("position_p_gain")
        res = tune_servo(bus, 5, "steering", Spec(), cfg.steering_motor, center_rad=center,
                         limits=Limits(position_min_rad=center - 1.5, position_max_rad=center + 1.5), clock=clock)
        assert not res.meets_spec and res.design.gains["position_p_gain"] != before
        assert emu.servo(5).read("position_p_gain") == before
        assert emu.servo(5).read("torque_enable") == 0


def test_leaving_the_range_mid_experiment_turns_the_torque_off(rc):
    from dataclasses import replace

    cfg = load_config(EMULATOR)
    center = 2048 * 2 * math.pi / 4096
    slow_prior = replace(cfg.steering_motor, back_emf_v_s_per_rad=3 * cfg.steering_motor.back_emf_v_s_per_rad)
    with _session(rc, cfg) as (emu, bus, clock):   # the motor is 3x faster than the prior says
        with pytest.raises(Exception, match="servo ID 5 left its safe range.*torque turned off"):
            tune_servo(bus, 5, "steering", Spec(), slow_prior, center_rad=center,
                       limits=Limits(position_min_rad=center - 0.45, position_max_rad=center + 0.45), clock=clock)
        assert emu.servo(5).read("torque_enable") == 0
        assert abs(emu.servo(5).read("present_position") - 2048) < 0.6 / (2 * math.pi / 4096)


def test_robot_emulator_path_sees_the_reflected_wheel_load(tmp_path, capsys):
    """Smoke test of ``--emulator robot``: the drive shaft carries the robot's mass, so J is the
    rotor's plus m r^2 / N^2 per wheel (README: a few % timing bias at 2 kHz physics)."""
    code, out = _tune(tmp_path, "--id", "1", "--emulator", "robot")
    assert code == 0, capsys.readouterr().err
    res = json.loads((out / "tune_1.json").read_text())
    cfg, rc = load_config(EMULATOR), load_robot_config(ROBOT)
    loaded = cfg.drive_motor.inertia_kg_m2 + (cfg.body.total_mass_kg / 4 * rc.wheel_radius_m ** 2
                                              / cfg.gear_ratio(rc.model) ** 2)
    assert res["identification"]["parameters"]["inertia_kg_m2"]["value"] == pytest.approx(loaded, rel=0.1)
    assert res["meets_spec"]


def test_realistic_gearbox_friction_is_identified_as_coulomb(tmp_path, capsys):
    """``--emulator-config realistic``: Coulomb + Stribeck friction on the output shaft. The fit
    puts it into Tc (between the Coulomb and the static torque), R, Ke and J stay at Table 1."""
    code, out = _tune(tmp_path, "--id", "5", "--emulator-config", "realistic")
    assert code == 0, capsys.readouterr().err
    res = json.loads((out / "tune_5.json").read_text())
    cfg = load_config(Path("configs/emulator-realistic.yaml"))
    truth, fr = cfg.steering_motor, cfg.steering_friction
    est = res["identification"]["parameters"]
    for name in FITTED[:3]:
        assert est[name]["value"] == pytest.approx(getattr(truth, name), rel=0.05), name
    assert 0.65 < est["friction_nm_s_per_rad"]["value"] / truth.friction_nm_s_per_rad < 1.0
    assert fr.coulomb_nm < est["coulomb_nm"]["value"] < fr.static_nm + 0.003
    assert res["identification"]["residual_rms"]["position_pulse"] < 0.8
    assert res["meets_spec"]


def test_two_lockstep_runs_print_the_same_json(tmp_path, capsys):
    """``--json``: the identified parameters and designed gains, the same bits every run."""
    printed = []
    for run in ("a", "b"):
        code = cli.main(["tune", "--emulate", "--id", "1", "--json", "--no-progress", "--out", str(tmp_path / run)])
        assert code == 0
        printed.append(capsys.readouterr().out)
    assert printed[0] == printed[1]
    doc = json.loads(printed[0])
    assert doc["meets_spec"] and set(doc["gains"]) == {"velocity_p_gain", "velocity_i_gain"}
    truth = load_config(EMULATOR).drive_motor
    assert doc["parameters"]["resistance_ohm"]["value"] == pytest.approx(truth.resistance_ohm, rel=0.05)
