"""Benchmark: ``swerve tune`` identification accuracy, 95 % interval coverage and cost.

Usage: ``python bench/bench_tune.py [--runs N]``. Open-loop PWM records are simulated with the
emulator's own ServoModel (0.5 pulse / 4 mA noise, quantisation, 1.5 ms +- 50 % bus sampling);
each is fitted with :func:`tools.tune.identify.identify`. Prints the mean and worst error per
parameter, how often the 95 % interval holds the true value, the fit's CPU time, and the CPU time
of one gain design per loop. Prints only; it does not edit BENCHMARKS.md.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "tools" / "tune"))

from swerve.emulator.physics import units as u  # noqa: E402
from swerve.emulator.physics.params import MotorParams, load_config  # noqa: E402
from simdata import PLAN, pwm_record  # noqa: E402
from swerve.tools.tune.gain_search import Plant, Spec, design_position, design_velocity  # noqa: E402
from swerve.tools.tune.identify import FITTED, identify  # noqa: E402

PRIOR = MotorParams(8.0, 3e-3, 0.012, 0.0067, 3e-7, 9e-8)


def main(runs: int) -> None:
    cfg = load_config(ROOT / "configs" / "emulator.yaml")
    for name, truth in (("drive", cfg.drive_motor), ("steering", cfg.steering_motor)):
        err, cover, cpu = {k: [] for k in FITTED}, {k: 0 for k in FITTED}, []
        for seed in range(runs):
            rec = pwm_record(truth, 212.6, PLAN, seed=100 + seed)
            c0 = time.process_time()
            ident = identify([rec], 212.6, PRIOR, position_lsb_rad=u.RAD_PER_PULSE,
                             current_lsb_a=u.AMP_PER_CURRENT_UNIT)
            cpu.append(time.process_time() - c0)
            for k in FITTED:
                e, t = ident.estimates[k], getattr(truth, k)
                err[k].append(100 * (e.value / t - 1))
                cover[k] += e.ci_low <= t <= e.ci_high
        print(f"{name}: {runs} records, fit CPU {1e3 * np.mean(cpu):.0f} ms each")
        print("| parameter | mean error % | worst error % | 95 % CI coverage |")
        print("|---|---|---|---|")
        for k in FITTED:
            print(f"| {k} | {np.mean(err[k]):+.2f} | {np.max(np.abs(err[k])):.2f} | {cover[k]}/{runs} |")
    for label, fn, motor in (("velocity PI", design_velocity, cfg.drive_motor),
                             ("position P", design_position, cfg.steering_motor)):
        c0 = time.process_time()
        d = fn(Plant(motor, 212.6, cfg.supply_voltage_v, cfg.firmware), Spec())
        print(f"design {label}: {d.gains} in {time.process_time() - c0:.1f} s CPU")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=20)
    main(ap.parse_args().runs)
