"""Gain schedules ``K(t)`` and their files.

``.npz``: arrays ``times_s`` (N,), ``K`` (N, 3, 5), ``phi_rad`` (N,), ``Q`` (5, 5), ``R`` (3, 3)
and a JSON string ``meta`` (trajectory, tau_s, method, cost, frames, sign convention, ...).
``.dat``: the paper's plain table, one row per step at 1/tau (62.5 Hz)::

    # swerve gain schedule
    # meta: {...json...}
    # columns: t_s K11 K12 ... K15 K21 ... K35 phi_rad
    0.000000 ...

``K`` rows are row-major (``K[i].ravel()``). Sign convention: ``u = ud + K x~``.
"""
from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swerve.configs.atomic import atomic_write
from swerve.controller.errors import ControllerError

SIGN_CONVENTION = "u = ud + K (x - xd)"


@dataclass
class GainSchedule:
    """A gain schedule with its metadata.

    ``K`` (N, 3, 5) gains of step i (in force for ``i tau <= t < (i+1) tau``), ``phi_rad`` (N,)
    chained frame of each step, ``tau_s``, ``Q``, ``R``, ``trajectory`` name, ``method``
    (``riccati`` or ``paper``), ``cost`` J from the synthesis' initial error(s), ``meta`` extra
    JSON-able facts.
    """

    K: np.ndarray
    phi_rad: np.ndarray
    tau_s: float
    Q: np.ndarray
    R: np.ndarray
    trajectory: str
    method: str
    cost: float
    meta: dict = field(default_factory=dict)

    @property
    def n_steps(self) -> int:
        return int(self.K.shape[0])

    @property
    def times_s(self) -> np.ndarray:
        return np.arange(self.n_steps) * self.tau_s

    def _meta(self) -> dict:
        return dict(self.meta, trajectory=self.trajectory, method=self.method,
                    tau_s=self.tau_s, cost=self.cost, n_steps=self.n_steps,
                    sign_convention=SIGN_CONVENTION,
                    Q_diag=np.diag(self.Q).tolist(), R_diag=np.diag(self.R).tolist())


def save_gains(path: str | Path, gains: GainSchedule) -> Path:
    """Write a schedule as ``.npz`` or ``.dat`` (chosen by the suffix); returns the path."""
    p = Path(path)
    if p.suffix not in (".npz", ".dat"):
        raise ControllerError(f"gain file must end in .npz or .dat, got {p.name}")
    meta = gains._meta()
    if p.suffix == ".dat":
        table = np.column_stack([gains.times_s, gains.K.reshape(gains.n_steps, 15),
                                 gains.phi_rad])
        cols = " ".join(f"K{r + 1}{c + 1}" for r in range(3) for c in range(5))
        header = (f"swerve gain schedule\nmeta: {json.dumps(meta)}\n"
                  f"columns: t_s {cols} phi_rad")
        with atomic_write(p, "wb") as fh:
            np.savetxt(fh, table, fmt="%.9g", header=header)
        return p
    with atomic_write(p, "wb") as fh:
        np.savez(fh, times_s=gains.times_s, K=gains.K, phi_rad=gains.phi_rad, Q=gains.Q, R=gains.R,
                 meta=json.dumps(meta))
    return p


def load_gains(path: str | Path) -> GainSchedule:
    """Read a schedule written by :func:`save_gains` (``.npz`` or ``.dat``).

    Raises :class:`ControllerError` if the file is missing, malformed or holds NaNs.
    """
    p = Path(path)
    if not p.is_file():
        raise ControllerError(f"gain file {p} " + ("is a directory" if p.is_dir() else "does not exist"))
    try:
        if p.suffix == ".dat":
            meta = {}
            with open(p, encoding="utf-8") as fh:
                for line in fh:
                    if not line.startswith("#"):
                        break
                    if line.startswith("# meta:"):
                        meta = json.loads(line[len("# meta:"):])
            table = np.loadtxt(p, comments="#", ndmin=2)
            if table.size == 0:
                raise ValueError("the file holds no table (empty)")
            if table.shape[1] != 17:
                raise ValueError(f"expected 17 columns, found {table.shape[1]}")
            K = table[:, 1:16].reshape(-1, 3, 5)
            phi = table[:, 16]
            Q, R = np.diag(meta.get("Q_diag", [1] * 5)), np.diag(meta.get("R_diag", [1] * 3))
            tau = float(meta.get("tau_s", table[1, 0] - table[0, 0]))
        else:
            with np.load(p, allow_pickle=False) as z:
                K, phi, Q, R = z["K"], z["phi_rad"], z["Q"], z["R"]
                meta = json.loads(str(z["meta"]))
            tau = float(meta["tau_s"])
    except (zipfile.BadZipFile, EOFError) as exc:
        raise ControllerError(f"{p} is not a gain schedule .npz (empty, truncated or not a zip archive: "
                              f"{exc})") from None
    except KeyError as exc:
        raise ControllerError(f"{p} is not a gain schedule: no {exc} in it") from None
    except (OSError, ValueError, IndexError) as exc:
        why = str(exc).split("; use `usecols`")[0]      # NumPy's advice does not apply to a gain file
        if "pickled" in why:
            why = "not a gain schedule .npz (holds Python objects)"
        elif "number of columns changed" in why:
            why = f"{why} (a truncated file?)"
        raise ControllerError(f"cannot read gain schedule {p}: {why}") from None
    if K.ndim != 3 or K.shape[1:] != (3, 5) or phi.shape != (K.shape[0],):
        raise ControllerError(f"{p}: gains must have shape (N, 3, 5), got {K.shape}")
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(phi))):
        raise ControllerError(f"{p}: gain schedule holds NaN or infinite values")
    extra = {k: v for k, v in meta.items() if k not in
             ("trajectory", "method", "tau_s", "cost", "n_steps", "sign_convention",
              "Q_diag", "R_diag")}
    return GainSchedule(K, phi, tau, Q, R, str(meta.get("trajectory", "")),
                        str(meta.get("method", "")), float(meta.get("cost", np.nan)), extra)
