"""Trajectories: a path to track and the synthesis problem's data, loaded from files.

A :class:`Trajectory` is a path plus the paper's problem data (``tf``, ``N``, ``tau``, ``Q``,
``R``, start state). :func:`load_trajectory` reads ``configs/trajectories/NAME.yaml`` or a YAML
file (through :mod:`swerve.configs.loader`) or a ``t,x,y`` CSV file of drawn samples (checked by
:mod:`controller.path_csv`, fitted by :mod:`controller.path_fit`). The formats, caps and what
is refused: ``docs/trajectories.md``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swerve.configs import shipped
from swerve.configs.loader import Section, read_yaml
from swerve.controller.errors import ControllerError
from swerve.controller.kinematics import Geometry, Limits
from swerve.controller.path_csv import read_csv_samples
from swerve.controller.path_fit import fit_samples, read_csv_path
from swerve.controller.paths import CirclePath, CurvilinearPath, LinePath, PlanarPath
from swerve.controller.reference import desired_states

#: Directory of the named trajectories (``line``, ``circle``, ``curvilinear``).
TRAJECTORY_DIR = shipped("trajectories")

#: Weights for a CSV path given without a YAML file: the line case's Q, and R with negative
#: exponents (tight tracking, the tracking law clips what the servos cannot do; a YAML
#: wrapper sets other weights).
DEFAULT_Q_DIAG = (1e3, 1.0, 1e2, 1.0, 1e3)
DEFAULT_R_DIAG = (1e-4, 1e-2, 1e-2)
#: Fit of CSV samples (:class:`controller.path_fit.FittedPath`): lines and arcs are recognised
#: within this tolerance (m), and curvature blends between them over this length (m).
CSV_TOLERANCE_M = 2e-5
CSV_BLEND_M = 0.05
#: Sampling period of the robot's loop, s (62.5 Hz).
DEFAULT_TAU_S = 0.016


@dataclass(frozen=True)
class Trajectory:
    """A path to track and the synthesis problem's data.

    Attributes: ``name``; ``path`` (a :class:`~swerve.controller.paths.PlanarPath`); ``tf_s``; ``n_steps`` (N);
    ``tau_s``; ``Q`` (5, 5); ``R`` (3, 3); ``start`` the robot's start state (5,), or pose
    (3,) with the steering that fits the path's curvature at t = 0, or ``None`` for "on the
    reference, aligned"; ``direction`` +1 (body faces the direction of travel) or -1 (driven
    in reverse: heading opposite to travel, v1 < 0).
    """

    name: str
    path: PlanarPath
    tf_s: float
    n_steps: int
    tau_s: float
    Q: np.ndarray
    R: np.ndarray
    start: np.ndarray | None = None
    source: str = ""
    direction: int = 1

    def __post_init__(self):
        if self.direction not in (1, -1):
            raise ControllerError(f"{self.name}: direction must be +1 (forwards) or -1 (reverse)")

    def start_state(self, geom: Geometry = Geometry()) -> np.ndarray:
        """The robot's start state ``(x, y, theta, delta1, delta2)``, shape (5,)."""
        on_path = desired_states(self.path, np.array([0.0]), geom, self.direction)[0][0]
        if self.start is None:
            return on_path
        start = np.array(self.start, dtype=float)
        return start if start.size == 5 else np.concatenate([start, on_path[3:]])


#: Plausibility bounds of trajectory-file keys (a larger value is a typo or a wrong unit).
TRAJ_DURATION_MAX_S = 1e5
TRAJ_LENGTH_MAX_M = 1e4
TRAJ_SPEED_MAX_MPS = 100.0
#: Most steps a trajectory may have (gain synthesis holds ~1 kB per step: 0.2 GB at most); at
#: 62.5 Hz this is 53 minutes.
N_STEPS_MAX = 200_000
WEIGHT_MAX = 1e12
PATH_TYPES = ("line", "circle", "curvilinear", "csv")


def _diag(sec: Section, key: str, n: int, default) -> np.ndarray:
    return np.diag(sec.numbers(key, n, default, positive=True, max=WEIGHT_MAX))


def _path_from_spec(sec: Section, tf_s: float, base: Path, geom: Geometry, limits: Limits):
    kind = sec.raw("type")
    if not isinstance(kind, str) or kind not in PATH_TYPES:
        sec.fail(f"path type must be {', '.join(PATH_TYPES[:-1])} or {PATH_TYPES[-1]}, got {kind!r}", "type")
    pos = dict(min=-TRAJ_LENGTH_MAX_M, max=TRAJ_LENGTH_MAX_M)
    span = dict(positive=True, max=TRAJ_DURATION_MAX_S)
    if kind == "line":
        path = LinePath(sec.numbers("start_m", 2, (0.0, 0.0), **pos),
                        sec.numbers("velocity_mps", 2, min=-TRAJ_SPEED_MAX_MPS, max=TRAJ_SPEED_MAX_MPS),
                        tf_s)
    elif kind == "circle":
        path = CirclePath(sec.number("radius_m", 1.0, positive=True, max=TRAJ_LENGTH_MAX_M),
                          sec.number("period_s", tf_s, **span), tf_s)
    elif kind == "curvilinear":
        path = CurvilinearPath(sec.number("offset_m", 0.6, **pos), sec.number("period_s", tf_s, **span), tf_s)
    else:
        path = read_csv_path(base / sec.string("file"),
                             sec.number("tolerance_m", CSV_TOLERANCE_M, positive=True, max=1.0),
                             sec.number("blend_m", CSV_BLEND_M, positive=True, max=10.0), limits, geom)
    sec.check_unknown()
    return path


