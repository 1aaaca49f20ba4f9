"""A campaign's plots: the error distributions (CDF) and each error against each varied value.

``plots/cdf.png``: one empirical CDF per summary group (trajectory, calibrated or not) for each
error metric. ``plots/<metric>_vs_parameters.png``: that metric against every drawn column
(per-wheel values each in their own panel), the groups in colours: the steepest cloud is the
tolerance that costs the most.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from swerve.core.atomic import save_figure

from .report import ERROR_METRICS, group_keys
from .spec import Campaign


def _num(v: str) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _groups(campaign: Campaign, rows: list[dict]) -> dict[str, list[dict]]:
    keys = group_keys(campaign)
    out: dict[str, list[dict]] = {}
    for r in rows:
        if r["status"] == "completed":
            out.setdefault(" ".join(f"{k}={r[k]}" if k != "trajectory" else Path(r[k]).stem for k in keys),
                           []).append(r)
    return out


def plot_campaign(campaign: Campaign, rows: list[dict], folder: Path) -> list[Path]:
    """Write the plots of ``rows`` (results.csv) to ``folder/plots``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = _groups(campaign, rows)
    out = []
    fig, axes = plt.subplots(1, len(ERROR_METRICS), figsize=(4.2 * len(ERROR_METRICS), 3.6), squeeze=False)
    for ax, m in zip(axes[0], ERROR_METRICS):
        for name, sel in groups.items():
            x = np.sort([v for v in (_num(r[m]) * 1e3 for r in sel) if math.isfinite(v)])
            if x.size:
                ax.step(np.r_[x[0], x], np.r_[0.0, np.arange(1, x.size + 1) / x.size], where="post", label=name)
        ax.set_xlabel(f"{m.removesuffix('_m')} (mm)")
        ax.set_ylabel("share of robots")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize="small")
    fig.suptitle(f"campaign {campaign.name}: error distributions (completed scenarios)")
    fig.tight_layout()
    out.append(save_figure(fig, folder / "plots" / "cdf.png", dpi=90))
    plt.close(fig)
    cols = [c for p in campaign.parameters for c in p.columns]
    if not cols:
        return out
    ncol = min(4, len(cols))
    nrow = -(-len(cols) // ncol)
    for m in ERROR_METRICS[:2]:
        fig, axes = plt.subplots(nrow, ncol, figsize=(3.6 * ncol, 3.0 * nrow), squeeze=False)
        for ax, c in zip(axes.flat, cols):
            for name, sel in groups.items():
                ax.plot([_num(r[c]) for r in sel], [_num(r[m]) * 1e3 for r in sel], ".", label=name, alpha=0.7)
            ax.set_xlabel(c, fontsize="small")
            ax.set_ylabel(f"{m.removesuffix('_m')} (mm)", fontsize="small")
            ax.grid(alpha=0.3)
        for ax in list(axes.flat)[len(cols):]:
            ax.set_visible(False)
        axes[0][0].legend(fontsize="x-small")
        fig.suptitle(f"campaign {campaign.name}: {m} against each drawn value")
        fig.tight_layout()
        out.append(save_figure(fig, folder / "plots" / f"{m}_vs_parameters.png", dpi=80))
        plt.close(fig)
    return out


__all__ = ["plot_campaign"]
