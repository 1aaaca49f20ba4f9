"""Drawn paths: how the fit's cost grows with the number of samples, against the former fit, and
how fast bad files are refused.

Run ``.venv/bin/python bench/bench_paths.py`` from the repository root. Paths, both sampled every
16 ms (the robot's loop) and written to CSV files with 6 decimals as a user's tool would:

- *free-form*: a self-crossing figure-eight (Lissajous 1:2, 1.0 m x 0.6 m, 75 s a lap), speed
  18-64 mm/s, curvature up to 27 1/m at its slow tips;
- *line-and-arc*: lines, arcs of 0.25-0.5 m and direct S-turns, repeated, at 5 cm/s.

Each size is timed as a whole load (``controller.trajectory.load_trajectory``: read, check,
fit) in a fresh process, the median of ``--repeat`` runs; the former fit (``--base DIR``: a
checkout of the former commit with its own ``.venv``) is timed on the same file, in its own
process, and given up after ``--old-timeout`` seconds. Then bad files are timed to their refusal.
``--write`` puts the tables into BENCHMARKS.md (section "Drawn paths: fit cost").
"""
from __future__ import annotations

import argparse
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

import numpy as np  # noqa: E402

from benchutil import cpu_model, write_section  # noqa: E402
from swerve.controller.paths import draw_primitives, draw_sines  # noqa: E402

SECTION = "## Drawn paths: fit cost"
TAU_S = 0.016
SPEED_MPS = 0.05
#: The figure-eight: x = 0.5 sin(w t), y = 0.3 sin(2 w t + 0.6), w = 2 pi / 75 s.
LAP_S = 75.0
FIGURE_EIGHT = ([(0.5, 2 * math.pi / LAP_S, 0.0)], [(0.3, 4 * math.pi / LAP_S, 0.6)])
#: One period of the line-and-arc path (about 4.1 m).
LINE_ARC = [("line", 0.3), ("arc", 0.3, math.pi / 2), ("arc", 0.3, -math.pi / 2), ("line", 0.2),
            ("arc", 0.25, math.pi), ("line", 0.4), ("arc", 0.5, -math.pi / 3),
            ("arc", 0.4, math.pi / 3 + math.pi / 2), ("line", 0.3)]

TIME_LOAD = """
import sys, time
from swerve.controller.{module} import load_trajectory
t0 = time.perf_counter()
try:
    load_trajectory(sys.argv[1])
    print("ok", time.perf_counter() - t0)
except ValueError as exc:
    print("refused", time.perf_counter() - t0, str(exc).splitlines()[0])
"""


def free_form_csv(n: int, out: Path) -> Path:
    """``n`` samples of the figure-eight every 16 ms, written to ``out``."""
    t = np.arange(n) * TAU_S
    x, y = draw_sines(t, *FIGURE_EIGHT)
    return write_csv(out, t, x, y)


def line_arc_csv(n: int, out: Path) -> Path:
    """``n`` samples of the line-and-arc path every 16 ms at 5 cm/s, written to ``out``."""
    period = sum(s[1] if s[0] == "line" else abs(s[1] * s[2]) for s in LINE_ARC)
    reps = int(math.ceil(n * TAU_S * SPEED_MPS / period)) + 1
    s, x, y, _ = draw_primitives(LINE_ARC * reps, (0.0, 0.0, 0.0), TAU_S * SPEED_MPS)
    return write_csv(out, s[:n] / SPEED_MPS, x[:n], y[:n])


def write_csv(out: Path, t, x, y) -> Path:
    rows = "".join(f"{a:.6f},{b:.6f},{c:.6f}\n" for a, b, c in zip(t, x, y))
    out.write_text("t,x,y\n" + rows)
    return out


