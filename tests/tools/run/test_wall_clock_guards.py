"""Host-failure guards under a time scale keep their wall-clock length (swerve.tools.run.orchestrate)."""
import pytest

from swerve.driver.robot_config import BUS_WATCHDOG_MAX_S, load_robot_config
from swerve.tools.run.orchestrate import wall_clock_guards


def test_real_time_keeps_the_robot_config():
    cfg = load_robot_config()
    assert wall_clock_guards(cfg, 1.0) is cfg


@pytest.mark.parametrize("scale", [2.0, 5.0, 7.5])
def test_guards_are_stretched_by_the_time_scale(scale):
    cfg = load_robot_config()
    out = wall_clock_guards(cfg, scale)
    assert out.bus_watchdog_s == pytest.approx(cfg.bus_watchdog_s * scale)
    assert out.max_consecutive_timeouts >= cfg.max_consecutive_timeouts * scale
    assert out.max_consecutive_timeouts < cfg.max_consecutive_timeouts * scale + 1
    assert (out.wheels, out.v1_max_mps) == (cfg.wheels, cfg.v1_max_mps)   # nothing else changes


def test_stretched_watchdog_stays_within_the_item():
    out = wall_clock_guards(load_robot_config(), 100.0)
    assert out.bus_watchdog_s == BUS_WATCHDOG_MAX_S
