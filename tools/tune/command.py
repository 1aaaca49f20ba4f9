"""``swerve tune``'s work: identify the servo, design its gains, write the results.

The options are :mod:`swerve.tools.commands.tune`; :func:`run` takes the parsed command line.
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
from swerve.emulator.physics.profiles import resolve_emulator_config
from swerve.emulator.factory import robot_emulator
from swerve.emulator.timing import Lockstep
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