def time_load(python: str, cwd: Path, module: str, csv: Path, timeout_s: float):
    """Seconds to load (read, check, fit) ``csv`` in a fresh process, or ``None`` after
    ``timeout_s``; raises on a refusal."""
    try:
        r = subprocess.run([python, "-c", TIME_LOAD.format(module=module), str(csv)], cwd=cwd,
                           capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        return None
    if r.returncode != 0:
        raise RuntimeError(f"{csv}: {r.stderr[-400:]}")
    word, dt, *msg = r.stdout.split(maxsplit=2)
    return float(dt) if word == "ok" else "refused: " + " ".join(msg)[:120]


def cost_table(args, work: Path) -> str:
    rows = ["| path | samples | duration s | load (read, check, fit) s | former fit s | former / new |",
            "|---|---|---|---|---|---|"]
    me = sys.executable
    old_py = str(Path(args.base) / ".venv" / "bin" / "python") if args.base else None
    for label, make in (("free-form figure-eight", free_form_csv), ("line-and-arc", line_arc_csv)):
        for n in args.sizes:
            csv = make(n, work / f"{label.split()[0]}_{n}.csv")
            runs = [time_load(me, ROOT, "trajectory", csv, args.timeout) for _ in range(args.repeat)]
            new = statistics.median(r for r in runs if isinstance(r, float)) \
                if all(isinstance(r, float) for r in runs) else runs[0]
            old = None
            if old_py and n <= args.old_max:
                old = time_load(old_py, Path(args.base), "reference", csv, args.old_timeout)
            old_txt = ("not run" if not old_py or n > args.old_max else
                       f"> {args.old_timeout:g} (stopped)" if old is None else
                       old if isinstance(old, str) else f"{old:.2f}")
            ratio = (f"{old / new:.1f}" if isinstance(old, float) and isinstance(new, float)
                     else f"> {args.old_timeout / new:.0f}" if old is None and old_py
                     and n <= args.old_max and isinstance(new, float) else "")
            new_txt = f"{new:.2f}" if isinstance(new, float) else str(new)
            rows.append(f"| {label} | {n} | {n * TAU_S:.0f} | {new_txt} | {old_txt} | {ratio} |")
            print(rows[-1], flush=True)
    return "\n".join(rows)


def bad_files(work: Path) -> list[tuple[str, Path]]:
    """Files a user might give by mistake, each refused before any fitting."""
    out = []
    big = work / "two_gigabytes.csv"
    with open(big, "wb") as fh:              # sparse: no disk space used
        fh.truncate(2 * 1024 ** 3)
    out.append(("2 GB file", big))
    many = work / "rows_over_cap.csv"
    with open(many, "w") as fh:
        fh.write("t,x,y\n")
        for i in range(200_001):
            fh.write(f"{i * 0.001:.3f},{i * 1e-5:.5f},0\n")
    out.append(("200,001 rows (4 MB)", many))
    t = np.arange(200) * 0.016
    out.append(("200 rows at 1,000 m/s", write_csv(work / "fast.csv", t, 1000 * t, 0 * t)))
    out.append(("x around 1e300", write_csv(work / "huge.csv", t, 1e300 + 0 * t, 0 * t)))
    cusp = 0.02 * (t - 1.6) ** 2
    out.append(("a cusp", write_csv(work / "cusp.csv", t, cusp, 0 * t)))
    return out


def refusal_table(work: Path) -> str:
    rows = ["| file | load refused after s | whole `swerve sim` s (with start-up) | message |",
            "|---|---|---|---|"]
    for label, path in bad_files(work):
        r = subprocess.run([sys.executable, "-c", TIME_LOAD.format(module="trajectory"), str(path)],
                           cwd=ROOT, capture_output=True, text=True)
        word, t_load, *_ = r.stdout.split(maxsplit=2)
        assert word == "refused", (label, r.stdout, r.stderr[-400:])
        t0 = time.perf_counter()
        r = subprocess.run([sys.executable, "-m", "swerve.tools.cli", "sim", "--trajectory",
                            str(path), "--quiet"], cwd=ROOT, capture_output=True, text=True)
        dt = time.perf_counter() - t0
        msg = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(msg) == 1, (label, r.returncode, r.stderr[-400:])
        rows.append(f"| {label} | {float(t_load):.3f} | {dt:.2f} | "
                    f"{msg[0].replace(str(work) + os.sep, '')[:150]} |")
        print(rows[-1], flush=True)
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1000, 10_000, 100_000])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--timeout", type=float, default=600.0)
    ap.add_argument("--base", help="checkout of the former commit with its .venv (for the ratio)")
    ap.add_argument("--old-timeout", type=float, default=120.0)
    ap.add_argument("--old-max", type=int, default=10_000, help="largest size to give the former fit")
    ap.add_argument("--no-refusals", action="store_true")
    ap.add_argument("--write", action="store_true", help="update BENCHMARKS.md")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        text = (f"`python bench/bench_paths.py{' --base ' + args.base if args.base else ''}`, "
                f"{cpu_model()}, {os.cpu_count()} CPUs, load average "
                f"{os.getloadavg()[0]:.1f} at the start\n\n" + cost_table(args, work))
        if not args.no_refusals:
            text += "\n\n" + refusal_table(work)
    print(text)
    if args.write:
        write_section(SECTION, f"{SECTION}\n\n{text}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
