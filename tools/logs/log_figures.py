"""PNG figures of a run, after the paper's Figs 11-16 (Caran et al., Actuators 2024, 13, 279).

Reference, simulation, odometry estimate and (emulator) true pose are overlaid wherever they
exist; a curve made only of NaN is left out. Wheel order: front_left, rear_left, rear_right,
front_right, so the front axle (delta1) is wheels 1 and 4, the rear axle (delta2) wheels 2 and 3.

A run has a sample per cycle (8750 for a 140 s path at 62.5 Hz), more than a figure has pixel
columns: each curve is drawn through at most :data:`PLOT_POINTS` of its samples, the lowest and
highest of each run of consecutive samples (see :func:`decimate`), so its envelope, spikes and gaps
look as with every sample. The log keeps every sample; only the drawing is thinned.

Each kind of figure is made once per process and emptied for the next run (:func:`_figure`):
its axes keep their tick marks and labels, which matplotlib otherwise builds anew for every
figure, the larger part of drawing one.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from swerve.core.atomic import save_figure  # noqa: E402
from swerve.tools.logs.record import CycleFlag  # noqa: E402

FRONT, REAR = [0, 3], [1, 2]
#: Most samples a curve is drawn through (two per bucket of consecutive samples, one bucket per
#: pixel column of the widest figure at :data:`DPI`).
PLOT_POINTS = 1800
#: Resolution of the PNG files, dots per inch.
DPI = 110
#: Figure margins as fractions of the figure (fixed, so no layout pass measures the text).
MARGINS = dict(left=0.11, right=0.97, bottom=0.08, top=0.93, hspace=0.12)
#: zlib level of the PNG files: 1 compresses a plot's flat colours about as well as 6, in a third of the time.
PNG_COMPRESS_LEVEL = 1
#: curve name -> (label, style)
STYLE = {
    "ref": ("reference", dict(color="k", ls="--", lw=1.4, zorder=4)),
    "sim": ("simulation", dict(color="tab:orange", lw=1.2)),
    "est": ("measured (odometry)", dict(color="tab:blue", lw=1.2)),
    "true": ("true (emulator)", dict(color="tab:green", lw=1.0, alpha=0.8)),
    "cmd": ("commanded", dict(color="tab:red", lw=1.0, zorder=3)),
    "meas": ("measured", dict(color="tab:blue", lw=1.0)),
}


def decimate(y: np.ndarray, points: int = PLOT_POINTS) -> np.ndarray:
    """Indices (ascending) of the samples of ``y`` (n,) to draw a curve through: all of them when
    ``n <= points``, else in each of ``points // 2`` buckets of consecutive samples the lowest
    and the highest, and the first NaN (so a gap stays a gap)."""
    n = len(y)
    if n <= points:
        return np.arange(n)
    size = -(-n // (points // 2))                   # samples per bucket
    buckets = -(-n // size)
    padded = np.full(buckets * size, np.nan)
    padded[:n] = y
    grid = padded.reshape(buckets, size)
    nan = np.isnan(grid)
    base = np.arange(buckets) * size
    lo = np.where(nan, np.inf, grid).argmin(axis=1)
    hi = np.where(nan, -np.inf, grid).argmax(axis=1)
    picks = [base + lo, base + hi]
    has_nan = nan.any(axis=1)
    picks.append((base + nan.argmax(axis=1))[has_nan])
    idx = np.unique(np.concatenate(picks))
    return idx[idx < n]


def _line(ax, t, y, key, label=None, **extra):
    if y is None or not np.isfinite(y).any():
        return
    lab, style = STYLE[key]
    keep = decimate(y)
    ax.plot(t[keep], y[keep], label=label or lab, **{**style, **extra})


def _poses(log, sim) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """curve name -> (t_s (n,), pose (n, 3)) for every pose source present."""
    t = log.t_s
    if sim is not None:  # a separate simulated run: its ground truth, else its estimate
        sp = sim.true_pose if np.isfinite(sim.true_pose).any() else sim.est_pose
        sim_curve = (sim.t_s, sp)
    else:
        sim_curve = (t, log.sim_pose)
    # legend order of the paper: reference, simulation, measured
    out = {"ref": (t, log.ref_pose), "sim": sim_curve, "est": (t, log.est_pose),
           "true": (t, log.true_pose)}
    return out


#: figure name -> (figure, axes) of the figures made so far in this process, kept for the next run.
_OPEN: dict[str, tuple] = {}


def _figure(name: str, rows: int, figsize: tuple[float, float]):
    """``(figure, axes)`` of kind ``name`` with no curve, legend or text: the one made before
    in this process, emptied, else a new one (``rows`` axes sharing x, ``figsize`` in inches)."""
    if name not in _OPEN:
        _OPEN[name] = plt.subplots(rows, 1, figsize=figsize, sharex=True)
    fig, axes = _OPEN[name]
    for ax in np.ravel(axes):
        for artist in (*ax.lines, *ax.collections, *ax.patches, *ax.texts):
            artist.remove()
        if ax.get_legend() is not None:
            ax.get_legend().remove()
        ax.set_prop_cycle(None)         # the colours start again from the first
        ax.relim()
        ax.autoscale()
    return fig, axes


def _finish(fig, axes, title, path) -> Path:
    for ax in np.ravel(axes):
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=8, loc="best")
    fig.suptitle(title)
    fig.subplots_adjust(**MARGINS)
    save_figure(fig, path, dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESS_LEVEL})
    return path


def _name(log) -> str:
    return str(log.metadata.get("trajectory", Path(log.path).name))


def plot_path(log, sim, out: Path) -> Path:
    """x-y path, equal axes."""
    fig, ax = _figure("path", 1, (6.5, 6))
    for key, (_, p) in _poses(log, sim).items():
        _line(ax, p[:, 0], p[:, 1], key)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal", adjustable="datalim")
    return _finish(fig, ax, f"Path - {_name(log)}", out)


def plot_pose(log, sim, out: Path) -> Path:
    """x, y and theta vs time (paper Figs 11, 13, 15)."""
    fig, axes = _figure("pose", 3, (8, 8))
    poses = _poses(log, sim)
    for i, (ax, lab) in enumerate(zip(axes, ("x [m]", "y [m]", "θ [rad]"))):
        for key, (t, p) in poses.items():
            _line(ax, t, p[:, i], key)
        ax.set_ylabel(lab)
    axes[-1].set_xlabel("trajectory time t [s]")
    return _finish(fig, axes, f"Positions and orientation - {_name(log)}", out)


def plot_velocities(log, sim, out: Path) -> Path:
    """v1 and wheel speeds, steering rates omega1/omega2 (paper Figs 12, 14, 16)."""
    t = log.t_s
    fig, axes = _figure("velocities", 3, (8, 8))
    _line(axes[0], t, log.cmd_v1_mps, "cmd", label="v1 commanded")
    r = log.metadata.get("wheel_radius_m")
    if r is not None and np.isfinite(log.meas_drive_radps).any():
        with warnings.catch_warnings():  # all-NaN rows (unread cycles) stay NaN
            warnings.simplefilter("ignore", RuntimeWarning)
            v1 = float(r) * np.nanmean(log.meas_drive_radps, axis=1)
        _line(axes[0], t, v1, "meas", label="v1 measured (mean wheel speed × r)")
    axes[0].set_ylabel("v1 [m/s]")
    for j, c in enumerate(("tab:red", "tab:purple", "tab:brown", "tab:olive")):
        _line(axes[1], t, log.cmd_drive_radps[:, j], "cmd", label=f"wheel {j + 1} cmd", color=c, ls="--")
        _line(axes[1], t, log.meas_drive_radps[:, j], "meas", label=f"wheel {j + 1} meas", color=c)
    axes[1].set_ylabel("wheel speed [rad/s]")
    axes[1].legend(fontsize=7, ncol=4, loc="best")
    _line(axes[2], t, log.cmd_omega_radps[:, 0], "cmd", label="ω1 (front) commanded")
    _line(axes[2], t, log.cmd_omega_radps[:, 1], "cmd", label="ω2 (rear) commanded", color="tab:purple")
    axes[2].set_ylabel("steering rate [rad/s]")
    axes[-1].set_xlabel("trajectory time t [s]")
    return _finish(fig, axes, f"Robot velocities - {_name(log)}", out)


def plot_steering(log, sim, out: Path) -> Path:
    """Steering angles delta1 (front) and delta2 (rear): reference, commanded, measured."""
    t = log.t_s
    fig, axes = _figure("steering", 2, (8, 6))
    for ax, idx, k, lab in ((axes[0], FRONT, 0, "δ1 (front)"), (axes[1], REAR, 1, "δ2 (rear)")):
        _line(ax, t, log.ref_delta[:, k], "ref")
        _line(ax, t, log.cmd_steer_rad[:, idx[0]], "cmd")
        for j in idx:
            _line(ax, t, log.meas_steer_rad[:, j], "meas", label=f"measured, wheel {j + 1}",
                  alpha=1.0 if j == idx[0] else 0.6)
        ax.set_ylabel(f"{lab} [rad]")
    axes[-1].set_xlabel("trajectory time t [s]")
    return _finish(fig, axes, f"Steering angles - {_name(log)}", out)


def plot_error(log, sim, out: Path) -> Path:
    """Position and heading error of estimate and true pose against the reference."""
    t, ref = log.t_s, log.ref_pose
    fig, axes = _figure("error", 2, (8, 6))
    for key, p in (("est", log.est_pose), ("true", log.true_pose)):
        _line(axes[0], t, np.hypot(*(p[:, :2] - ref[:, :2]).T) * 1e3, key)
        _line(axes[1], t, np.angle(np.exp(1j * (p[:, 2] - ref[:, 2]))), key)
    axes[0].set_ylabel("position error [mm]")
    axes[1].set_ylabel("heading error [rad]")
    axes[-1].set_xlabel("trajectory time t [s]")
    return _finish(fig, axes, f"Tracking error - {_name(log)}", out)


def plot_timing(log, sim, out: Path) -> Path:
    """Measured loop period and flagged cycles."""
    t = log.t_s
    fig, axes = _figure("timing", 2, (8, 5))
    _line(axes[0], t, log.period_s * 1e3, "meas", label="measured period")
    tau = log.metadata.get("period_s")
    if tau is not None:
        axes[0].axhline(float(tau) * 1e3, color="k", ls="--", lw=1, label="nominal τ")
    axes[0].set_ylabel("loop period [ms]")
    for bit, y in ((CycleFlag.OVERRUN, 1), (CycleFlag.STALE, 2)):
        hit = (log.flags & int(bit)) != 0
        axes[1].plot(t[hit], np.full(hit.sum(), y), "|", ms=10, label=f"{bit.name} ({hit.sum()})")
    axes[1].set_yticks([1, 2], ["overrun", "stale"])
    axes[1].set_ylim(0.5, 2.5)
    axes[-1].set_xlabel("trajectory time t [s]")
    return _finish(fig, axes, f"Loop timing - {_name(log)}", out)


FIGURES = (("path", plot_path), ("pose", plot_pose), ("velocities", plot_velocities),
           ("steering", plot_steering), ("error", plot_error), ("timing", plot_timing))


def plot_run(log, out_dir: str | Path, sim=None) -> list[Path]:
    """Write every figure of :data:`FIGURES` as ``<out_dir>/<name>.png``; return the paths.

    ``sim``: an optional second :class:`~tools.logs.bag.RunLog` (e.g. from ``swerve sim``) whose
    pose is overlaid as "simulation"; without it the log's own ``sim_pose`` is used if present.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [fn(log, sim, out_dir / f"{name}.png") for name, fn in FIGURES]
