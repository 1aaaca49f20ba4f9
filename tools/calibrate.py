"""``swerve calibrate``: steering zero, direction signs and wheel radius, measured on the robot.

Three steps, each a function of a :class:`Session` (the bus and the robot file being
calibrated) and an :class:`Operator` (whoever looks at the robot and answers)::

    with Session(bus, cfg) as s:
        centers = steering_zero(s, op, jog=True)      # Present/Goal Position at straight, pulse
        drive_dir, steer_dir = directions(s, op)      # +1/-1 per wheel
        radius_m = wheel_radius(s, op, distance_m=1.0)
    text = update_robot_text(path.read_text(), center_pulse=centers, wheel_radius_m=radius_m)

Operators: :class:`ConsoleOperator` (prompts, arrow-key jog), :class:`DefaultOperator`
(``--yes``: accept every default), :class:`EmulatorOperator` (``--yes`` on the emulator:
answers from the emulator's true state, which never crosses the bus).

The robot file is edited line by line by :mod:`swerve.configs.yaml_edit` (comments and alignment
kept), re-validated with :func:`swerve.driver.robot_config.parse_robot_config`, and replaced
atomically by :mod:`swerve.core.atomic` (a symlink is written through; a read-only file is
refused, and ``swerve calibrate --write`` checks that before it drives the robot).
"""
from __future__ import annotations

import dataclasses
import os
import sys
import time
from pathlib import Path
from typing import Callable, Protocol, Sequence

from swerve.configs.loader import parse_yaml_text
from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import ConfigError, SwerveError
from swerve.driver.robot_config import RobotConfig, WheelConfig, parse_robot_config
from swerve.driver.wheelset import WheelSet
from swerve.core.atomic import write_text
from swerve.configs.yaml_edit import set_value
from swerve.tools.signals import safe_stop

#: Steering test angle for the direction check, rad (about 17 degrees).
STEER_TEST_RAD = 0.3
#: Wheel ground speed of the direction check, m/s, and how long it turns, robot s.
DRIVE_TEST_MPS = 0.05
DRIVE_TEST_S = 0.8
#: Ground speed of the radius drive, m/s (below the paper's 0.13 m/s cap).
RADIUS_SPEED_MPS = 0.1
#: The calibration steps, in the order they run.
STEPS = ("steering", "directions", "radius")


class CalibrationAborted(SwerveError):
    """The operator stopped the calibration."""


class Operator(Protocol):
    """Whoever looks at the robot: sets wheels straight, confirms directions, measures."""

    def wait_straight(self) -> None:
        """Return once the steering wheels (torque off) have been set straight by hand."""

    def jog_straight(self, jog: "Jogger") -> None:
        """Jog each steering wheel (torque on) until it points straight ahead."""

    def observe(self, kind: str, wheel: int) -> None:
        """Called while wheel ``wheel`` is moving in the direction test (``kind``: drive/steer)."""

    def confirm(self, kind: str, wheel: int, name: str) -> bool:
        """Did wheel ``wheel`` (``name``) roll forward (drive) / turn counter-clockwise seen from
        above (steer)?"""

    def drive_starts(self) -> None:
        """Called just before the radius drive starts."""

    def measured_distance_m(self, commanded_m: float) -> float:
        """The distance the robot travelled, measured on the floor, m."""


@dataclasses.dataclass
class Jogger:
    """Steering goals by wheel, written on every :meth:`jog` (torque on, position mode)."""

    session: "Session"
    goals: list[int]

    def jog(self, wheel: int, delta_pulse: int) -> int:
        """Move wheel ``wheel``'s steering goal by ``delta_pulse``; returns the new goal."""
        steer_id = self.session.cfg.wheels[wheel].steer_id
        new = min(self.session.bus.table(steer_id).pulses_per_rev - 1, max(0, self.goals[wheel] + int(delta_pulse)))
        self.goals[wheel] = new
        self.session.bus.write(steer_id, Reg.GOAL_POSITION, new)
        return new

    def settle(self, robot_s: float = 0.3) -> None:
        self.session.sleep(robot_s)


