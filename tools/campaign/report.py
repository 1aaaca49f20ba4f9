"""A campaign's summary: counts by status and p50/p95/max of each error metric, per trajectory
(and calibrated or not) and overall; the worst scenarios with the command that replays each.

Written as ``summary.json`` and ``summary.md`` (the table the README quotes) from results.csv's
rows, so a resumed or partial campaign summarises exactly what its table holds.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from swerve.core.atomic import write_text

from .scenario import STATUSES
from .spec import Campaign

#: The error metrics summarised (m).
ERROR_METRICS = ("rms_position_error_m", "max_position_error_m", "final_position_error_m",
                 "odometry_vs_true_max_m")
#: Scenarios listed as the worst.
WORST = 10


def _float(v: str) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def stats(rows: list[dict]) -> dict:
    """``{"count": {status: n}, "metrics": {metric: {p50, p95, max, n}}}`` of ``rows`` (metrics
    over the completed rows with a finite value; ``None`` where there is none)."""
    count = {s: sum(r["status"] == s for r in rows) for s in STATUSES}
    metrics = {}
    for m in ERROR_METRICS:
        x = np.array([_float(r[m]) for r in rows if r["status"] == "completed"])
        x = x[np.isfinite(x)]
        metrics[m] = dict(n=int(x.size), p50=float(np.percentile(x, 50)) if x.size else None,
                          p95=float(np.percentile(x, 95)) if x.size else None,
                          max=float(x.max()) if x.size else None)
    return dict(count=count, metrics=metrics)


def group_keys(campaign: Campaign) -> tuple[str, ...]:
    """Columns the summary groups by: the trajectory, and whether calibrated when both ran."""
    return ("trajectory", "calibrate") if "calibrate" in campaign.varied else ("trajectory",)


def worst(rows: list[dict], folder: Path, n: int = WORST) -> list[dict]:
    """The ``n`` worst rows: failed, then stopped, then the largest rms error; with replay commands."""
    rank = {"failed": 0, "stopped": 1, "completed": 2}

    def key(r):
        e = _float(r["rms_position_error_m"])
        return rank[r["status"]], -(e if math.isfinite(e) else math.inf), int(r["index"])

    out = []
    for r in sorted(rows, key=key)[:n]:
        out.append(dict(index=int(r["index"]), trajectory=r["trajectory"], calibrate=r["calibrate"],
                        status=r["status"], reason=r["reason"],
                        rms_position_error_m=e if math.isfinite(e := _float(r["rms_position_error_m"])) else None,
                        replay=f"swerve campaign replay {folder} {r['index']} --log {folder}/replay-{r['index']}"))
    return out


def summarise(campaign: Campaign, rows: list[dict], folder: Path) -> dict:
    """The summary of ``rows`` (results.csv) as a JSON-ready dict."""
    keys = group_keys(campaign)
    groups = []
    for values in dict.fromkeys(tuple(r[k] for k in keys) for r in rows):
        sel = [r for r in rows if tuple(r[k] for k in keys) == values]
        groups.append(dict(zip(keys, values), **stats(sel)))
    return dict(campaign=campaign.name, seed=campaign.seed, scenarios=campaign.scenarios, finished=len(rows),
                overall=stats(rows), groups=groups, worst=worst(rows, folder))


def _mm(v) -> str:
    return "-" if v is None else f"{v * 1e3:.1f}"


def table(summary: dict, metric: str = "rms_position_error_m") -> str:
    """Markdown table of the groups: counts and p50 / p95 / max of ``metric`` in mm."""
    keys = [k for k in ("trajectory", "calibrate") if summary["groups"] and k in summary["groups"][0]]
    head = keys + ["completed", "stopped", "failed", f"{metric} p50 / p95 / max (mm)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for g in summary["groups"] + [dict(trajectory="all", calibrate="", **summary["overall"])]:
        m = g["metrics"][metric]
        cells = [str(g.get(k, "")) for k in keys] + [str(g["count"][s]) for s in STATUSES]
        cells.append(f"{_mm(m['p50'])} / {_mm(m['p95'])} / {_mm(m['max'])}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_summary(campaign: Campaign, rows: list[dict], folder: Path) -> dict:
    """Write ``summary.json`` and ``summary.md`` to ``folder``; returns the summary."""
    s = summarise(campaign, rows, folder)
    write_text(folder / "summary.json", json.dumps(s, indent=2, allow_nan=False) + "\n")
    lines = [f"# campaign {campaign.name}", "",
             f"{s['finished']} of {s['scenarios']} scenarios finished (seed {campaign.seed}). Errors against the "
             "emulator's true pose, over t >= tf/4 (rms, max) and at the end (final).", "",
             table(s), "", "## Worst scenarios", ""]
    lines += [f"- {w['index']}: {w['trajectory']} calibrate={w['calibrate']} {w['status']} "
              f"{_mm(w['rms_position_error_m'])} mm rms"
              f"{': ' + w['reason'] if w['reason'] else ''} — `{w['replay']}`" for w in s["worst"]]
    write_text(folder / "summary.md", "\n".join(lines) + "\n")
    return s


__all__ = ["ERROR_METRICS", "stats", "summarise", "table", "worst", "write_summary"]
