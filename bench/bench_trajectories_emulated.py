"""Drawn and paper trajectories tracked through the servo emulator, Riccati versus default CG gains.

Each case of ``bench_trajectories.TRACK_CASES`` (plus the R-negative presets and two reverse
starts) is run with ``swerve run --emulate --lockstep --emulator-config ideal --json``: once with
Riccati gains (synthesised by ``run``) and once with ``swerve synth --method paper`` gains (the
default CG with its check; a schedule the check refuses is reported as refused and not run).
Lockstep makes the emulator own robot time, so the numbers do not depend on the machine's load.
Errors are against the emulator's true pose over t >= tf/4 (the summary's tracking fields).

Run ``.venv/bin/python bench/bench_trajectories_emulated.py`` from the repository root; the runs
are sequential (each 10-60 s). Results are kept in ``out/bench/trajectories_emulated.json`` as
they come, so ``--method riccati`` and ``--method paper`` can be run separately and ``--table``
prints the Markdown table of what has been measured.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from bench_trajectories import TRACK_CASES  # noqa: E402

SWERVE = [sys.executable, "-m", "swerve.tools.cli"]
RESULTS = ROOT / "out" / "bench" / "trajectories_emulated.json"
GAINS_DIR = ROOT / "out" / "bench" / "gains"
RUN_TIMEOUT_S = 900.0
SYNTH_TIMEOUT_S = 1200.0

#: (label, trajectory name or CSV file in configs/trajectories, start state or None)
CASES = list(TRACK_CASES) + [
    ("circle_r_negative, start 0.1 m off, θ = 0.3", "circle_r_negative", (0.0, -0.1, 0.3, 0.0, 0.0)),
    ("line_r_negative (paper start)", "line_r_negative", None),
    ("reverse_arc, start (0, 0.01)", "reverse_arc.csv", (0.0, 0.01, 0.0, 0.0, 0.0)),
    ("reverse_arc, start (0, −0.01)", "reverse_arc.csv", (0.0, -0.01, 0.0, 0.0, 0.0)),
]


def _trajectory_arg(name: str) -> str:
    return str(ROOT / "configs" / "trajectories" / name) if name.endswith(".csv") else name


def _x0_args(start) -> list[str]:
    return [] if start is None else ["--x0=" + ",".join(f"{v:g}" for v in start)]


def _last_line(text: str) -> str:
    lines = [ln for ln in text.strip().splitlines() if ln.strip()]
    return lines[-1].strip() if lines else ""


def synth_paper(name: str, start, out: Path) -> tuple[bool, str, float]:
    """``swerve synth --method paper`` into ``out``: (written, last output line, seconds)."""
    cmd = SWERVE + ["synth", "--method", "paper", "--quiet", "--trajectory", _trajectory_arg(name),
                    "--out", str(out)] + _x0_args(start)
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=SYNTH_TIMEOUT_S, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return False, f"synth timed out after {SYNTH_TIMEOUT_S:.0f} s", time.perf_counter() - t0
    dt = time.perf_counter() - t0
    if p.returncode != 0:
        return False, _last_line(p.stderr) or _last_line(p.stdout), dt
    cg = [ln for ln in p.stdout.splitlines() if ln.startswith(("method:", "CG"))]
    return True, "; ".join(cg), dt


def run_emulated(name: str, start, gains: Path | None) -> dict:
    """One lockstep run on the ideal emulator: the summary dict plus exit code and messages."""
    cmd = SWERVE + ["run", "--emulate", "--lockstep", "--emulator-config", "ideal", "--no-log",
                    "--json", "--trajectory", _trajectory_arg(name)] + _x0_args(start)
    if gains is not None:
        cmd += ["--gains", str(gains)]
    t0 = time.perf_counter()
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=RUN_TIMEOUT_S, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"returncode": None, "error": f"run timed out after {RUN_TIMEOUT_S:.0f} s",
                "bench_wall_s": time.perf_counter() - t0}
    res = {"returncode": p.returncode, "bench_wall_s": time.perf_counter() - t0}
    try:
        res.update(json.loads(p.stdout))
    except json.JSONDecodeError:
        res["error"] = _last_line(p.stderr) or "no JSON summary"
    if p.returncode != 0:
        res["stderr_last"] = _last_line(p.stderr)
    return res


def load_results() -> dict:
    return json.loads(RESULTS.read_text()) if RESULTS.exists() else {}


def save_results(results: dict) -> None:
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1, sort_keys=True) + "\n")


def measure(method: str, labels: set[str] | None) -> None:
    """Run every case (or those in ``labels``) with ``method``'s gains, saving after each."""
    results = load_results()
    for i, (label, name, start) in enumerate(CASES):
        if labels and label not in labels:
            continue
        entry = {"trajectory": name, "start": start}
        if method == "paper":
            GAINS_DIR.mkdir(parents=True, exist_ok=True)
            gains = GAINS_DIR / f"case{i}_{Path(name).stem}_paper.npz"
            ok, msg, dt = synth_paper(name, start, gains)
            entry.update(synth_ok=ok, synth_message=msg, synth_s=dt)
            if ok:
                entry["run"] = run_emulated(name, start, gains)
        else:
            entry["run"] = run_emulated(name, start, None)
        results.setdefault(label, {})[method] = entry
        save_results(results)
        print(f"{label} [{method}]: {cell(entry)}", flush=True)


def cell(entry: dict | None) -> str:
    """'rms / max / final (sat.)', or why there is no number."""
    if entry is None:
        return "not run"
    if entry.get("synth_ok") is False:
        return f"refused by synth: {entry['synth_message']}"
    r = entry["run"]
    if "rms_position_error_m" not in r:
        return f"failed: {r.get('error', r.get('stderr_last', '?'))}"
    s = (f"{r['rms_position_error_m']:.1e} / {r['max_position_error_m']:.1e} / "
         f"{r['final_position_error_m']:.1e} ({100 * r['saturated_fraction']:.1f} %)")
    if not r.get("completed", False):
        s += f", aborted ({r.get('abort_cause')}): {r.get('abort_message') or r.get('stderr_last')}"
    return s


def table() -> str:
    """Markdown table of the measured cases."""
    results = load_results()
    rows = ["| case | Riccati: rms / max / final m (sat.) | CG: rms / max / final m (sat.) |",
            "|---|---|---|"]
    for label, _name, _start in CASES:
        if label in results:
            res = results[label]
            rows.append(f"| {label} | {cell(res.get('riccati'))} | {cell(res.get('paper'))} |")
    return "\n".join(rows)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", choices=("riccati", "paper", "both"), default="both")
    ap.add_argument("--case", action="append", default=None, metavar="LABEL",
                    help="only this case (its label in the table); repeatable")
    ap.add_argument("--table", action="store_true", help="only print the table of stored results")
    args = ap.parse_args()
    if not args.table:
        for method in (("riccati", "paper") if args.method == "both" else (args.method,)):
            measure(method, set(args.case) if args.case else None)
    print(table())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