class Session:
    """The bus and the robot file being calibrated. ``time_scale``: robot seconds per wall
    second (an emulator's; 1 on the robot). ``clock``: a lockstep emulator's
    :class:`~swerve.tools.run.lockstep.LockstepLoopClock` (robot time; ``time_scale`` is then unused),
    or None for the wall clock. Leaving it stops the wheels and turns the torque off."""

    def __init__(self, bus: Bus, cfg: RobotConfig, *, time_scale: float = 1.0,
                 log: Callable[[str], None] = print, clock=None):
        self.bus = bus
        self.cfg = cfg
        self.time_scale = 1.0 if clock is not None else float(time_scale)
        self.clock = clock
        self.log = log
        self.wheels = WheelSet(bus, cfg)

    def now(self) -> float:
        """Robot time, s (on the wall clock: monotonic seconds times the time scale)."""
        return self.clock.now() if self.clock is not None else time.monotonic() * self.time_scale

    def sleep(self, robot_s: float) -> None:
        """Let ``robot_s`` seconds of robot time pass."""
        if self.clock is not None:
            self.clock.sleep_until(self.clock.now() + robot_s)
        else:
            time.sleep(robot_s / self.time_scale)

    def use(self, cfg: RobotConfig) -> None:
        """Continue with ``cfg`` (e.g. the steering zero just found)."""
        self.cfg = cfg
        self.wheels = WheelSet(self.bus, cfg)

    def configure(self) -> None:
        """Modes, gains and return delay of the robot file; the Bus Watchdog stays off, because
        the host waits for the operator between commands."""
        self.wheels.configure()
        self.bus.sync_write(Reg.BUS_WATCHDOG, {i: 0 for i in self.wheels.ids})

    def __enter__(self) -> "Session":
        return self

    def __exit__(self, *exc) -> None:
        with safe_stop():               # a stop signal waits until the torque is off
            self.wheels.safe_shutdown()


def with_calibration(cfg: RobotConfig, *, center_pulse: Sequence[int] | None = None,
                     drive_direction: Sequence[int] | None = None,
                     steer_direction: Sequence[int] | None = None,
                     wheel_radius_m: float | None = None) -> RobotConfig:
    """``cfg`` with the given calibration values replaced (others kept)."""
    wheels = []
    for k, w in enumerate(cfg.wheels):
        wheels.append(dataclasses.replace(
            w, center_pulse=int(center_pulse[k]) if center_pulse is not None else w.center_pulse,
            drive_direction=int(drive_direction[k]) if drive_direction is not None else w.drive_direction,
            steer_direction=int(steer_direction[k]) if steer_direction is not None else w.steer_direction))
    return dataclasses.replace(cfg, wheels=tuple(wheels),
                               wheel_radius_m=cfg.wheel_radius_m if wheel_radius_m is None else float(wheel_radius_m))


# --- step 1: steering zero ------------------------------------------------------------------

def steering_zero(s: Session, op: Operator, *, jog: bool) -> list[int]:
    """Steering centres, pulse: by hand (torque off, Present Position once the operator says
    the wheels are straight) or by jogging (torque on, the Goal Position the operator settled on)."""
    steer_ids = [w.steer_id for w in s.cfg.wheels]
    if not jog:
        s.bus.sync_write(Reg.TORQUE_ENABLE, {i: 0 for i in steer_ids})
        s.log("steering: torque off; set all four wheels straight ahead by hand")
        op.wait_straight()
        pos = s.bus.sync_read(steer_ids, Reg.PRESENT_POSITION)
        return [pos[i][Reg.PRESENT_POSITION] % s.bus.table(i).pulses_per_rev for i in steer_ids]
    s.configure()
    jogger = Jogger(s, [w.center_pulse for w in s.cfg.wheels])
    s.bus.sync_write(Reg.GOAL_POSITION, dict(zip(steer_ids, jogger.goals)))
    s.bus.sync_write(Reg.TORQUE_ENABLE, {i: 1 for i in steer_ids})
    jogger.settle(0.5)
    s.log("steering: torque on at the configured centres; jog each wheel straight")
    op.jog_straight(jogger)
    return list(jogger.goals)


