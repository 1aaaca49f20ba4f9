"""``swerve tune``: identify one servo's DC motor from step experiments and design its loop gains.

Runs on a real bus (``--port``) or on an in-process emulator on a pty (``--emulate``) through the
same driver code path. Drive servos get the velocity PI tuned, steering servos the position P.
Results: ``OUT/tune_<id>.json|.yaml``, ``OUT/pwm_<id>.png``, ``OUT/step_<id>.png``. The gains stay
in the servo's RAM; ``--write-config`` also stores them in the robot config.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import sys
from pathlib import Path

from tqdm import tqdm

from swerve.configs import locate_robot_file
from swerve.core.atomic import check_writable, files_into
from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import ConfigError, DxlTimeoutError, SwerveError
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.profiles import EMULATOR_CONFIG_HELP, resolve_emulator_config
from swerve.emulator.factory import robot_emulator
from swerve.emulator.timing import Lockstep
from swerve.tools.argtypes import baud_rate, finite_float, int_range, positive_float, servo_id
from swerve.tools.cli import add_config_option
from swerve.tools.run.lockstep import LockstepLoopClock
from swerve.tools.tune.config_io import write_gains
from swerve.tools.tune.emulated import make_emulator, noise_spec
from swerve.tools.tune.experiments import Limits
from swerve.tools.tune.gain_search import Spec
from swerve.tools.tune.pipeline import tune_servo
from swerve.tools.tune.report import write_report


#: Bus reply slack against the lockstep emulator, wall s: its replies are never late in robot
#: time, so this only rides out a loaded host; a reply given up for lost would change the
#: samples (and a missing servo costs this per try).
TUNE_LOCKSTEP_TIMEOUT_MARGIN_S = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument("--port", help="serial port of the bus (e.g. /dev/ttyUSB0)")
    where.add_argument("--emulate", action="store_true", help="tune an emulated servo (in-process, on a pty)")
    parser.add_argument("--baud", type=baud_rate, default=None, help="bps (default: robot config link.baud)")
    parser.add_argument("--id", type=servo_id, default=1, help="servo ID (default 1)")
    parser.add_argument("--mode", choices=("drive", "steering"), default=None,
                        help="which loop to tune (default: from the ID's role in the robot config)")
    parser.add_argument("--overshoot-max", type=finite_float(0.0, 1.0), default=0.02,
                        help="velocity step overshoot limit, fraction (default 0.02)")
    parser.add_argument("--settle-max", type=finite_float(0.0, lo_open=True, allow_inf=True), default=math.inf,
                        help="2 %% settle-time limit of the tuned step, s (default: none, fastest)")
    parser.add_argument("--velocity-step", type=positive_float, default=None,
                        help="velocity step, rad/s at the output (default 100 units = 2.40 rad/s)")
    parser.add_argument("--position-step", type=positive_float, default=None,
                        help="position step, rad (default 512 pulses = 0.785 rad)")
    parser.add_argument("--pwm", type=finite_float(0.0, 1.0, lo_open=True), default=0.5, help="largest open-loop PWM duty, 0..1 (default 0.5)")
    parser.add_argument("--current-max", type=positive_float, default=None,
                        help="abort above this |Present Current|, A (default: the servo's Current Limit)")
    add_config_option(parser)
    parser.add_argument("--prior", default=None,
                        help="motor parameters to start from and to fix L, Km (paper Table 1; a profile "
                             "name or a physics .yaml; default: the shipped emulator.yaml)")
    parser.add_argument("--emulator-config", default=None,
                        help="--emulate: " + EMULATOR_CONFIG_HELP.replace("%", "%%")
                             + " (e.g. a copy with +30 %% inertia)")
    parser.add_argument("--emulator", choices=("servo", "robot"), default="servo",
                        help="--emulate: 'servo' = each servo alone, unloaded, 1 kHz physics (default); "
                             "'robot' = the project's robot emulator (2 kHz physics, robot mass on the "
                             "drive shafts as in configs/emulator.yaml body.load_enabled)")
    parser.add_argument("--noise", action="store_true",
                        help="--emulate: sensor noise on (0.5 pulse encoder, 4 mA current, std)")
    parser.add_argument("--seed", type=int_range(0, 2**32 - 1), default=0,
                        help="--emulate: noise seed (default 0: the same noise every run)")
    parser.add_argument("--write-config", action="store_true",
                        help="store the gains in the robot file (drive.gains or steering.gains)")
    parser.add_argument("--out", default="out/tune", help="directory for PNG/JSON/YAML results")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument("--json", action="store_true",
                        help="print the identified parameters, designed gains and step metrics as JSON")


def run(args: argparse.Namespace) -> int:
    choice = locate_robot_file(args.config)
    robot_file = choice.path
    emulator_file = resolve_emulator_config(args.emulator_config or "ideal")
    print(f"config: {choice.describe()}", file=sys.stderr if args.json else sys.stdout)
    rc = load_robot_config(robot_file)
    # a read-only or full robot file or report folder is refused before the servo moves
    check_writable(Path(args.out) / f"tune_{args.id}.json")
    if args.write_config:
        check_writable(robot_file, mkdir=False)
    prior_cfg = load_config(resolve_emulator_config(args.prior or "ideal"))
    if not 0.0 < args.pwm <= 1.0:
        raise ConfigError(f"--pwm {args.pwm} must be in (0, 1]")
    if args.current_max is not None and not args.current_max > 0:
        raise ConfigError(f"--current-max {args.current_max} must be > 0 A")
    group = args.mode or ("drive" if args.id in rc.drive_ids else "steering" if args.id in rc.steer_ids else None)
    if group is None:
        raise ConfigError(f"servo ID {args.id} is neither a drive nor a steering servo in {robot_file}; "
                          "give --mode")
    spec_kw = {"velocity_overshoot_max": args.overshoot_max}
    spec_kw["velocity_settle_max_s" if group == "drive" else "position_settle_max_s"] = args.settle_max
    if args.velocity_step is not None:
        spec_kw["velocity_step_radps"] = args.velocity_step
    if args.position_step is not None:
        spec_kw["position_step_rad"] = args.position_step
    spec = Spec(**spec_kw)
    prior = prior_cfg.drive_motor if group == "drive" else prior_cfg.steering_motor
    center_rad = None
    if group == "steering":
        pulse = next((w.center_pulse for w in rc.wheels if w.steer_id == args.id), 2048)
        center_rad = rc.table[Reg.PRESENT_POSITION].to_si(pulse)

    with contextlib.ExitStack() as stack:
        clock = None
        if args.emulate:            # in lockstep: the emulator owns time, every run samples alike
            if args.emulator == "robot":
                emu = stack.enter_context(robot_emulator(robot_file, emulator_file, baud=args.baud, timing=Lockstep(),
                                                         noise=noise_spec(args.seed) if args.noise else None))
            else:
                emu = stack.enter_context(make_emulator(rc, load_config(emulator_file), noise=args.noise,
                                                        seed=args.seed, baud=args.baud, timing=Lockstep()))
            clock = stack.enter_context(LockstepLoopClock(emu.control.path))
            port, margin = emu.port, TUNE_LOCKSTEP_TIMEOUT_MARGIN_S
        else:
            port, margin = args.port, 0.002
        bus = stack.enter_context(Bus(port, args.baud or rc.link.baud, retries=3, timeout_margin_s=margin))
        if clock is not None:
            clock.attach(bus)
        try:
            found = bus.ping(args.id)
        except DxlTimeoutError:
            raise SwerveError(f"servo ID {args.id} does not answer on {port} (ping timed out): check the ID with "
                              "'swerve scan', the cable and the power; nothing was written") from None
        current_max = args.current_max if args.current_max is not None else bus.read_si(args.id, Reg.CURRENT_LIMIT)
        if group == "steering":
            limits = Limits(position_min_rad=center_rad - rc.steer_angle_max_rad,
                            position_max_rad=center_rad + rc.steer_angle_max_rad, current_max_a=current_max)
        else:
            limits = Limits(speed_max_radps=rc.drive_max_radps, current_max_a=current_max)
        bar = stack.enter_context(tqdm(total=None, unit="s", disable=args.no_progress,
                                       desc=f"ID {args.id} ({found.model}, {group})",
                                       bar_format="{desc}: {n:.1f} s of experiments [{postfix}]"))

        def progress(phase):
            bar.set_postfix_str(phase)
            return bar.update

        res = tune_servo(bus, args.id, group, spec, prior, limits=limits, firmware=prior_cfg.firmware,
                         center_rad=center_rad, duty_max=args.pwm, progress=progress, clock=clock)
    with files_into(args.out) as tmp:       # the whole report or none of it
        paths = [Path(args.out) / p.name for p in write_report(res, tmp)]
    if args.json:
        print(json.dumps(identified(res), sort_keys=True, allow_nan=False))
    else:
        _print(res, paths)
    if not res.meets_spec:
        raise SwerveError("the designed gains do not meet the spec when measured ("
                          + "; ".join(res.spec_notes) + "); original gains kept, torque off, config untouched")
    if args.write_config:
        write_gains(robot_file, group, res.design.gains)
        print(f"gains written to {robot_file} ({group}.gains)", file=sys.stderr if args.json else sys.stdout)
    return 0


def identified(res) -> dict:
    """``--json``: the identified parameters (value, 95 % interval, identified or fixed), the
    designed gains, the step metrics before and after, and whether the spec is met."""
    ident = res.identification
    return {"id": res.id, "group": res.group, "clock": res.clock, "samples": ident.n_samples,
            "parameters": {name: {"value": _finite(e.value), "ci_low": _finite(e.ci_low),
                                  "ci_high": _finite(e.ci_high), "identified": e.identified, "unit": e.unit}
                           for name, e in ident.estimates.items()},
            "gains": dict(res.design.gains), "meets_spec": res.meets_spec,
            "steps": {name: {"overshoot_pct": loop.measured.overshoot_pct, "rise_s": loop.measured.rise_s,
                             "settle_s": loop.measured.settle_s}
                      for name, loop in (("before", res.before), ("after", res.after))}}


def _finite(x: float) -> float | None:
    """``x``, or None for NaN / infinity (an interval a fixed parameter does not have)."""
    return float(x) if math.isfinite(x) else None


def _print(res, paths) -> None:
    ident = res.identification
    print(f"servo ID {res.id} ({res.model}, {res.group}), gear {res.gear_ratio:g}, supply {res.supply_voltage_v:.1f} V,"
          f" {ident.n_samples} samples ({res.clock} clock)")
    for name, e in ident.estimates.items():
        ci = f"[{e.ci_low:.4g}, {e.ci_high:.4g}] 95 %" if e.identified else f"fixed: {e.note}"
        print(f"  {name:24s} {e.value:.4g} {e.unit:10s} {ci}")
    print(f"  residual RMS: {ident.residual_rms['position_pulse']:.2f} pulse, "
          f"{ident.residual_rms['current_a'] * 1e3:.2f} mA; tau_m {ident.derived['tau_m_s'] * 1e3:.2f} ms")
    print(f"  gains: {res.design.gains}")
    print("                  overshoot %   rise ms   settle ms")
    for name, loop in (("before", res.before), ("after", res.after)):
        for what, m in (("predicted", loop.predicted.reported), ("measured", loop.measured)):
            print(f"  {name:6s} {what:9s} {m.overshoot_pct:9.2f} {m.rise_s * 1e3:9.1f} {m.settle_s * 1e3:11.1f}")
    print(f"  spec: {'met' if res.meets_spec else 'NOT met'} ({'; '.join(res.spec_notes)})")
    print("  files: " + ", ".join(str(p) for p in paths))
