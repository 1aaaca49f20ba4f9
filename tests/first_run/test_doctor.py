"""``swerve doctor`` against the emulator: a misplaced servo, a latched fault, settings, timing."""
from __future__ import annotations

import json

import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import DEFAULT_PATH, load_robot_config
from swerve.emulator.robot_emulator import build_emulator
from swerve.tools import doctor
from swerve.tools.cli import main

MARGIN_S = 0.2      # the emulator is a Python thread on a shared machine
BAUDS = (57_600, 1_000_000)


@pytest.fixture
def cfg():
    return load_robot_config(DEFAULT_PATH)


@pytest.fixture
def emu():
    with build_emulator(load_robot_config(DEFAULT_PATH), time_scale=0) as e:
        yield e


def _by_name(report):
    return {c.name: c for c in report.checks}


def _factory_servo(port: str, id_: int) -> None:
    """Make servo ``id_`` look new from the box: ID 1 at 57600 bps (through the protocol)."""
    with Bus(port, 1_000_000, timeout_margin_s=MARGIN_S) as bus:
        bus.write(id_, Reg.BAUD_RATE, 1)
    with Bus(port, 57_600, timeout_margin_s=MARGIN_S) as bus:
        bus.write(id_, Reg.ID, 1)
        assert bus.ping(1).model_number == 1010


def test_missing_servo_is_found_at_factory_baud_and_moved(emu, cfg):
    _factory_servo(emu.port, 7)
    report = doctor.diagnose(cfg, emu.port, margin_s=MARGIN_S, cycles=5, scan_bauds=BAUDS)
    present = _by_name(report)["servos present"]
    assert present.status == doctor.FAIL
    assert "IDs 7 do not answer at 1000000 bps" in present.detail
    assert "ID 1 (XH430-W210) at 57600 bps" in present.detail
    assert "ID 1 at 57600 bps -> ID 7 at 1000000 bps" in present.fix
    assert not report.ok

    fixed = doctor.diagnose(cfg, emu.port, fix=True, margin_s=MARGIN_S, cycles=5, scan_bauds=BAUDS)
    assert _by_name(fixed)["servos present"].status == doctor.PASS
    assert any("to ID 7, 1000000 bps" in f for f in fixed.fixed)
    assert fixed.ok, [c.line() for c in fixed.checks]
    assert emu.servo(7).baud_bps == 1_000_000
    again = doctor.diagnose(cfg, emu.port, margin_s=MARGIN_S, cycles=5, scan_bauds=BAUDS)
    assert again.ok and not again.fixed


def test_latched_hardware_error_is_explained_and_cleared_by_reboot(emu, cfg):
    emu.faults.raise_hardware_error(3, "overload+overheating")
    report = doctor.diagnose(cfg, emu.port, margin_s=MARGIN_S, cycles=5)
    hw = _by_name(report)["hardware errors"]
    assert hw.status == doctor.FAIL
    assert "ID 3: 0x24" in hw.detail
    assert "persistent load" in hw.detail and "Temperature Limit" in hw.detail
    fixed = doctor.diagnose(cfg, emu.port, fix=True, margin_s=MARGIN_S, cycles=5)
    assert _by_name(fixed)["hardware errors"].status == doctor.PASS
    assert "rebooted ID 3 to clear overheating, overload" in fixed.fixed


def test_settings_differing_from_file_warn_and_fix_writes_them(emu, cfg):
    report = doctor.diagnose(cfg, emu.port, margin_s=MARGIN_S, cycles=5)
    ee = _by_name(report)["EEPROM settings"]
    assert ee.status == doctor.WARN       # factory: position mode everywhere, return delay 500 us
    assert "operating_mode 3 on ID 1,2,3,4 (file: 1)" in ee.detail
    with Bus(emu.port, 1_000_000, timeout_margin_s=MARGIN_S) as bus:
        bus.write(5, Reg.POSITION_P_GAIN, 700)
    gains = _by_name(doctor.diagnose(cfg, emu.port, margin_s=MARGIN_S, cycles=5))["gains"]
    assert gains.status == doctor.WARN and "position_p_gain 700 on ID 5 (file: 1310)" in gains.detail
    fixed = doctor.diagnose(cfg, emu.port, fix=True, margin_s=MARGIN_S, cycles=5)
    assert fixed.ok, [c.line() for c in fixed.checks]
    with Bus(emu.port, 1_000_000, timeout_margin_s=MARGIN_S) as bus:
        assert bus.read(5, Reg.POSITION_P_GAIN) == 1310
        assert bus.read(1, Reg.OPERATING_MODE) == 1


def test_latency_timer_above_one_ms_warns_with_command_and_udev_rule(tmp_path):
    dev = tmp_path / "ttyUSB7"
    dev.write_text("")
    sysfs = tmp_path / "sys"
    (sysfs / "ttyUSB7").mkdir(parents=True)
    (sysfs / "ttyUSB7" / "latency_timer").write_text("16\n")
    check, done = doctor.check_latency(str(dev), sysfs_root=str(sysfs))
    assert check.status == doctor.WARN and "16 ms" in check.detail
    assert "echo 1 | sudo tee" in check.fix and doctor.UDEV_RULE in check.fix
    check, done = doctor.check_latency(str(dev), fix=True, sysfs_root=str(sysfs))
    assert check.status == doctor.PASS and done
    assert (sysfs / "ttyUSB7" / "latency_timer").read_text().strip() == "1"


def test_wire_limit_counts_the_bytes_of_one_cycle(cfg):
    # Sync Read request (14 + 8 IDs = 22 bytes), 8 replies of 11 + 10 bytes, Bulk Write of
    # 4 x (5 + 4) for velocity and 4 x (5 + 4) for position + 10 bytes header/CRC = 82 bytes.
    assert doctor.wire_time_s(cfg, 1_000_000) == pytest.approx((22 + 168 + 82) * 10 / 1e6)


def test_cli_exit_status_and_json(capsys):
    assert main(["doctor", "--emulate", "--cycles", "5", "--json"]) == 1      # factory settings warn
    doc = json.loads(capsys.readouterr().out)
    assert doc["ok"] is False and {c["name"] for c in doc["checks"]} >= {"servos present", "gains"}
    assert main(["doctor", "--emulate", "--cycles", "5", "--fix"]) == 0
    assert "all checks pass" in capsys.readouterr().out