# --- step 2: direction signs ----------------------------------------------------------------

def directions(s: Session, op: Operator) -> tuple[list[int], list[int]]:
    """Drive and steering direction signs: each wheel turns briefly; a wheel the operator does
    not confirm gets its sign flipped."""
    s.configure()
    cfg, table = s.cfg, s.cfg.table
    vel, pos = table[Reg.GOAL_VELOCITY], table[Reg.GOAL_POSITION]
    s.bus.sync_write(Reg.GOAL_VELOCITY, {i: 0 for i in cfg.drive_ids})
    s.bus.sync_write(Reg.GOAL_POSITION, {w.steer_id: w.center_pulse for w in cfg.wheels})
    s.wheels.enable()
    s.sleep(0.5)
    drive, steer = [], []
    for k, w in enumerate(cfg.wheels):
        s.log(f"{w.name}: the drive wheel turns briefly")
        s.bus.write(w.drive_id, Reg.GOAL_VELOCITY, vel.from_si(w.drive_direction * DRIVE_TEST_MPS / cfg.wheel_radius_m))
        s.sleep(DRIVE_TEST_S / 2)
        op.observe("drive", k)
        s.sleep(DRIVE_TEST_S / 2)
        s.bus.write(w.drive_id, Reg.GOAL_VELOCITY, 0)
        ok = op.confirm("drive", k, w.name)
        drive.append(w.drive_direction if ok else -w.drive_direction)
        s.log(f"{w.name}: drive direction {drive[-1]:+d}" + ("" if ok else " (flipped)"))
        s.log(f"{w.name}: the steering turns briefly")
        s.bus.write(w.steer_id, Reg.GOAL_POSITION,
                    w.center_pulse + round(w.steer_direction * STEER_TEST_RAD / pos.scale))
        s.sleep(0.5)
        op.observe("steer", k)
        s.bus.write(w.steer_id, Reg.GOAL_POSITION, w.center_pulse)
        ok = op.confirm("steer", k, w.name)
        steer.append(w.steer_direction if ok else -w.steer_direction)
        s.log(f"{w.name}: steering direction {steer[-1]:+d}" + ("" if ok else " (flipped)"))
        s.sleep(0.5)
    return drive, steer


# --- step 3: wheel radius -------------------------------------------------------------------

def wheel_radius(s: Session, op: Operator, *, distance_m: float = 1.0,
                 speed_mps: float = RADIUS_SPEED_MPS, period_s: float = 0.016) -> tuple[float, dict]:
    """Drive straight until the encoders say ``distance_m`` (at the configured radius), stop,
    ask for the measured distance; radius = measured distance / mean wheel rotation.

    Returns ``(radius_m, facts)`` with the encoder rotation (rad) and both distances (m).
    """
    if not distance_m > 0 or not speed_mps > 0:
        raise ConfigError("the radius drive needs a positive distance and speed")
    s.configure()
    cfg = s.cfg
    s.wheels.write_goals([0.0] * 4, [0.0] * 4)
    s.wheels.enable()
    s.sleep(0.5)
    start = s.wheels.read_state().drive_rad
    op.drive_starts()
    w_radps = speed_mps / cfg.wheel_radius_m
    s.log(f"driving straight {distance_m:.3f} m at {speed_mps:.2f} m/s (by the wheel encoders)")
    deadline = s.now() + 3.0 * distance_m / speed_mps + 5.0 * s.time_scale     # robot s
    try:
        while True:
            s.wheels.write_goals([w_radps] * 4, [0.0] * 4)
            st = s.wheels.read_state()
            done = cfg.wheel_radius_m * sum(a - b for a, b in zip(st.drive_rad, start)) / 4
            if done >= distance_m:
                break
            if s.now() > deadline:
                raise SwerveError(f"the robot did not cover {distance_m} m by its encoders in time "
                                  f"(got {done:.3f} m): is a wheel blocked?")
            s.sleep(period_s)
    finally:
        s.wheels.stop()
    s.sleep(1.0)
    end = s.wheels.read_state().drive_rad
    rotation = sum(a - b for a, b in zip(end, start)) / 4
    measured = float(op.measured_distance_m(cfg.wheel_radius_m * rotation))
    if not measured > 0:
        raise ConfigError(f"measured distance must be positive, got {measured}")
    radius = measured / rotation
    return radius, {"rotation_rad": rotation, "encoder_distance_m": cfg.wheel_radius_m * rotation,
                    "measured_distance_m": measured}


