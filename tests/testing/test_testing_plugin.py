"""The README's example for users of the ``swerve.testing`` pytest plugin, as written there."""
import pytest
from swerve.driver.bus import Bus


@pytest.mark.emulated_bus(ids=[1, 2, 3])
def test_my_scan_finds_three_servos(emulated_bus):
    with Bus(emulated_bus, 1_000_000) as bus:
        assert [r.id for r in bus.scan(range(1, 10))] == [1, 2, 3]


def test_robot_stays_put_without_goals(emulated_robot):
    with emulated_robot.open_bus() as bus:      # counts the bytes you write, for lockstep
        bus.ping(1)
        emulated_robot.advance(1.0)             # one second of robot time, however long it takes
        assert emulated_robot.pose == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)


def test_the_plugin_is_registered_through_its_entry_point():
    from importlib.metadata import entry_points

    (ep,) = [e for e in entry_points(group="pytest11") if e.name == "swerve"]
    assert ep.value == "swerve.testing"

