"""``swerve doctor`` against the emulator: a misplaced servo, a latched fault, settings, timing."""
from __future__ import annotations

import json

import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.robot_config import DEFAULT_PATH, load_robot_config
from swerve.emulator.factory import build_emulator
from swerve.emulator.timing import Frozen
from swerve.tools import doctor
from swerve.tools.cli import main

MARGIN_S = 0.2      # the emulator is a Python thread on a shared machine
BAUDS = (57_600, 1_000_000)
#: The CLI tests' reply slack, a hang guard: the emulated bus paces replies on this shared machine's
#: wall clock, and a reply that comes is never waited for longer (500 ms was missed under a load of 9
#: on 2 cores).
SLACK = ("--timeout-margin-ms", "5000")


@pytest.fixture
def cfg():
    return load_robot_config(DEFAULT_PATH)


@pytest.fixture
def emu():
    with build_emulator(load_robot_config(DEFAULT_PATH), timing=Frozen()) as e:
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


@pytest.mark.slow
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


def test_settings_run_writes_pass_as_what_run_sets_and_fix_writes_them(emu, cfg):
    report = doctor.diagnose(cfg, emu.port, margin_s=MARGIN_S, cycles=5)
    ee = _by_name(report)["EEPROM settings"]
    assert ee.status == doctor.PASS       # factory: position mode everywhere, return delay 500 us
    assert ee.detail.startswith("swerve run sets them before it moves")
    assert "operating_mode 3 -> 1 on ID 1,2,3,4" in ee.detail
    assert "return_delay_time 250 -> 0 on ID 1,2,3,4,5,6,7,8" in ee.detail
    assert report.exit_code == doctor.EXIT_OK
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
    timer = doctor.SysfsLatencyTimer(str(dev), sysfs_root=str(sysfs))
    check, done = doctor.check_latency(timer)
    assert check.status == doctor.WARN and "16 ms" in check.detail
    assert "echo 1 | sudo tee" in check.fix and doctor.UDEV_RULE in check.fix
    check, done = doctor.check_latency(timer, fix=True)
    assert check.status == doctor.PASS and done
    assert (sysfs / "ttyUSB7" / "latency_timer").read_text().strip() == "1"


def test_wire_limit_counts_the_bytes_of_one_cycle(cfg):
    # Sync Read request (14 + 8 IDs = 22 bytes), 8 replies of 11 + 10 bytes, Bulk Write of
    # 4 x (5 + 4) for velocity and 4 x (5 + 4) for position + 10 bytes header/CRC = 82 bytes.
    assert doctor.wire_time_s(cfg, 1_000_000) == pytest.approx((22 + 168 + 82) * 10 / 1e6)


def test_cli_exit_0_on_a_fresh_emulated_robot_and_json(capsys):
    """Factory settings that swerve run writes itself do not fail the check."""
    assert main(["doctor", "--emulate", "--cycles", "5", "--json", *SLACK]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["ok"] is True and doc["exit_code"] == 0
    # every check passes but the timed cycle, which is timed on this (shared) machine's wall clock
    assert {c["status"] for c in doc["checks"] if c["name"] != "read/write cycle"} == {"pass"}
    assert {c["name"] for c in doc["checks"]} >= {"latency timer", "servos present", "gains"}
    latency = next(c for c in doc["checks"] if c["name"] == "latency timer")
    assert latency["detail"] == "emulated U2D2: 1 ms"          # the shipped robot file's adapter


def test_cli_exit_0_with_warnings_names_the_16_ms_adapter_and_its_fix(capsys):
    assert main(["doctor", "--emulate", "--cycles", "3", "--adapter-latency-ms", "16", *SLACK]) == 0
    out = capsys.readouterr().out
    assert "[warn] latency timer: emulated U2D2: 16 ms" in out
    assert "--adapter-latency-ms 1" in out and "latency_timer" in out
    assert out.strip().splitlines()[-1].startswith("no check failed;")


def test_cli_fix_sets_the_emulated_adapter_to_1_ms(capsys):
    assert main(["doctor", "--emulate", "--cycles", "3", "--adapter-latency-ms", "16", "--fix", "--json",
                 *SLACK]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "set the latency timer of emulated U2D2 to 1 ms (until the adapter is replugged)" in doc["fixed"]
    assert next(c for c in doc["checks"] if c["name"] == "latency timer")["status"] == "pass"


def test_cli_exit_1_when_a_check_fails(capsys):
    with build_emulator(load_robot_config(DEFAULT_PATH), timing=Frozen()) as emu:
        emu.faults.raise_hardware_error(2, "overload")
        code = main(["doctor", "--port", emu.port, "--cycles", "3", "--timeout-margin-ms", "200"])
    out = capsys.readouterr().out
    assert code == doctor.EXIT_FAILED == 1
    assert "[fail] hardware errors: ID 2: 0x20 (overload: a persistent load" in out
    assert out.strip().splitlines()[-1] == "2 check(s) failed: hardware errors, read/write cycle"


@pytest.mark.parametrize("value", ["0", "-1", "256", "nan", "1.5", "inf", "x"])
def test_adapter_latency_option_refuses_bad_values_in_one_line(value, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["doctor", "--emulate", "--adapter-latency-ms", value])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--adapter-latency-ms: must be an integer >= 1 and <= 255" in err


def test_report_verdict_and_exit_code_follow_the_worst_status():
    report = doctor.DoctorReport("p", [doctor.Check("a", doctor.PASS, "")])
    assert (report.ok, report.exit_code, report.verdict()) == (True, 0, "all checks pass")
    report.checks.append(doctor.Check("b", doctor.WARN, ""))
    assert (report.ok, report.exit_code) == (True, 0)
    report.checks.append(doctor.Check("c", doctor.FAIL, ""))
    assert (report.ok, report.exit_code, report.verdict()) == (False, 1, "1 check(s) failed: c")
