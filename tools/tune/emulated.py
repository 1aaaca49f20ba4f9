"""An in-process emulated bus for ``swerve tune --emulate`` and the tests.

Each servo of the robot config runs the emulator's own :class:`ServoModel` with the physics of
``configs/emulator.yaml`` (drive or steering motor by the servo's role; steering servos start at
their centre), built by :func:`swerve.emulator.factory.build_emulator` without the robot
body: the servos are unloaded — a wheel lifted off the ground, as a tuning session on the robot
should be done — so the identified values compare with Table 1 directly.
"""
from __future__ import annotations

from swerve.driver.robot_config import RobotConfig
from swerve.emulator.factory import build_emulator
from swerve.emulator.server import Emulator, LinkSettings
from swerve.emulator.physics.params import PhysicsConfig, SensorParams
from swerve.emulator.timing import Timing, WallTime

#: ``--noise``: encoder noise before quantisation (pulse) and current-sensor noise (A), std.
NOISE = SensorParams(position_noise_std_pulse=0.5, current_noise_std_a=0.004)
#: Physics rate of the tuning bus, Hz.
RATE_HZ = 1000.0


def noise_spec(seed: int | None = None) -> dict[str, float]:
    """``--noise`` as a ``build_emulator(noise=...)`` mapping (with the generator's ``seed``)."""
    spec = {"position": NOISE.position_noise_std_pulse, "current": NOISE.current_noise_std_a}
    if seed is not None:
        spec["seed"] = seed
    return spec


def make_emulator(rc: RobotConfig, cfg: PhysicsConfig | None, *, noise: bool = False, seed: int | None = None,
                  baud: int | None = None, timing: Timing = WallTime(), link: LinkSettings = LinkSettings()) -> Emulator:
    """An (unstarted) :class:`Emulator` with every servo of ``rc``, unloaded, at 1 kHz; ``cfg=None``:
    static servos. ``timing``: real time by default; ``Lockstep()``: the emulator owns time
    (``emu.control.path``: its control socket for :class:`swerve.tools.run.lockstep.LockstepLoopClock`).
    ``link``: how the bus behaves on the line."""
    return build_emulator(rc, cfg, timing=timing, rate_hz=RATE_HZ, baud=baud, link=link,
                          noise=noise_spec(seed) if noise and cfg is not None else None)
