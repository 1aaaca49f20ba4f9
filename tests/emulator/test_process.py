"""The emulated robot in a child process: port, shared true pose, fault commands, final stats."""
import gc
import os
import subprocess
import sys
import time

import pytest

from swerve.driver.bus import Bus
from swerve.driver.errors import ConfigError, DxlTimeoutError, SwerveError
from swerve.emulator import process, spawn
from swerve.emulator.process import EmulatorProcess
from swerve.emulator.spawn import prestarted
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.server import freeze_startup_heap
from swerve.emulator.timing import Lockstep, WallTime


@pytest.mark.slow
def test_child_emulator_serves_the_bus_and_shares_the_pose():
    with EmulatorProcess("configs/robot.yaml", timing=WallTime(1.0), body=BodySettings(start_pose=(0.5, -0.25, 0.1))) as emu:
        with Bus(emu.port, 1_000_000, timeout_margin_s=0.3) as bus:
            found = bus.scan(range(1, 9))
            assert [p.id for p in found] == list(range(1, 9))
            assert {p.model for p in found} == {"XH430-W210"}
            t0 = emu.sim_time_s
            deadline = time.monotonic() + 10
            while emu.sim_time_s <= t0 and time.monotonic() < deadline:
                time.sleep(0.01)
            assert emu.sim_time_s > t0                    # the physics clock runs in the child
            assert emu.pose == pytest.approx((0.5, -0.25, 0.1))   # at rest where it was put
            emu.fault("vanish", 3)
            with pytest.raises(DxlTimeoutError) as info:
                bus.ping(3)
            assert info.value.ids == (3,)
            with pytest.raises(ConfigError, match="no_such_fault"):
                emu.fault("no_such_fault")
    assert emu.final_stats["bus"]["packets_received"] > 0
    assert emu.final_stats["clock"]["steps"] > 0


def test_bad_config_is_reported_from_the_child(tmp_path):
    bad = tmp_path / "robot.yaml"
    bad.write_text("geometry: 3\n")
    with pytest.raises(ConfigError, match="emulator"):
        EmulatorProcess(bad).start()


def test_bad_physics_config_is_reported_from_the_child(tmp_path):
    bad = tmp_path / "emulator.yaml"
    bad.write_text("rate_hz: 3\n")
    with pytest.raises(ConfigError, match="emulator"):
        EmulatorProcess(None, bad).start()


def test_emulator_process_freezes_its_start_up_heap():
    try:
        freeze_startup_heap()
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()


def test_closed_emulator_process_is_waited_for():
    emu = EmulatorProcess("configs/robot.yaml", timing=Lockstep()).start()
    pid = emu.pid
    emu.close()
    with pytest.raises(ChildProcessError):      # reaped: no longer our child, not even a zombie
        os.waitpid(pid, os.WNOHANG)


def test_a_prestarted_child_is_taken_by_the_first_launch_and_serves_its_request():
    with prestarted():
        first = EmulatorProcess("configs/robot.yaml", timing=Lockstep(),
                                body=BodySettings(start_pose=(0.5, -0.25, 0.1)))
        first.launch()
        second = EmulatorProcess("configs/robot.yaml", timing=Lockstep())
        second.launch()
        try:
            first.start()
            second.start()
            assert first.pid != second.pid
            with Bus(first.port, 1_000_000, timeout_margin_s=0.3) as bus:
                assert [p.id for p in bus.scan(range(1, 9))] == list(range(1, 9))
        finally:
            first.close()
            second.close()
    assert first.final_stats["bus"]["packets_received"] > 0     # the request it was sent built it
    assert first.final_stats["pose"] == pytest.approx([0.5, -0.25, 0.1])


def test_a_prestarted_child_no_launch_took_is_stopped_and_reaped():
    with prestarted():
        spare = spawn._prestarted
        pid = spare[0].pid
    assert spawn._prestarted is None
    assert spare[0].returncode is not None
    with pytest.raises(ChildProcessError):      # reaped: not even a zombie is left
        os.waitpid(pid, os.WNOHANG)


def test_a_prestarted_child_told_nothing_exits_quietly():
    """Its parent gone before sending a request (EOF), the child ends without output or error."""
    proc, conn, shared = spawn.spawn_child()
    conn.close()
    assert proc.wait(timeout=60) == 0
    shared.close()


#: Runs ``swerve run`` as a child subreaper (Linux ``PR_SET_CHILD_SUBREAPER``): any process the
#: command leaves behind, running or defunct, is re-parented to this script instead of init.
_SUBREAPER = """
import ctypes, os, subprocess, sys
if ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0) != 0:
    sys.exit(3)
rc = subprocess.run([sys.executable, "-m", "swerve.tools.cli", "run", "--trajectory", "line",
                     "--emulate", "--lockstep", "--no-log", "--json", *sys.argv[1:]], capture_output=True).returncode
try:
    os.waitpid(-1, os.WNOHANG)
    print(rc, "left-behind")
except ChildProcessError:
    print(rc, "none")
"""


@pytest.mark.slow
@pytest.mark.skipif(sys.platform != "linux", reason="PR_SET_CHILD_SUBREAPER is Linux only")
@pytest.mark.parametrize("extra,status", [((), "0"), (("--bogus-option",), "2"), (("--trajectory", "no-such-path"), "2")],
                         ids=["completed", "bad-option", "bad-trajectory"])
def test_swerve_run_emulate_leaves_no_process_behind(extra, status):
    """Neither a run nor a command that fails before it takes the emulator child started ahead
    (``run --emulate`` starts it before parsing its options) leaves a process behind."""
    out = subprocess.run([sys.executable, "-c", _SUBREAPER, *extra], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [status, "none"]


def test_a_prestarted_child_that_died_is_one_clear_error(monkeypatch):
    monkeypatch.setattr(spawn, "_CHILD_PROGRAM", "import sys; sys.exit(3)")   # dies before reading its request
    with prestarted():
        spawn._prestarted[0].wait(timeout=60)
        emu = EmulatorProcess("configs/robot.yaml", timing=Lockstep())
        with pytest.raises(SwerveError, match="died while starting"):
            emu.launch()
            emu.start()
    assert emu.pid is None                       # closed and reaped
