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
import math
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swerve.core.atomic import atomic_write
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


#: Most steps a gain file may hold: 2 000 000 steps are 8.9 h at 62.5 Hz, 240 MB of ``K``.
GAINS_MAX_STEPS = 2_000_000
#: Largest ``.dat`` gain file read, bytes (a full-length schedule as text is about 500 MB).
DAT_MAX_BYTES = 1 << 30
#: Largest ``meta`` JSON text, characters.
META_MAX_CHARS = 1 << 20
#: Shape of each array of a ``.npz`` schedule; ``N`` is the number of steps (``K``'s first axis).
NPZ_SHAPES = {"K": ("N", 3, 5), "phi_rad": ("N",), "Q": (5, 5), "R": (3, 3), "meta": ()}


def _npz_headers(p: Path) -> dict[str, tuple[tuple[int, ...], np.dtype]]:
    """``{name: (shape, dtype)}`` of every array in a ``.npz``, read from the ``.npy`` headers
    only (:func:`numpy.lib.format.read_array_header_1_0`), so nothing large is allocated."""
    headers = {}
    with zipfile.ZipFile(p) as zf:
        for info in zf.infolist():
            if not info.filename.endswith(".npy"):
                continue
            with zf.open(info) as f:
                version = np.lib.format.read_magic(f)
                read = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                        else np.lib.format.read_array_header_2_0)
                shape, _, dtype = read(f)
            headers[info.filename[:-len(".npy")]] = (tuple(shape), dtype)
    return headers


def _check_npz_headers(p: Path, headers: dict) -> None:
    """Refuse a ``.npz`` whose declared shapes or types are not a gain schedule's, before loading."""
    for name, want in NPZ_SHAPES.items():
        if name not in headers:
            raise ControllerError(f"{p} is not a gain schedule: no '{name}' in it")
    n = headers["K"][0][0] if len(headers["K"][0]) == 3 else None
    for name, want in NPZ_SHAPES.items():
        shape, dtype = headers[name]
        expect = tuple(n if d == "N" else d for d in want)
        if shape != expect or (n is not None and not 0 < n <= GAINS_MAX_STEPS):
            text = "(N, 3, 5)" if name == "K" else str(expect) if n is not None else str(want)
            more = f" with 1 <= N <= {GAINS_MAX_STEPS}" if name == "K" else (
                f" to match K {headers['K'][0]}" if "N" in want else "")
            raise ControllerError(f"{p}: {name} must have shape {text}{more}, got {shape}")
        if name == "meta":
            if dtype.kind not in "US" or dtype.itemsize > 4 * META_MAX_CHARS:
                raise ControllerError(f"{p}: meta must be a JSON text of at most {META_MAX_CHARS} "
                                      f"characters, got {dtype}")
        elif dtype.kind not in "fiu":
            raise ControllerError(f"{p}: {name} must hold real numbers, got {dtype} values")


def _meta(p: Path, text: str) -> dict:
    meta = json.loads(text)
    if not isinstance(meta, dict):
        raise ControllerError(f"{p}: meta must be a JSON object, got {type(meta).__name__} "
                              f"{text[:40]!r}")
    return meta


def load_gains(path: str | Path) -> GainSchedule:
    """Read a schedule written by :func:`save_gains` (``.npz`` or ``.dat``).

    The shapes a ``.npz`` declares are checked from its headers before anything is loaded.
    Raises :class:`ControllerError` (one line naming the file) if the file is missing,
    malformed, complex, too large, inconsistent or holds NaNs.
    """
    p = Path(path)
    if not p.is_file():
        raise ControllerError(f"gain file {p} " + ("is a directory" if p.is_dir() else "does not exist"))
    try:
        if p.suffix == ".dat":
            if p.stat().st_size > DAT_MAX_BYTES:
                raise ControllerError(f"{p}: larger than {DAT_MAX_BYTES >> 20} MiB: not a gain schedule")
            meta = {}
            with open(p, encoding="utf-8") as fh:
                for line in fh:
                    if not line.startswith("#"):
                        break
                    if line.startswith("# meta:"):
                        meta = _meta(p, line[len("# meta:"):])
            table = np.loadtxt(p, comments="#", ndmin=2)
            if table.size == 0:
                raise ValueError("the file holds no table (empty)")
            if table.shape[1] != 17:
                raise ValueError(f"expected 17 columns, found {table.shape[1]}")
            if table.shape[0] > GAINS_MAX_STEPS:
                raise ValueError(f"{table.shape[0]} steps, more than {GAINS_MAX_STEPS}")
            K = table[:, 1:16].reshape(-1, 3, 5)
            phi = table[:, 16]
            Q = np.diag(np.asarray(meta.get("Q_diag", [1] * 5), dtype=float))
            R = np.diag(np.asarray(meta.get("R_diag", [1] * 3), dtype=float))
            tau = meta.get("tau_s", table[1, 0] - table[0, 0])
        else:
            _check_npz_headers(p, _npz_headers(p))
            with np.load(p, allow_pickle=False) as z:
                K, phi, Q, R = z["K"], z["phi_rad"], z["Q"], z["R"]
                meta = _meta(p, str(z["meta"]))
            tau = meta["tau_s"]
        if isinstance(tau, bool) or not isinstance(tau, (int, float, np.floating)) or not (
                math.isfinite(tau) and tau > 0):
            raise ValueError(f"tau_s must be a positive number of seconds, got {tau!r}")
        tau = float(tau)
        cost = meta.get("cost", np.nan)
        cost = float(cost) if isinstance(cost, (int, float)) and not isinstance(cost, bool) else np.nan
    except ControllerError:
        raise
    except (zipfile.BadZipFile, EOFError) as exc:
        raise ControllerError(f"{p} is not a gain schedule .npz (empty, truncated or not a zip archive: "
                              f"{exc})") from None
    except KeyError as exc:
        raise ControllerError(f"{p} is not a gain schedule: no {exc} in it") from None
    except (OSError, ValueError, IndexError, TypeError) as exc:
        why = str(exc).split("; use `usecols`")[0]      # NumPy's advice does not apply to a gain file
        if "pickled" in why:
            why = "not a gain schedule .npz (holds Python objects)"
        elif "number of columns changed" in why:
            why = f"{why} (a truncated file?)"
        raise ControllerError(f"cannot read gain schedule {p}: {' '.join(why.split())}") from None
    if K.ndim != 3 or K.shape[1:] != (3, 5):
        raise ControllerError(f"{p}: K must have shape (N, 3, 5), got {K.shape}")
    if phi.shape != (K.shape[0],):
        raise ControllerError(f"{p}: phi_rad must have shape ({K.shape[0]},) to match K {K.shape}, "
                              f"got {phi.shape}")
    if Q.shape != (5, 5) or R.shape != (3, 3):
        raise ControllerError(f"{p}: Q must be 5 x 5 and R 3 x 3, got {Q.shape} and {R.shape}")
    if not all(np.all(np.isfinite(a)) for a in (K, phi, Q, R)):
        raise ControllerError(f"{p}: gain schedule holds NaN or infinite values")
    extra = {k: v for k, v in meta.items() if k not in
             ("trajectory", "method", "tau_s", "cost", "n_steps", "sign_convention",
              "Q_diag", "R_diag")}
    return GainSchedule(K.astype(float), phi.astype(float), tau, Q.astype(float), R.astype(float),
                        str(meta.get("trajectory", "")), str(meta.get("method", "")), cost, extra)