# --- the robot file -------------------------------------------------------------------------

def update_robot_text(text: str, *, center_pulse: Sequence[int] | None = None,
                      drive_direction: Sequence[int] | None = None,
                      steer_direction: Sequence[int] | None = None,
                      wheel_radius_m: float | None = None, where: str = "robot config") -> str:
    """``text`` with the calibration values replaced, line by line: every other byte, comment
    and alignment is kept. The result is validated and must give back the values written;
    raises :class:`ConfigError` otherwise."""
    def seq(values: Sequence[int]) -> str:
        return "[" + ", ".join(str(int(v)) for v in values) + "]"

    new = text
    if center_pulse is not None:
        new = set_value(new, "steering", "center_pulse", seq(center_pulse), where)
    if drive_direction is not None:
        new = set_value(new, "drive", "direction", seq(drive_direction), where)
    if steer_direction is not None:
        new = set_value(new, "steering", "direction", seq(steer_direction), where)
    if wheel_radius_m is not None:
        new = set_value(new, "geometry", "wheel_radius_m", f"{float(wheel_radius_m):.6g}", where)
    cfg = parse_robot_config(parse_yaml_text(new, where))
    want = with_calibration(cfg, center_pulse=center_pulse, drive_direction=drive_direction,
                            steer_direction=steer_direction,
                            wheel_radius_m=None if wheel_radius_m is None else float(f"{float(wheel_radius_m):.6g}"))
    if want != cfg:
        raise ConfigError(f"{where}: the calibration did not round-trip through the file")
    return new


def write_robot_file(path: str | Path, **values) -> None:
    """Apply :func:`update_robot_text` to the file at ``path`` and replace it atomically."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from None
    write_text(path, update_robot_text(text, where=str(path), **values), mkdir=False)


def yaml_snippet(*, center_pulse=None, drive_direction=None, steer_direction=None,
                 wheel_radius_m=None) -> str:
    """The calibrated keys as YAML to paste into the robot file."""
    lines = []
    if wheel_radius_m is not None:
        lines += ["geometry:", f"  wheel_radius_m: {wheel_radius_m:.6f}"]
    if drive_direction is not None:
        lines += ["drive:", f"  direction: [{', '.join(map(str, drive_direction))}]"]
    if steer_direction is not None or center_pulse is not None:
        lines.append("steering:")
        if steer_direction is not None:
            lines.append(f"  direction: [{', '.join(map(str, steer_direction))}]")
        if center_pulse is not None:
            lines.append(f"  center_pulse: [{', '.join(map(str, center_pulse))}]")
    return "\n".join(lines) + "\n"


# --- the steps in order, and the emulated robot -----------------------------------------------

def run_steps(s: Session, op: Operator, steps: Sequence[str] = STEPS, *, jog: bool,
              distance_m: float = 1.0, speed_mps: float = RADIUS_SPEED_MPS) -> dict:
    """Run the chosen ``steps`` (of :data:`STEPS`, in that order), each continuing with what the
    previous ones found. Returns the keyword values of :func:`write_robot_file` /
    :func:`yaml_snippet`; the radius step adds ``radius_facts`` (encoder and measured distance, m)."""
    cfg = s.cfg
    values: dict = {}
    if "steering" in steps:
        values["center_pulse"] = steering_zero(s, op, jog=jog)
        s.use(with_calibration(s.cfg, center_pulse=values["center_pulse"]))
        s.log(f"steering centres: {values['center_pulse']} pulse (were {[w.center_pulse for w in cfg.wheels]})")
    if "directions" in steps:
        values["drive_direction"], values["steer_direction"] = directions(s, op)
        s.use(with_calibration(s.cfg, drive_direction=values["drive_direction"],
                               steer_direction=values["steer_direction"]))
    if "radius" in steps:
        radius, facts = wheel_radius(s, op, distance_m=distance_m, speed_mps=speed_mps)
        values["wheel_radius_m"] = radius
        values["radius_facts"] = facts
        s.log(f"wheel radius: {radius * 1e3:.3f} mm (was {cfg.wheel_radius_m * 1e3:.3f} mm; encoders "
              f"{facts['encoder_distance_m']:.4f} m, measured {facts['measured_distance_m']:.4f} m)")
    return values


# --- operators ------------------------------------------------------------------------------

class DefaultOperator:
    """``--yes`` on a real bus: the wheels are taken as straight as they are, every direction
    as right, the measured distance as the encoders' (so the radius stays)."""

    def wait_straight(self) -> None:
        pass

    def jog_straight(self, jog: Jogger) -> None:
        pass

    def observe(self, kind: str, wheel: int) -> None:
        pass

    def confirm(self, kind: str, wheel: int, name: str) -> bool:
        return True

    def drive_starts(self) -> None:
        pass

    def measured_distance_m(self, commanded_m: float) -> float:
        return commanded_m


