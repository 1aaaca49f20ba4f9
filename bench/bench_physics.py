"""Benchmark: CPU cost of one physics second for the 8-servo robot (real-time factor).

Usage: ``python bench/bench_physics.py [--seconds S] [--rate HZ]``. Reports the CPU time
(``time.process_time``) per simulated second and the real-time factor (simulated / CPU seconds),
for the servos alone and with the body, at the configured physics rate.
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from swerve.emulator.physics import units as u
from swerve.emulator.physics.params import load_config
from swerve.emulator.physics.robot import RobotPhysics, load_robot_geometry
from swerve.emulator.physics.servo_model import ServoModel
from swerve.emulator.physics.steptest import position_step, simulate, table, velocity_step

ROOT = Path(__file__).resolve().parents[1]


def robot_tables(cfg, geo):
    """Drive wheels at 0.1 m/s, steering at ±0.3 rad: every loop busy."""
    g = cfg.paper_spec_gains
    goal = round(0.1 / geo.wheel_radius_m / u.RADPS_PER_VEL_UNIT)
    tabs = {}
    for w in geo.wheels:
        tabs[w.drive_id] = table(goal_velocity=w.drive_direction * goal, velocity_p_gain=g["velocity_p_gain"],
                                 velocity_i_gain=g["velocity_i_gain"])
        tabs[w.steer_id] = table(operating_mode=u.MODE_POSITION, position_p_gain=g["position_p_gain"],
                                 goal_position=w.center_pulse + (341 if w.x_m > 0 else -341))
    return tabs


def measure(seconds: float, rate_hz: float) -> dict[str, float]:
    """Return CPU seconds per simulated second: servos only, and servos + body."""
    cfg = dataclasses.replace(load_config(ROOT / "configs" / "emulator.yaml"), rate_hz=rate_hz)
    geo = load_robot_geometry(ROOT / "configs" / "robot.yaml")
    robot = RobotPhysics(cfg, geo)
    tabs = robot_tables(cfg, geo)
    dt, n = 1.0 / rate_hz, int(seconds * rate_hz)
    robot.step(dt, tabs)                                  # warm the discretisation caches
    c0 = time.process_time()
    for _ in range(n):
        for sid, servo in robot.servos.items():
            servo.step(dt, tabs[sid])
    c1 = time.process_time()
    for _ in range(n):
        robot.step(dt, tabs)
    c2 = time.process_time()
    return {"servos_cpu_per_sim_s": (c1 - c0) / seconds, "robot_cpu_per_sim_s": (c2 - c1) / seconds}


def step_report(dt_s: float) -> None:
    """Print the step tests (paper-spec gains and e-Manual defaults)."""
    cfg = load_config(ROOT / "configs" / "emulator.yaml")
    g = cfg.paper_spec_gains
    gear = cfg.gear_ratio("xh430-w210")

    def servo(params):
        return ServoModel(params, gear, cfg.supply_voltage_v, cfg.firmware)

    d = servo(cfg.drive_motor)
    simulate(d, table(operating_mode=u.MODE_PWM, goal_pwm=885), 0.5, dt_s)
    print(f"no-load output speed at 100 % PWM: {d.shaft_speed_radps:.4f} rad/s; V/Ke/gear = "
          f"{cfg.supply_voltage_v / cfg.drive_motor.back_emf_v_s_per_rad / gear:.4f} rad/s; "
          f"with friction {d.motor.no_load_output_speed_radps(cfg.supply_voltage_v):.4f} rad/s")
    print("| step | gains (table) | overshoot % (true / Present) | 2 % settle s | 10-90 % rise s |")
    print("|---|---|---|---|---|")
    for kp, ki in ((g["velocity_p_gain"], g["velocity_i_gain"]), (100, 1920), (250, 6000)):
        m, _, _, outs = velocity_step(servo(cfg.drive_motor), 100, dt_s, 1.5,
                                      velocity_p_gain=kp, velocity_i_gain=ki)
        pres = max(o["present_velocity"] for o in outs) / 100 * 100 - 100
        print(f"| velocity 0->100 (22.9 rpm) | P {kp}, I {ki} | {m.overshoot_pct:.2f} / {max(pres, 0):.0f} | "
              f"{m.settle_s:.3f} | {m.rise_s:.4f} |")
    for kp in (g["position_p_gain"], 900, 3000):
        for step in (50, 512):
            m, _, _, outs = position_step(servo(cfg.steering_motor), 2048, step, dt_s, 1.0, position_p_gain=kp)
            over = max(o["present_position"] for o in outs) - (2048 + step)
            print(f"| position +{step} pulse | P {kp} | {m.overshoot_pct:.2f} / {max(over, 0) / step * 100:.1f} | "
                  f"{m.settle_s:.3f} | {m.rise_s:.4f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=5.0)
    ap.add_argument("--rate", type=float, default=None, help="physics rate, Hz (default: config)")
    args = ap.parse_args()
    rates = [args.rate] if args.rate else [1000.0, 2000.0, 4000.0]
    step_report(1.0 / (args.rate or 2000.0))
    print("| rate (Hz) | servo steps/s | CPU s per physics s, 8 servos | with body | real-time factor (with body) |")
    print("|---|---|---|---|---|")
    for rate in rates:
        r = measure(args.seconds, rate)
        print(f"| {rate:.0f} | {8 * rate:.0f} | {r['servos_cpu_per_sim_s']:.3f} | "
              f"{r['robot_cpu_per_sim_s']:.3f} | {1.0 / r['robot_cpu_per_sim_s']:.2f} |")


if __name__ == "__main__":
    main()
