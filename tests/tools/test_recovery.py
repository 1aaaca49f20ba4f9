"""The servo-fault recovery policy on the emulated bus: reboot, restore, rate limit, event log."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import ConfigError, ServoError
from swerve.driver.robot_config import DEFAULT_PATH, load_robot_config
from swerve.driver.wheelset import WheelSet
from swerve.emulator.factory import build_emulator
from swerve.emulator.timing import Frozen
from swerve.tools import recovery


def _fault(ids=(3,), cause="hardware error"):
    return SimpleNamespace(cause=cause, ids=ids)


@pytest.fixture
def wheels():
    cfg = load_robot_config(DEFAULT_PATH)
    with build_emulator(load_robot_config(DEFAULT_PATH), timing=Frozen()) as emu, \
            Bus(emu.port, cfg.link.baud, timeout_margin_s=0.2) as bus:
        ws = WheelSet(bus, cfg)
        ws.configure()
        ws.enable()
        ws.emu = emu
        yield ws


def test_recover_reboots_restores_settings_and_rehomes(wheels):
    wheels.emu.faults.raise_hardware_error(3, "overload")
    with pytest.raises(ServoError) as err:
        wheels.read_state()
    assert err.value.alert
    homed = []
    pol = recovery.RecoverFromFault()
    assert pol.recover(_fault(), wheels, lambda: homed.append(True)) is True
    assert homed == [True]
    bus = wheels.bus
    assert bus.hardware_error(3) == 0
    assert bus.read(3, Reg.OPERATING_MODE) == 1
    assert bus.read(3, Reg.VELOCITY_P_GAIN) == 250          # RAM: back from the power-up default
    assert bus.read(3, Reg.TORQUE_ENABLE) == 1
    assert bus.read(3, Reg.BUS_WATCHDOG) == 5
    wheels.read_state()                                     # reads work again
    steps = [e.step for e in pol.events]
    assert steps == ["fault", "stop", "reboot", "restore", "torque", "rehome", "resume"]
    assert "0x20" in pol.events[2].detail
    assert pol.summary().recoveries == 1 and "reboot" in pol.summary().recovery_steps[2]


def test_at_most_three_recoveries_per_minute(wheels):
    now = [0.0]
    pol = recovery.RecoverFromFault(clock=lambda: now[0])
    for k in range(3):
        wheels.emu.faults.raise_hardware_error(5, "overheating")
        assert pol.recover(_fault((5,)), wheels, lambda: None)
        now[0] += 10.0
    assert not pol.recover(_fault((5,)), wheels, lambda: None)
    assert pol.events[-1].step == "refused" and "3 recoveries within 60 s" in pol.events[-1].detail
    now[0] += 31.0                                          # the first recovery is now 61 s old
    assert pol.recover(_fault((5,)), wheels, lambda: None)


def test_other_causes_and_the_stop_policy_do_not_recover(wheels):
    pol = recovery.RecoverFromFault()
    assert not pol.recover(_fault((), "no reply"), wheels, lambda: None)
    assert pol.events[-1].step == "refused"
    assert not recovery.StopOnFault().recover(_fault(), wheels, lambda: None)
    assert isinstance(recovery.policy("stop"), recovery.StopOnFault)
    with pytest.raises(ConfigError):
        recovery.policy("retry")


class _StepClock:
    """A clock that moves only when slept on, as robot time does in lockstep."""

    def __init__(self):
        self.t_s = 100.0
        self.slept: list[float] = []

    def now(self) -> float:
        return self.t_s

    def sleep_until(self, t: float) -> None:
        self.slept.append(t - self.t_s)
        self.t_s = max(self.t_s, t)


def test_recovery_waits_on_the_runs_clock(wheels):
    clock = _StepClock()
    pol = recovery.policy("recover", clock=clock)
    wheels.emu.faults.raise_hardware_error(3, "overload")
    with pytest.raises(ServoError):
        wheels.read_state()
    assert pol.recover(_fault(), wheels, lambda: None)
    assert all(e.t_s >= 100.0 for e in pol.events)        # stamped on the run's clock
    pol.sleep(0.25)
    assert clock.slept[-1] == pytest.approx(0.25) and clock.now() >= 100.25