class ConsoleOperator:
    """Prompts on the terminal; jogs with the arrow keys (left/right: move the selected wheel,
    up/down: select a wheel, +/-: step size, Enter: accept, q: abort)."""

    def __init__(self, wheels: Sequence[WheelConfig], stream=sys.stdin, out=sys.stderr):
        self.names = [w.name for w in wheels]
        self.stream = stream
        self.out = out

    def _ask(self, prompt: str) -> str:
        self.out.write(prompt)
        self.out.flush()
        line = self.stream.readline()
        if not line:
            raise CalibrationAborted("no answer (end of input)")
        return line.strip()

    def wait_straight(self) -> None:
        self._ask("set all four wheels straight ahead, then press Enter ")

    def observe(self, kind: str, wheel: int) -> None:
        pass

    def drive_starts(self) -> None:
        pass

    def confirm(self, kind: str, wheel: int, name: str) -> bool:
        what = ("roll FORWARD" if kind == "drive"
                else "turn COUNTER-CLOCKWISE (its front to the left, seen from above)")
        ans = self._ask(f"{name}: did the wheel {what}? [Y/n] ").lower()
        return ans in ("", "y", "yes")

    def measured_distance_m(self, commanded_m: float) -> float:
        ans = self._ask(f"the encoders say {commanded_m:.3f} m; distance measured on the floor, m "
                        f"[{commanded_m:.3f}]: ")
        try:
            return float(ans) if ans else commanded_m
        except ValueError:
            raise ConfigError(f"not a distance in metres: {ans!r}") from None

    def jog_straight(self, jog: Jogger) -> None:
        import termios
        import tty

        fd = self.stream.fileno()
        if not os.isatty(fd):
            raise ConfigError("--jog reads the arrow keys: run it in a terminal (or set the wheels by hand)")
        old = termios.tcgetattr(fd)
        k, step = 0, 4
        try:
            tty.setcbreak(fd)
            while True:
                self.out.write(f"\r{self.names[k]:<12} goal {jog.goals[k]:>4} pulse  step {step:>2}  "
                               "(<-/->: jog, up/down: wheel, +/-: step, Enter: done, q: abort) ")
                self.out.flush()
                ch = os.read(fd, 1)
                if ch == b"\x1b":
                    seq = os.read(fd, 2)
                    if seq == b"[C":
                        jog.jog(k, step)
                    elif seq == b"[D":
                        jog.jog(k, -step)
                    elif seq == b"[A":
                        k = (k - 1) % len(self.names)
                    elif seq == b"[B":
                        k = (k + 1) % len(self.names)
                elif ch in (b"+", b"="):
                    step = min(64, step * 2)
                elif ch == b"-":
                    step = max(1, step // 2)
                elif ch in (b"\r", b"\n"):
                    break
                elif ch in (b"q", b"Q", b"\x03"):
                    raise CalibrationAborted("jog aborted")
        finally:
            termios.tcsetattr(fd, termios.TCSADRAIN, old)
            self.out.write("\n")
