"""The emulated robot in a child process: port, shared true pose, fault commands, final stats."""
import time

import pytest

from swerve.driver.bus import Bus
from swerve.driver.errors import ConfigError, DxlTimeoutError
from swerve.emulator.process import EmulatorProcess


def test_child_emulator_serves_the_bus_and_shares_the_pose():
    with EmulatorProcess("configs/robot.yaml", time_scale=1.0, start_pose=(0.5, -0.25, 0.1)) as emu:
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
    import gc

    from swerve.emulator.server import freeze_startup_heap

    try:
        freeze_startup_heap()
        assert gc.get_freeze_count() > 0
    finally:
        gc.unfreeze()
