"""Benchmark: the emulator with physics — physics cost inside the running emulator,
the largest time scale at which the bus still answers a 62.5 Hz cycle, and the step tests
through the bus.

Usage::

    python bench/bench_emulator_physics.py [--scales 1,1.5,2,3] [--sim-seconds 10] [--rate HZ]
    python bench/bench_emulator_physics.py --serve --time-scale S [--rate HZ]   # emulator process
    python bench/bench_emulator_physics.py --bank 8,16,32 --rate 1000 [--cost-seconds 10]  # physics alone

1. **Cost.** ``robot_emulator(timing=Frozen())``; all eight loops busy (4 drives at 0.1 m/s, 4
   steering servos sweeping ±0.3 rad, set through the bus with WheelSet), one read and one write
   per 16 ms of robot time as in a run; ``emu.advance`` over 10 s; CPU of the calling thread
   (``thread_time``) per simulated second; real-time factor = simulated s / CPU s. The served runs below also report
   the clock's own real-time factor (CPU of the physics steps in the bus thread).
2. **Max time scale.** The emulator runs in a child process (``--serve``), the client
   (WheelSet.read_state + write_goals) in this one, one cycle every 16 ms / S of wall time for
   ``--sim-seconds`` of simulated time. A cycle misses its deadline if it ends after the next
   cycle was due. Also reported: the simulated time the physics clock delivered per wall second
   and the time it had to drop (ClockStats). Largest S with no miss and no dropped time wins.
The servo ticks run compiled when numba is installed (``pip install swerve[fast]``), as Python with
``SWERVE_NO_JIT=1``; the header says which.
``--bank 8,16,32``: instead, the physics alone: the CPU of one 16 ms lockstep cycle for N
free-shaft servos (:func:`cost_bank`, how the cost grows with the bank), then item 1 (the robot), then the
robot's physics in a lockstep run's batches (:func:`cost_lockstep`).
3. **Step tests** through the bus (deterministic, ``timing=Frozen()``): overshoot and settle times.
Prints a markdown section for BENCHMARKS.md.
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchutil import cpu_model  # noqa: E402
from swerve.driver.bus import Bus, ExchangeSettings  # noqa: E402
from swerve.driver.control_table import Reg  # noqa: E402
from swerve.driver.robot_config import load_robot_config  # noqa: E402
from swerve.driver.wheelset import WheelSet  # noqa: E402
from swerve.emulator.physics import units as u  # noqa: E402
from swerve.emulator.physics.params import load_config  # noqa: E402
from swerve.emulator.physics.steptest import step_metrics  # noqa: E402
from swerve.emulator.factory import robot_emulator  # noqa: E402
from swerve.emulator.body_settings import BodySettings  # noqa: E402
from swerve.emulator.timing import Frozen, scaled  # noqa: E402
from swerve.emulator.status_file import read_status  # noqa: E402
from swerve.tools.commands.emulate import format_ids, parse_port_line  # noqa: E402

ROBOT = ROOT / "configs" / "robot.yaml"
PHYSICS = ROOT / "configs" / "emulator.yaml"
CYCLE_S = 0.016
V1_MPS = 0.1


def goals(cfg, t_s: float):
    """Busy goals: 0.1 m/s on every wheel, steering sweeping ±0.3 rad (every loop works)."""
    d = 0.3 * math.sin(2 * math.pi * 0.5 * t_s)
    return [V1_MPS / cfg.wheel_radius_m] * 4, [d, -d, -d, d]


def tick_kernel() -> str:
    """Where the servo ticks run: compiled with numba, or Python (no numba, or ``SWERVE_NO_JIT`` set)."""
    from swerve.emulator.physics import jit
    return f"compiled (numba {jit.numba.__version__})" if jit.ENABLED else "Python"


# --- 1. cost --------------------------------------------------------------------------------------
def cost_in_process(seconds: float, rate_hz: float | None) -> dict[str, float]:
    """Physics CPU per simulated second with a run's traffic: every 16 ms of robot time one
    ``read_state`` + ``write_goals`` (so the watchdog stays fed and the present items are read),
    then ``emu.advance(16 ms)``; only the ``advance`` calls are timed."""
    cfg = load_robot_config(ROBOT)
    with robot_emulator(ROBOT, PHYSICS, timing=Frozen(), rate_hz=rate_hz) as emu, \
            Bus(emu.port, emu.baud, timeout_margin_s=0.3) as bus, WheelSet(bus, cfg) as wheels:
        wheels.configure()
        wheels.enable()
        cycles, wall = [], 0.0
        n = round(seconds / CYCLE_S)
        for k in range(n + 10):
            wheels.write_goals(*goals(cfg, k * CYCLE_S))
            wheels.read_state()
            c0, w0 = time.thread_time(), time.perf_counter()
            emu.advance(CYCLE_S)
            if k >= 10:                                   # the first cycles warm the caches
                cycles.append(time.thread_time() - c0)
                wall += time.perf_counter() - w0
        sim = n * CYCLE_S
        cpu = sum(cycles)
        med = float(np.median(cycles))
        return {"rate_hz": emu.rate_hz, "cpu_per_sim_s": cpu / sim, "rtf": sim / cpu, "wall_rtf": sim / wall,
                "tick_us": 1e6 * cpu / (sim * emu.rate_hz), "median_cycle_ms": 1e3 * med,
                "median_tick_us": 1e6 * med / round(CYCLE_S * emu.rate_hz), "median_rtf": CYCLE_S / med}


#: Physics steps per 16 ms lockstep cycle between the bus events of a run at 1 kHz: the Sync Read's
#: replies, the goals' Bulk Write, the ``advance`` to the next deadline (measured in a lockstep run).
LOCKSTEP_BATCHES = (2, 1, 13)


def cost_lockstep(seconds: float, rate_hz: float | None) -> dict[str, float]:
    """The robot's physics per 16 ms cycle as a lockstep run batches it (:data:`LOCKSTEP_BATCHES`):
    per cycle every servo's Sync Read entry (present current .. position, which publishes the
    present items), two steps, the goals as Bulk Write entries (the items change every cycle),
    one step, then thirteen; direct calls, no pty. CPU of the calling thread in
    ``emu.step_many`` per cycle, median over the cycles."""
    cfg = load_robot_config(ROBOT)
    with robot_emulator(ROBOT, PHYSICS, timing=Frozen(), rate_hz=rate_hz) as emu, \
            Bus(emu.port, emu.baud, timeout_margin_s=0.3) as bus, WheelSet(bus, cfg) as wheels:
        wheels.configure()
        wheels.enable()
        bus.sync_read(wheels.ids, Reg.TORQUE_ENABLE)      # the enable has arrived (the steps bypass the pty)
        by_id = {s.id: s for s in emu.servos}
        table = emu.servos[0].table
        first = table[Reg.PRESENT_CURRENT].address
        length = table[Reg.PRESENT_POSITION].address + 4 - first
        address = {i: table[Reg.GOAL_VELOCITY].address for i in cfg.drive_ids}
        address.update({i: table[Reg.GOAL_POSITION].address for i in cfg.steer_ids})
        dt = 1.0 / emu.rate_hz
        pre, mid = (round(k * emu.rate_hz / 1000.0) for k in LOCKSTEP_BATCHES[:2])
        post = round(CYCLE_S * emu.rate_hz) - pre - mid
        cycles = []
        n = round(seconds / CYCLE_S)
        for k in range(n + 10):
            for s in emu.servos:                          # a Sync Read's entries
                s.note_traffic()
                s.read_status(first, length)
            c0 = time.thread_time()
            emu.step_many(dt, pre)
            c = time.thread_time() - c0
            for i, raw in wheels.goal_raw(*goals(cfg, k * CYCLE_S)).items():    # a Bulk Write's entries
                by_id[i].note_traffic()
                by_id[i].bus_write(address[i], raw.to_bytes(4, "little", signed=True))
            c0 = time.thread_time()
            emu.step_many(dt, mid)
            emu.step_many(dt, post)
            if k >= 10:
                cycles.append(c + time.thread_time() - c0)
        med = float(np.median(cycles))
        return {"rate_hz": emu.rate_hz, "median_cycle_ms": 1e3 * med, "median_rtf": CYCLE_S / med,
                "rtf": n * CYCLE_S / sum(cycles)}


def cost_bank(n_servos: int, seconds: float, rate_hz: float | None, profile: str = "ideal") -> dict[str, float]:
    """Cost of one 16 ms lockstep cycle for ``n_servos`` free-shaft servos (no body), as
    ``swerve emulate --ids 1-N`` has them: even IDs in Velocity mode at 100 units, odd IDs in
    Position mode stepping ±512 pulse every 0.5 s; per cycle the goals written as a Sync Write's
    entries, then (timed) ``emu.advance(16 ms)`` and every servo's Present Current .. Present
    Position read as a Sync Read's entries (no pty, no packets). CPU of the calling thread
    (``thread_time``) per cycle, per physics tick and per servo-tick: the median over the
    cycles (``mean_rtf``: from the mean)."""
    from swerve.emulator.physics.profiles import resolve_emulator_config
    from swerve.emulator.factory import build_emulator

    physics = load_config(resolve_emulator_config(profile))
    emu = build_emulator(None, physics, ids=range(1, n_servos + 1), timing=Frozen(), rate_hz=rate_hz)
    for s in emu.servos:
        m = s.memory
        m.set(Reg.OPERATING_MODE, u.MODE_VELOCITY if s.id % 2 == 0 else u.MODE_POSITION)
        m.set(Reg.TORQUE_ENABLE, 1)
    table = emu.servos[0].table
    gv, gp = table[Reg.GOAL_VELOCITY].address, table[Reg.GOAL_POSITION].address
    first = table[Reg.PRESENT_CURRENT].address                  # present current .. present position
    length = table[Reg.PRESENT_POSITION].address + 4 - first
    n = round(seconds / CYCLE_S)
    cycles = []
    for k in range(n + 10):
        goal = 2048 + (512 if (k * CYCLE_S) % 1.0 < 0.5 else -512)
        for s in emu.servos:                              # a Sync Write's entries
            s.bus_write(gv, (100).to_bytes(4, "little", signed=True))
            s.bus_write(gp, goal.to_bytes(4, "little", signed=True))
        c0 = time.thread_time()
        emu.advance(CYCLE_S)
        for s in emu.servos:                              # a Sync Read's entries
            s.read_status(first, length)
        if k >= 10:
            cycles.append(time.thread_time() - c0)
    per_cycle = float(np.median(cycles))
    ticks = round(CYCLE_S * emu.rate_hz)
    return {"servos": n_servos, "rate_hz": emu.rate_hz, "cycle_ms": 1e3 * per_cycle, "tick_us": 1e6 * per_cycle / ticks,
            "servo_tick_us": 1e6 * per_cycle / ticks / n_servos, "rtf": CYCLE_S / per_cycle,
            "mean_rtf": n * CYCLE_S / sum(cycles)}


# --- 2. served emulator + client cycle -------------------------------------------------------------
def serve(time_scale: float, rate_hz: float | None, status_file: str | None) -> int:
    emu = robot_emulator(ROBOT, PHYSICS, timing=scaled(time_scale), rate_hz=rate_hz, status_file=status_file,
                         status_hz=5.0)
    stop = []
    signal.signal(signal.SIGTERM, lambda *_: stop.append(1))
    with emu:
        print(f"PORT {emu.port} BAUD {emu.baud} IDS {format_ids(s.id for s in emu.servos)}", flush=True)
        while not stop:
            time.sleep(0.05)
    return 0


def run_cycles(time_scale: float, sim_seconds: float, rate_hz: float | None) -> dict:
    cfg = load_robot_config(ROBOT)
    with tempfile.TemporaryDirectory() as tmp:
        status = os.path.join(tmp, "status.json")
        cmd = [sys.executable, __file__, "--serve", "--time-scale", str(time_scale), "--status-file", status]
        if rate_hz:
            cmd += ["--rate", str(rate_hz)]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, cwd=ROOT)
        try:
            port, baud, _ids = parse_port_line(proc.stdout.readline())
            period = CYCLE_S / time_scale if time_scale > 0 else CYCLE_S   # 0: baseline, physics frozen
            n = round(sim_seconds / CYCLE_S)
            lat, missed, errors = [], 0, 0
            # a reply later than 50 ms is a missed cycle anyway
            with Bus(port, baud, timeout_margin_s=0.05) as bus, WheelSet(bus, cfg) as wheels:
                with bus.exchanging(ExchangeSettings(retries=3, timeout_margin_s=0.3)):
                    wheels.configure()                # retries: setup is not what is measured
                    wheels.enable()
                before = read_status(status)
                t0 = time.monotonic()
                for k in range(n):
                    due = t0 + k * period
                    now = time.monotonic()
                    if now < due:
                        time.sleep(due - now)
                    start = time.monotonic()
                    try:
                        wheels.read_state()
                        wheels.write_goals(*goals(cfg, k * CYCLE_S))
                    except Exception:  # noqa: BLE001 - a timeout is a missed cycle
                        errors += 1
                    end = time.monotonic()
                    lat.append(end - start)
                    if end > due + period:
                        missed += 1
                wall = time.monotonic() - t0
                time.sleep(0.5)                       # > 2 status periods
                after = read_status(status)
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)
    sim = after["t_s"] - before["t_s"]
    lat_ms = np.array(lat) * 1e3
    ck = after["clock"]
    if time_scale == 0:
        ck = {"achieved_scale": 0.0, "lost_sim_s": 0.0, "real_time_factor": math.nan}
    return {"scale": time_scale, "cycles": n, "missed": missed, "errors": errors, "wall_s": wall,
            "period_ms": period * 1e3, "median_ms": float(np.median(lat_ms)),
            "p99_ms": float(np.percentile(lat_ms, 99)), "max_ms": float(lat_ms.max()),
            "achieved_scale": ck["achieved_scale"], "lost_sim_s": ck["lost_sim_s"],
            "clock_rtf": ck["real_time_factor"] or math.nan, "sim_s": sim}


# --- 3. step tests through the bus ------------------------------------------------------------------
class _Bench:
    """A fresh unloaded robot (no clock) and a bus to it, per step test."""

    def __enter__(self):
        self.emu = robot_emulator(ROBOT, PHYSICS, timing=Frozen(), body=BodySettings(wheel_load=False)).start()
        self.bus = Bus(self.emu.port, self.emu.baud, timeout_margin_s=0.3).__enter__()
        return self

    def __exit__(self, *exc):
        self.bus.__exit__(*exc)
        self.emu.close()

    def setup(self, id_, mode, **gains):
        self.bus.write(id_, Reg.TORQUE_ENABLE, 0)
        self.bus.write(id_, Reg.OPERATING_MODE, mode)
        for k, v in gains.items():
            self.bus.write(id_, k, v)
        self.bus.write(id_, Reg.TORQUE_ENABLE, 1)

    def sample(self, id_, reg, truth, seconds=0.8):
        t, p, tr = [], [], []
        for k in range(round(seconds / 1e-3)):
            self.emu.advance(1e-3)
            p.append(self.bus.read(id_, reg))
            tr.append(truth())
            t.append((k + 1) * 1e-3)
        return np.array(t), np.array(p, float), np.array(tr)


def step_table() -> list[str]:
    spec = load_config(PHYSICS).paper_spec_gains
    rows = []
    with _Bench() as b:
        b.setup(1, u.MODE_PWM)
        b.bus.write(1, Reg.GOAL_PWM, 885)
        b.emu.advance(0.6)
        w = b.bus.read(1, Reg.PRESENT_VELOCITY) * u.RADPS_PER_VEL_UNIT
    rows.append(f"No-load speed at 100 % PWM read over the bus: {w:.3f} rad/s "
                f"(V/Ke/gear = 5.480 rad/s; with Table 1 friction 5.228 rad/s).")
    rows += ["", "| step (over the bus) | gains | overshoot % true / Present | 2 % settle s true / Present "
             "| 10–90 % rise s |", "|---|---|---|---|---|"]
    for kp, ki in ((spec["velocity_p_gain"], spec["velocity_i_gain"]), (100, 1920),
                   (250, 2 * spec["velocity_i_gain"])):
        with _Bench() as b:
            b.setup(1, u.MODE_VELOCITY, velocity_p_gain=kp, velocity_i_gain=ki)
            b.emu.advance(0.1)
            b.bus.write(1, Reg.GOAL_VELOCITY, 100)
            servo = b.emu.physics.servos[1]
            t, p, tr = b.sample(1, Reg.PRESENT_VELOCITY, lambda: servo.velocity_radps / u.RADPS_PER_VEL_UNIT)
        mp, mt = step_metrics(t, p, 0, 100), step_metrics(t, tr, 0, 100)
        rows.append(f"| velocity 0→100 (drive ID 1) | P {kp}, I {ki} | {mt.overshoot_pct:.2f} / "
                    f"{mp.overshoot_pct:.0f} | {mt.settle_s:.3f} / {mp.settle_s:.3f} | {mt.rise_s:.3f} |")
    for kp in (spec["position_p_gain"], 900, 300):
        with _Bench() as b:
            b.setup(5, u.MODE_POSITION, position_p_gain=kp, position_i_gain=0, position_d_gain=0)
            b.bus.write(5, Reg.GOAL_POSITION, 2048)
            b.emu.advance(0.5)
            y0 = b.bus.read(5, Reg.PRESENT_POSITION)
            b.bus.write(5, Reg.GOAL_POSITION, 2048 + 512)
            servo = b.emu.physics.servos[5]
            t, p, tr = b.sample(5, Reg.PRESENT_POSITION, lambda: servo.shaft_angle_rad / u.RAD_PER_PULSE)
        mp, mt = step_metrics(t, p, y0, 2560), step_metrics(t, tr, y0, 2560)
        rows.append(f"| position +512 pulse (steering ID 5) | P {kp} | {mt.overshoot_pct:.2f} / "
                    f"{int(p.max()) - 2560:+d} pulse | {mt.settle_s:.3f} / {mp.settle_s:.3f} | {mt.rise_s:.3f} |")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--serve", action="store_true", help="(internal) run the emulator and print PORT")
    ap.add_argument("--time-scale", type=float, default=1.0)
    ap.add_argument("--status-file", default=None)
    ap.add_argument("--rate", type=float, default=None, help="physics rate, Hz (default: configs/emulator.yaml)")
    ap.add_argument("--scales", default="0,1,1.5,2,2.5,3", help="time scales to try (0: physics frozen, "
                    "16 ms cycle: the baseline of the bus alone on this machine)")
    ap.add_argument("--sim-seconds", type=float, default=10.0)
    ap.add_argument("--cost-seconds", type=float, default=10.0)
    ap.add_argument("--skip-steps", action="store_true")
    ap.add_argument("--bank", default=None, metavar="N,N,...",
                    help="only the cost of a 16 ms cycle for N free-shaft servos (e.g. 8,16,32), then exit")
    args = ap.parse_args(argv)
    if args.serve:
        return serve(args.time_scale, args.rate, args.status_file)

    print(f"date {time.strftime('%Y-%m-%d')}, nproc {os.cpu_count()}, CPU {cpu_model()!r}, "
          f"Python {platform.python_version()}, load {os.getloadavg()}, servo ticks {tick_kernel()}")
    if args.bank:
        print("\nCPU time of the calling thread per 16 ms cycle: median over the cycles (mean in brackets; "
              "neighbours on a shared machine inflate the mean)")
        print("\n| servos | CPU per 16 ms cycle ms | per tick us | per servo-tick us | real-time factor (mean) |")
        print("|---|---|---|---|---|")
        for n in (int(x) for x in args.bank.split(",")):
            b = cost_bank(n, args.cost_seconds, args.rate)
            print(f"| {n} | {b['cycle_ms']:.3f} | {b['tick_us']:.1f} | {b['servo_tick_us']:.2f} | {b['rtf']:.1f} "
                  f"({b['mean_rtf']:.1f}) |", flush=True)
        c = cost_in_process(args.cost_seconds, args.rate)
        print(f"\nthe robot (8 servos + body, a run's bus traffic), {c['rate_hz']:.0f} Hz: "
              f"{c['median_cycle_ms']:.3f} ms CPU per 16 ms cycle, {c['median_tick_us']:.1f} us per tick, "
              f"real-time factor {c['median_rtf']:.1f} (mean {c['tick_us']:.1f} us per tick, {c['rtf']:.1f})")
        c = cost_lockstep(args.cost_seconds, args.rate)
        print(f"the robot in lockstep batches ({'+'.join(map(str, LOCKSTEP_BATCHES))} steps per cycle at 1 kHz, "
              f"the goals changing every cycle): {c['median_cycle_ms']:.3f} ms CPU per 16 ms cycle, "
              f"real-time factor {c['median_rtf']:.1f} (mean {c['rtf']:.1f})")
        print(f"load after: {os.getloadavg()}")
        return 0
    c = cost_in_process(args.cost_seconds, args.rate)
    print(f"\ncost inside the emulator (emu.advance with a run's traffic, {c['rate_hz']:.0f} Hz): "
          f"{c['cpu_per_sim_s']:.3f} CPU s per physics s, {c['tick_us']:.0f} us per tick (8 servos + body), "
          f"real-time factor {c['rtf']:.2f} (wall {c['wall_rtf']:.2f})")
    print("\n| time scale | cycle period ms | cycles | missed | errors | cycle median / p99 / max ms "
          "| achieved scale | dropped sim s | clock RTF |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in (float(x) for x in args.scales.split(",")):
        r = run_cycles(s, args.sim_seconds, args.rate)
        print(f"| {s:g}{' (frozen)' if s == 0 else ''} | {r['period_ms']:.2f} | {r['cycles']} | {r['missed']} | {r['errors']} | "
              f"{r['median_ms']:.2f} / {r['p99_ms']:.2f} / {r['max_ms']:.2f} | {r['achieved_scale']:.2f} | "
              f"{r['lost_sim_s']:.2f} | {r['clock_rtf']:.2f} |", flush=True)
    if not args.skip_steps:
        print()
        print("\n".join(step_table()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
