"""What the world's disagreement does to the tracking loop: the paper's trajectories on the
emulated robot under ``ideal``, each realism effect alone, and ``realistic``.

Usage: ``python bench/bench_realism.py [--trajectories line circle curvilinear]
[--effects ideal contact friction tolerances supply protection realistic] [--json OUT]``.

Lockstep, so the numbers do not depend on machine load: the emulator runs without a clock and
the loop's clock is the emulator's simulated time (each wait advances the physics). The loop,
odometry, law, driver and bus are the production ones (``TrackingLoop``, ``WheelSet``, ``Bus``).
Errors are the TRUE pose against the reference over t >= tf/4.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import tempfile
import time
from pathlib import Path

import yaml

from swerve.configs import shipped
from swerve.driver.bus import Bus
from swerve.driver.errors import ServoError
from swerve.driver.robot_config import load_robot_config
from swerve.driver.wheelset import WheelSet
from swerve.emulator.physics.contact import ContactBody
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.profiles import EFFECTS, resolve_emulator_config, single_effect
from swerve.emulator.factory import robot_emulator
from swerve.emulator.body_settings import BodySettings
from swerve.emulator.timing import Frozen
from swerve.emulator.server import Emulator
from swerve.tools.run.loop import TrackingLoop
from swerve.tools.run.orchestrate import EMULATOR_PHYSICS_RATE_HZ, prepare_law
from swerve.tools.run.geometry import geometry_and_limits
from swerve.tools.run.ticker import ForegroundClock

#: The build tolerances one at a time: choice -> key of the ``tolerances`` section.
TOLERANCE_PARTS = {"radius": "wheel_radius_scale", "steer-zero": "steer_zero_offset_rad",
                   "backlash": "steer_backlash_rad", "encoder": "encoder_offset_pulse"}
CHOICES = ("ideal", *EFFECTS, "realistic", *TOLERANCE_PARTS)


class EmulatorTime(ForegroundClock):
    """The loop's clock: the emulator's simulated time, moved on by whole physics steps when the
    loop waits (``now`` / ``sleep_until``, the :class:`~swerve.tools.run.ticker.Clock` protocol)."""

    def __init__(self, emu: Emulator, dt_s: float):
        self.emu, self.dt_s = emu, dt_s

    def now(self) -> float:
        return self.emu.sim_time_s

    def sleep_until(self, t: float) -> None:
        while self.emu.sim_time_s < t - 1e-9:
            self.emu.advance(self.dt_s)


class LockstepWheels:
    """A :class:`WheelSet` whose state carries the emulator's simulated time, and whose goals
    have reached the servos before simulated time moves on (a Bulk Write gets no reply, so a
    Ping behind it tells when the emulator has executed it)."""

    def __init__(self, wheels: WheelSet, emu: Emulator):
        self.wheels, self.emu = wheels, emu

    def read_state(self):
        return dataclasses.replace(self.wheels.read_state(), t_s=self.emu.sim_time_s)

    def write_goals(self, drive_radps, steer_rad):
        self.wheels.write_goals(drive_radps, steer_rad)
        with contextlib.suppress(ServoError):
            self.wheels.bus.ping(self.wheels.drive_ids[0])

    def stop(self):
        self.wheels.stop()


def physics_file(choice: str, tmp: Path) -> Path:
    """A config file for ``choice``: a profile, or ``ideal`` with one effect of ``realistic``."""
    if choice in ("ideal", "realistic"):
        return resolve_emulator_config(choice)
    real = yaml.safe_load(resolve_emulator_config("realistic").read_text())
    doc = yaml.safe_load(resolve_emulator_config("ideal").read_text())
    if choice in TOLERANCE_PARTS:
        key = TOLERANCE_PARTS[choice]
        doc["tolerances"] = {key: real["tolerances"][key]}
        path = tmp / f"{choice}.yaml"
        path.write_text(yaml.safe_dump(doc))
        return path
    section = {"contact": "contact", "friction": "gearbox_friction", "tolerances": "tolerances",
               "supply": "supply", "protection": "protection"}[choice]
    doc[section] = real[section]
    path = tmp / f"{choice}.yaml"
    path.write_text(yaml.safe_dump(doc))
    ideal, realistic = load_config(resolve_emulator_config("ideal")), load_config(resolve_emulator_config("realistic"))
    assert load_config(path) == single_effect(ideal, realistic, choice)    # the file is that effect alone
    return path


def run_one(trajectory: str, choice: str, tmp: Path) -> dict:
    cfg_path = shipped("robot.yaml")
    cfg = load_robot_config(cfg_path)
    geom, limits = geometry_and_limits(cfg)
    traj, law = prepare_law(trajectory, None, geom, limits)
    start = traj.start_state(geom)
    with contextlib.ExitStack() as stack:
        emu = stack.enter_context(robot_emulator(cfg_path, physics_file(choice, tmp), timing=Frozen(),
                                                 rate_hz=EMULATOR_PHYSICS_RATE_HZ, body=BodySettings(start_pose=tuple(start[:3]))))
        bus = stack.enter_context(Bus(emu.port, cfg.link.baud, retries=1, default_model=cfg.model,
                                      timeout_margin_s=1.0))
        wheels = stack.enter_context(WheelSet(bus, cfg))
        wheels.configure()
        loop = TrackingLoop(LockstepWheels(wheels, emu), law, geom, watchdog_s=cfg.bus_watchdog_s,
                            true_pose=lambda: emu.pose,
                            clock=EmulatorTime(emu, 1.0 / EMULATOR_PHYSICS_RATE_HZ))
        wheels.enable()
        loop.move_to_start(start[3], start[4])
        cpu0 = time.process_time()
        result = loop.run(start)
        e = result.tracking
        body = emu.world.physics.body
        out = dict(trajectory=trajectory, physics=choice, completed=result.completed,
                   rms_mm=e.rms_position_error_m * 1e3, max_mm=e.max_position_error_m * 1e3,
                   final_mm=e.final_position_error_m * 1e3, odo_max_mm=e.odometry_vs_true_max_m * 1e3,
                   odo_final_mm=e.odometry_vs_true_final_m * 1e3,
                   input_saturated=e.saturated_fraction, cycles=result.cycles,
                   cpu_s=time.process_time() - cpu0,
                   abort=None if result.aborted is None else result.aborted.cause)
        if isinstance(body, ContactBody):
            out["slip_energy_j"] = body.slip_energy_j
            out["tyre_saturated"] = body.saturated_steps / max(body.wheel_steps, 1)
        return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trajectories", nargs="+", default=["line", "circle", "curvilinear"])
    ap.add_argument("--effects", nargs="+", default=["ideal", *EFFECTS, "realistic"], choices=CHOICES,
                    help=f"physics to compare; also the tolerances one by one: {', '.join(TOLERANCE_PARTS)}")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for trajectory in args.trajectories:
            for choice in args.effects:
                row = run_one(trajectory, choice, Path(tmp))
                rows.append(row)
                print(json.dumps(row, default=float), flush=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
