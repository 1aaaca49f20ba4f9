"""Result files of ``swerve tune``: one PNG per experiment and a JSON + YAML summary.

``pwm_<id>.png``: open-loop steps, measured Present Position / Present Current and the fitted
model. ``step_<id>.png``: the closed-loop step before (original gains) and after tuning,
measured and predicted. ``tune_<id>.json`` / ``.yaml``: parameters with 95 % intervals, residuals,
gains, predicted and measured metrics.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import yaml  # noqa: E402

from swerve.core.atomic import save_figure, write_text  # noqa: E402

from swerve.tools.tune.identify import simulate_open_loop  # noqa: E402
from swerve.tools.tune.pipeline import TuneResult  # noqa: E402


def _clean(x):
    """JSON-safe: NaN/inf -> None, numpy -> Python."""
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    return x


def summary(res: TuneResult) -> dict:
    """The result as plain data (SI units; gains raw)."""
    ident = res.identification
    loops = {}
    for name, loop in (("before", res.before), ("after", res.after)):
        loops[name] = {"gains": loop.gains, "measured": asdict(loop.measured),
                       "predicted_reported": asdict(loop.predicted.reported),
                       "predicted_true": asdict(loop.predicted.true)}
    return _clean({
        "servo": {"id": res.id, "model": res.model, "group": res.group, "gear_ratio": res.gear_ratio,
                  "supply_voltage_v": res.supply_voltage_v, "sample_clock": res.clock,
                  "pwm_runs": len(res.pwm)},
        "identification": {
            "parameters": {k: asdict(e) for k, e in ident.estimates.items()},
            "derived": ident.derived, "input_delay_s": ident.delay_s,
            "position_skew_s": ident.position_skew_s, "residual_rms": ident.residual_rms,
            "noise_std_at_rest": ident.noise_std, "correlation_fitted": ident.correlation,
            "samples": ident.n_samples, **ident.extra},
        "gains": res.design.gains,
        "steps": loops,
        "meets_spec": res.meets_spec, "spec_notes": res.spec_notes,
    })


def write_report(res: TuneResult, out_dir: str | Path) -> list[Path]:
    """Write the PNGs, JSON and YAML for ``res`` into ``out_dir``; return the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    data = summary(res)
    paths = [out / f"tune_{res.id}.json", out / f"tune_{res.id}.yaml",
             out / f"pwm_{res.id}.png", out / f"step_{res.id}.png"]
    write_text(paths[0], json.dumps(data, indent=2) + "\n")
    write_text(paths[1], yaml.safe_dump(data, sort_keys=False))
    _plot_pwm(res, paths[2])
    _plot_steps(res, paths[3])
    return paths


def _plot_pwm(res: TuneResult, path: Path) -> None:
    ident = res.identification
    fig, ax = plt.subplots(2, 1, sharex=True, figsize=(8, 6))
    end = 0.0
    for k, (rec, sw) in enumerate(zip(res.pwm, ident.switch_t_s)):   # runs back to back on one axis
        t = np.linspace(rec.t_s[0], rec.t_s[-1], 2000)
        sim = simulate_open_loop(ident.params, res.gear_ratio, t, sw, rec.voltage_v, ident.coulomb_nm)
        fit_at = simulate_open_loop(ident.params, res.gear_ratio, rec.t_s - ident.position_skew_s, sw,
                                    rec.voltage_v, ident.coulomb_nm)
        offset = float(np.mean(rec.position_rad - fit_at["angle_rad"]))
        label = {} if k else {"m": "measured", "f": "model fit"}
        ax[0].plot(end + rec.t_s, rec.position_rad, ".", ms=2, color="C0", label=label.get("m"))
        ax[0].plot(end + t + ident.position_skew_s, sim["angle_rad"] + offset, "-", lw=1, color="C1",
                   label=label.get("f"))
        ax[1].plot(end + rec.t_s, rec.current_a, ".", ms=2, color="C0", label=label.get("m"))
        ax[1].plot(end + t, sim["current_a"], "-", lw=1, color="C1", label=label.get("f"))
        end += rec.t_s[-1] + 0.05
    ax[0].set_ylabel("Present Position, rad")
    ax[1].set_ylabel("Present Current, A")
    ax[1].set_xlabel("time, s (servo clock; runs back to back)")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(loc="best", fontsize=8)
    ax[0].set_title(f"ID {res.id}: open-loop PWM steps; residual RMS "
                    f"{ident.residual_rms['position_pulse']:.2f} pulse, {ident.residual_rms['current_a'] * 1e3:.1f} mA")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)


def _plot_steps(res: TuneResult, path: Path) -> None:
    unit = "rad/s" if res.group == "drive" else "rad"
    fig, ax = plt.subplots(1, 2, sharey=True, figsize=(10, 4))
    for a, (name, loop) in zip(ax, (("before", res.before), ("after", res.after))):
        rec, pr = loop.record, loop.predicted
        y0 = rec["y0"]
        a.plot(rec["t_s"], rec["y"], ".", ms=3, label="measured")
        a.plot(pr.t_s, pr.y_reported + y0, "-", lw=1, label="predicted (reported signal)")
        a.plot(pr.t_s, pr.y_true + y0, "--", lw=1, label="predicted (true shaft)")
        a.axhline(rec["goal"], color="k", lw=0.5)
        short = ", ".join(f"{k.replace('_gain', '').replace('_', ' ')} {v}" for k, v in loop.gains.items())
        a.set_title(f"ID {res.id} {name}: {short}", fontsize=9)
        a.set_xlabel("time from step, s")
        a.grid(alpha=0.3)
        a.legend(fontsize=7)
    ax[0].set_ylabel(f"{'Present Velocity' if res.group == 'drive' else 'Present Position'}, {unit}")
    fig.tight_layout()
    save_figure(fig, path, dpi=110)
    plt.close(fig)
