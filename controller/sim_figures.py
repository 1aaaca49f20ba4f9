"""Figures like the paper's 4-9: path, states, inputs and gain schedule of one run."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from swerve.controller.path_fit import FittedPath  # noqa: E402
from swerve.core.atomic import save_figure  # noqa: E402


def _save(fig, path: Path) -> Path:
    """Write ``fig`` to ``path`` (PNG, atomically) and close it."""
    save_figure(fig, path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_run(res, ref, gains, out_dir: str | Path, name: str) -> list[Path]:
    """Write ``NAME_path.png``, ``NAME_states.png``, ``NAME_inputs.png``, ``NAME_gains.png``.

    Parameters
    ----------
    res : controller.simulate.SimResult
    ref : controller.reference.Reference
    gains : controller.gains_io.GainSchedule
    out_dir : directory (created if missing)
    name : file-name prefix

    Returns the written paths.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    files = []
    t = res.t_s

    fig, ax = plt.subplots(figsize=(6, 5))
    ax.plot(ref.states[:, 0], ref.states[:, 1], "k--", label="reference")
    ax.plot(res.states[:, 0], res.states[:, 1], "C0", label="robot")
    ax.plot(res.states[0, 0], res.states[0, 1], "C0o")
    drawn = ref.trajectory.path
    if isinstance(drawn, FittedPath):
        report = drawn.report
        ax.plot(drawn.samples[1][:, 0], drawn.samples[1][:, 1], "k.", ms=2, label="drawn samples")
        ax.text(0.02, 0.02, f"fit vs samples: position {report.position_m * 1e3:.3f} mm, "
                f"heading {report.heading_rad * 1e3:.2f} mrad,\ncurvature "
                f"{report.curvature_1pm:.2g} 1/m, arc overshoot {100 * report.overshoot:.2f} %",
                transform=ax.transAxes, fontsize=7, va="bottom")
    ax.set(xlabel="x [m]", ylabel="y [m]", title=f"{name}: path (cf. paper Fig. 4a/6a/8a)")
    ax.axis("equal")
    ax.legend()
    files.append(_save(fig, out / f"{name}_path.png"))

    fig, axs = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for k, lab in enumerate(["x [m]", "y [m]", "θ [rad]"]):
        axs[0].plot(t, res.states[:, k], f"C{k}", label=lab)
        axs[0].plot(t, res.ref_states[:, k], f"C{k}--", lw=0.8)
    axs[0].set(ylabel="pose", title=f"{name}: x, y, θ (dashed: reference) and steering")
    axs[0].legend()
    axs[1].plot(t, res.states[:, 3], label="δ1")
    axs[1].plot(t, res.states[:, 4], label="δ2")
    axs[1].set(xlabel="t [s]", ylabel="steering [rad]")
    axs[1].legend()
    files.append(_save(fig, out / f"{name}_states.png"))

    fig, axs = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    axs[0].plot(t, res.inputs[:, 0], label="v1")
    axs[0].set(ylabel="v1 [m/s]", title=f"{name}: inputs (cf. paper Fig. 5a/7a/9a)")
    axs[1].plot(t, res.inputs[:, 1], label="ω1")
    axs[1].plot(t, res.inputs[:, 2], label="ω2")
    axs[1].set(xlabel="t [s]", ylabel="steering rate [rad/s]")
    axs[1].legend()
    files.append(_save(fig, out / f"{name}_inputs.png"))

    fig, axs = plt.subplots(3, 1, figsize=(7, 8), sharex=True)
    tk = gains.times_s
    for r in range(3):
        for c in range(5):
            axs[r].plot(tk, gains.K[:, r, c], lw=0.8, label=f"K{r + 1}{c + 1}")
        axs[r].set(ylabel=f"row {r + 1}")
        axs[r].legend(ncol=5, fontsize=7)
    axs[0].set_title(f"{name}: gain schedule K(t), {gains.method} (cf. paper Fig. 5b/7b/9b)")
    axs[2].set_xlabel("t [s]")
    files.append(_save(fig, out / f"{name}_gains.png"))
    return files