def _start_from_spec(sec: Section, path, geom, direction: int = 1):
    pose = [sec.number(k, 0.0, min=-TRAJ_LENGTH_MAX_M, max=TRAJ_LENGTH_MAX_M) for k in ("x_m", "y_m")]
    pose.append(sec.number("theta_rad", 0.0, min=-100.0, max=100.0))
    if sec.raw("steering_rad", "ackermann") == "ackermann":
        # steering that fits the path's curvature at t = 0 (the paper's circle start)
        steer = desired_states(path, np.array([0.0]), geom, direction)[0][0][3:]
        if not np.all(np.isfinite(steer)):
            sec.fail("the path's steering at t = 0 is undefined (path at rest)", "steering_rad")
    else:
        steer = sec.numbers("steering_rad", 2, min=-math.pi, max=math.pi)
    sec.check_unknown()
    return np.array(pose + [float(v) for v in steer])


def load_trajectory(name_or_path: str | Path, geom: Geometry = Geometry(),
                    limits: Limits = Limits()) -> Trajectory:
    """Load a named trajectory (``line``, ``circle``, ``curvilinear``: files in
    ``configs/trajectories``) or a ``.yaml`` / ``.csv`` file.

    A CSV file holds ``t,x,y`` samples (s, m, m), checked against ``limits`` before it is
    fitted (``docs/trajectories.md``); it gets ``tau = 0.016 s``,
    ``N = floor(tf / tau)``, :data:`DEFAULT_Q_DIAG`, :data:`DEFAULT_R_DIAG` and starts on the
    path. A YAML file is read by :mod:`swerve.configs.loader`. Raises :class:`ControllerError`
    (``FILE:LINE: KEY: problem`` for a YAML key) on anything malformed.
    """
    text = str(name_or_path)
    p = Path(text)
    if p.suffix.lower() not in (".yaml", ".yml", ".csv"):
        cand = TRAJECTORY_DIR / f"{text}.yaml"
        if not cand.is_file():
            names = sorted(f.stem for f in TRAJECTORY_DIR.glob("*.yaml"))
            raise ControllerError(f"unknown trajectory {text!r}: use one of {', '.join(names)}"
                                  " or a path to a .yaml or .csv file")
        p = cand
    if not p.is_file():
        raise ControllerError(f"trajectory file {p} does not exist")
    if p.suffix.lower() == ".csv":
        return load_csv_trajectory(p, geom, limits)
    top = read_yaml(p, ControllerError, "trajectory file").root()
    tau = top.number("tau_s", DEFAULT_TAU_S, positive=True, max=10.0)
    tf_given = top.number("tf_s", None, positive=True, max=TRAJ_DURATION_MAX_S)
    spec = top.section("path")
    path0 = _path_from_spec(spec, tf_given or 1.0, p.parent, geom, limits)
    tf = tf_given if tf_given is not None else path0.t_end_s
    n_float = tf / tau
    if n_float > N_STEPS_MAX and "n_steps" not in top:
        top.fail(f"tf_s / tau_s = {tf:g} s / {tau:g} s is {n_float:.0f} steps, more than the "
                 f"{N_STEPS_MAX} a gain schedule may hold (shorten tf_s or lengthen tau_s)", "tf_s")
    n = top.integer("n_steps", int(np.floor(n_float + 1e-9)), min=10, max=N_STEPS_MAX)
    if abs(n * tau - tf) > 1e-6 * max(tf, 1):
        top.fail(f"need tf_s = n_steps * tau_s (got {tf:g}, {n}, {tau:g})", "n_steps")
    if tf > path0.t_end_s + 1e-9:
        top.fail(f"tf_s = {tf:g} s is longer than the path ({path0.t_end_s:g} s)", "tf_s")
    Q = _diag(top, "Q_diag", 5, DEFAULT_Q_DIAG)
    R = _diag(top, "R_diag", 3, DEFAULT_R_DIAG)
    direction = path0.direction
    if "direction" in top:
        direction = top.choice("direction", {"forward": 1, "reverse": -1})
    start = (_start_from_spec(top.section("start"), path0, geom, direction) if "start" in top
             else None)
    name = top.string("name", p.stem)
    top.check_unknown()
    return Trajectory(name, path0, tf, n, tau, Q, R, start, str(p), direction)


def load_csv_trajectory(p: Path, geom: Geometry = Geometry(),
                        limits: Limits = Limits()) -> Trajectory:
    """A trajectory CSV file (format: ``docs/trajectories.md``), checked against ``geom`` and ``limits``, with
    ``tau = 0.016 s``, ``N = floor(tf / tau)``, :data:`DEFAULT_Q_DIAG`,
    :data:`DEFAULT_R_DIAG`, its ``# start`` line (else on the path) and its direction."""
    smp = read_csv_samples(p, limits, geom, DEFAULT_TAU_S)
    path = fit_samples(smp, CSV_TOLERANCE_M, CSV_BLEND_M, str(p))
    tf = path.t_end_s
    n = int(np.floor(tf / DEFAULT_TAU_S + 1e-9))
    if n < 10:
        raise ControllerError(f"{p}: path lasts {tf:.3f} s, too short for tau = 16 ms")
    if n > N_STEPS_MAX:
        raise ControllerError(f"{p}: path lasts {tf:g} s, {n} steps of 16 ms, more than the "
                              f"{N_STEPS_MAX} a gain schedule may hold")
    start = None if smp.start is None else np.array(smp.start, dtype=float)
    return Trajectory(p.stem, path, n * DEFAULT_TAU_S, n, DEFAULT_TAU_S,
                      np.diag(DEFAULT_Q_DIAG), np.diag(DEFAULT_R_DIAG), start, str(p),
                      smp.direction)
