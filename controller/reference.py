"""References: desired states and inputs of a trajectory on its time grid.

:func:`build_reference` samples a :class:`~controller.trajectory.Trajectory` on
``t_i = i tau`` (``i = 0..N``) with the body aligned with the path (``theta_d = atan2(y', x')``,
unwrapped) and symmetric steering, and assigns each step a chained-form frame angle ``phi_i``
(see :func:`frame_schedule`).

Only ``+ - * /``, ``sqrt`` and :mod:`math`'s functions (mapped over arrays by
:func:`core.mathmap.elementwise`) enter the numbers: NumPy's ``sin``, ``arctan2``, ``power``, ...
take SIMD loops picked per CPU, which differ in the last bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from swerve.controller.chained import to_chained, wrap_angle
from swerve.controller.errors import ControllerError, SingularityError
from swerve.controller.kinematics import Geometry, Limits
from swerve.core.mathmap import elementwise

if TYPE_CHECKING:
    from swerve.controller.trajectory import Trajectory

#: Below this speed (m/s) a path counts as stopped (standstill or cusp).
MIN_SPEED_MPS = 2e-3
#: Hysteresis of the frame schedule: re-anchor when the travel direction is more than this
#: (rad) from the frame's x-axis (mod pi); the new frame puts it within pi/4.
FRAME_SWITCH_RAD = 1.2
#: The plain chained form (fixed frame) refuses references with |cos(sigma)| below this.
FIXED_FRAME_MIN_MARGIN = 0.05

def desired_states(path, t, geom: Geometry = Geometry(), direction: int = 1):
    """Desired states and inputs of a path (body along the velocity, symmetric steering).

    ``direction = -1``: driven in reverse (heading opposite to travel, v1 < 0, steering
    mirrored so that the body still turns with the path).

    Returns
    -------
    states : ndarray, shape (n, 5)
        ``(x, y, theta_d, delta, -delta)``, ``theta_d`` unwrapped along ``t``.
    inputs : ndarray, shape (n, 3)
        ``(v1, omega, -omega)``.
    extra : dict
        ``speed_mps``, ``curvature_1pm``, ``theta_rate_radps``, ``theta_acc_radps2`` and the raw
        ``derivatives`` (4, 2, n).
    """
    der = path.derivatives(t)
    p, v, a, j = der
    V2 = v[0] * v[0] + v[1] * v[1]
    V = np.sqrt(V2)
    V3 = V2 * V
    cross = v[0] * a[1] - v[1] * a[0]
    dot = v[0] * a[0] + v[1] * a[1]
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = cross / V3
        kappa_dot = (v[0] * j[1] - v[1] * j[0]) / V3 - 3 * cross * dot / (V3 * V2)
        th_rate = cross / V2
        th_acc = (v[0] * j[1] - v[1] * j[0]) / V2 - 2 * cross * dot / (V2 * V2)
    theta = np.unwrap(elementwise(math.atan2, v[1], v[0]))
    if direction < 0:
        theta = theta + math.pi
    q = geom.r2_m2 / geom.a_m
    qk = q * kappa
    delta = direction * elementwise(math.atan, qk)
    delta_rate = direction * q * kappa_dot / (1 + qk * qk)
    v1 = direction * V / elementwise(math.cos, delta)
    states = np.stack([p[0], p[1], theta, delta, -delta], axis=-1)
    inputs = np.stack([v1, delta_rate, -delta_rate], axis=-1)
    extra = dict(speed_mps=V, curvature_1pm=kappa, theta_rate_radps=th_rate,
                 theta_acc_radps2=th_acc, derivatives=der)
    return states, inputs, extra


def chained_desired(states, extra, phi, geom: Geometry = Geometry()):
    """Desired chained state and inputs (11)-(18) in the frame ``phi`` (rad, shape (n,)).

    ``xd = (x', theta_rate/x'_dot, theta - phi, y'_dot/x'_dot, y')``, ``ud1 = x'_dot``,
    ``ud2 = d/dt xd2``, ``ud3 = d/dt xd4``. Returns ``xd`` (n, 5) and ``ud`` (n, 3).
    """
    _, v, a, _ = extra["derivatives"]
    c, s = elementwise(math.cos, phi), elementwise(math.sin, phi)
    vx, vy = c * v[0] + s * v[1], -s * v[0] + c * v[1]
    ax, ay = c * a[0] + s * a[1], -s * a[0] + c * a[1]
    xd = to_chained(states, geom, phi)
    thr, tha = extra["theta_rate_radps"], extra["theta_acc_radps2"]
    vx2 = vx * vx
    ud = np.stack([vx, (tha * vx - thr * ax) / vx2, (ay * vx - vy * ax) / vx2], axis=-1)
    return xd, ud


def sample_at(der, theta_near: float, phi: float, geom: Geometry = Geometry(),
              direction: int = 1):
    """Scalar twin of :func:`desired_states` + :func:`chained_desired` at one time.

    Parameters
    ----------
    der : sequence of 8 floats
        The path's derivatives ``(px, py, vx, vy, ax, ay, jx, jy)`` at that time (m, m/s, ...).
    theta_near : float
        An unwrapped heading near the answer, rad: ``theta_d`` is taken on its branch.
    phi : float
        Chained frame, rad.
    direction : int
        +1 forwards, -1 reverse (see :func:`desired_states`).

    Returns
    -------
    (state, inputs, xd, ud) : tuples of 5, 3, 5 and 3 floats
        The same numbers as the vectorised functions (same operations in the same order).

    Raises
    ------
    ZeroDivisionError
        Where those return inf/NaN (the path stops, or travels along the frame's y-axis).
    """
    px, py, vx, vy, ax, ay, jx, jy = der
    # desired_states
    V2 = vx * vx + vy * vy
    V = math.sqrt(V2)
    V3 = V2 * V
    cross = vx * ay - vy * ax
    dot = vx * ax + vy * ay
    kappa = cross / V3
    kappa_dot = (vx * jy - vy * jx) / V3 - 3 * cross * dot / (V3 * V2)
    th_rate = cross / V2
    th_acc = (vx * jy - vy * jx) / V2 - 2 * cross * dot / (V2 * V2)
    heading = math.atan2(vy, vx)
    if direction < 0:
        heading = heading + math.pi
    theta = theta_near + ((heading - theta_near + math.pi) % (2 * math.pi) - math.pi)
    q = geom.r2_m2 / geom.a_m
    qk = q * kappa
    delta = direction * math.atan(qk)
    delta_rate = direction * q * kappa_dot / (1 + qk * qk)
    state = (px, py, theta, delta, -delta)
    inputs = (direction * V / math.cos(delta), delta_rate, -delta_rate)
    # chained_desired (delta2 = -delta)
    c, s = math.cos(phi), math.sin(phi)
    vxr, vyr = c * vx + s * vy, -s * vx + c * vy
    axr, ayr = c * ax + s * ay, -s * ax + c * ay
    thr = theta - phi
    D = geom.a_m * (math.sin(delta) - math.sin(-delta)) / geom.r2_m2
    C = math.cos(delta + thr) + math.cos(-delta + thr)
    xd = (c * px + s * py, D / C, thr, math.tan(0.5 * (delta + -delta) + thr), -s * px + c * py)
    vx2 = vxr * vxr
    ud = (vxr, (th_acc * vxr - th_rate * axr) / vx2, (ayr * vxr - vyr * axr) / vx2)
    return state, inputs, xd, ud


def frame_schedule(theta_d, mode: str = "rotating", switch_rad: float = FRAME_SWITCH_RAD):
    """Chained-form frame angle ``phi_i`` for each sample of the unwrapped heading ``theta_d``.

    ``mode="fixed"``: ``phi = 0`` (the paper). ``mode="rotating"``: start at 0 unless the path
    starts more than ``switch_rad`` from the x-axis (mod pi); whenever the travel direction gets
    more than ``switch_rad`` (mod pi) from the frame's x-axis, re-anchor to the multiple of pi/2
    nearest to it. The chained states then stay bounded by ``tan(switch_rad)``.
    """
    th = np.asarray(theta_d, dtype=float)
    if mode == "fixed":
        return np.zeros_like(th)
    if mode != "rotating":
        raise ControllerError(f"frame mode must be 'rotating' or 'fixed', got {mode!r}")
    phi = np.empty_like(th)
    cur = 0.0
    for i, t in enumerate(th):
        dev = (t - cur + np.pi / 2) % np.pi - np.pi / 2
        if abs(dev) > switch_rad:
            cur = cur + np.pi / 2 * np.round((t - cur) / (np.pi / 2))
        phi[i] = cur
    return phi


@dataclass
class Reference:
    """A trajectory sampled on ``t_i = i tau``, ``i = 0..N``.

    Arrays: ``times_s`` (N+1,), ``states`` (N+1, 5) desired states, ``inputs`` (N+1, 3) desired
    ``(v1, omega1, omega2)``, ``phi_rad`` (N+1,) chained frame of each step, ``xd`` (N+1, 5) and
    ``ud`` (N+1, 3) desired chained state and inputs in the frame ``phi_rad[i]``.
    """

    trajectory: Trajectory
    geom: Geometry
    times_s: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    phi_rad: np.ndarray
    xd: np.ndarray
    ud: np.ndarray
    frames: str = "rotating"
    extra: dict = field(default_factory=dict, repr=False)

    @property
    def tau_s(self) -> float:
        return self.trajectory.tau_s

    @property
    def n_steps(self) -> int:
        return self.trajectory.n_steps

    @property
    def tf_s(self) -> float:
        return self.trajectory.tf_s

    def start_state(self) -> np.ndarray:
        """The robot's start state, shape (5,)."""
        return self.trajectory.start_state(self.geom)

    def index(self, t_s: float) -> int:
        """Gain-schedule index in force at time ``t_s``: ``floor(t / tau)`` within [0, N-1]."""
        return math.floor(min(max(t_s / self.tau_s + 1e-9, 0.0), self.n_steps - 1))

    def at(self, t_s: float, phi_rad: float | None = None):
        """Desired state (5,), inputs (3,), chained state (5,) and inputs (3,) at ``t_s``.

        The chained values are in the frame ``phi_rad`` (default: that of :meth:`index`).
        ``theta_d`` is unwrapped consistently with the sampled grid. Arrays of :meth:`sample`.
        """
        return tuple(np.array(v) for v in self.sample(t_s, phi_rad))

    def sample(self, t_s: float, phi_rad: float | None = None):
        """:meth:`at` as tuples of floats ``(state, inputs, xd, ud)``: the tracking law's path.

        On the grid (``t_s == times_s[i]`` and frame ``phi_rad[i]``, the usual case while the
        reference governor does not slow the clock) a table lookup; elsewhere the path is
        evaluated at ``t_s`` (:func:`sample_at`). Raises :class:`ControllerError` where the
        reference is undefined.
        """
        t = float(min(max(t_s, 0.0), self.tf_s))
        i = self.index(t)
        times, phis, thetas, rows = self._grid
        phi = phis[i] if phi_rad is None else float(phi_rad)
        if t == times[i] and phi == phis[i]:
            return rows[i]
        der = self.trajectory.path.derivatives(np.array([t])).reshape(8).tolist()
        try:
            return sample_at(der, thetas[i], phi, self.geom, self.trajectory.direction)
        except ZeroDivisionError:
            raise ControllerError(f"the reference is undefined at t = {t:.3f} s (the path stops, "
                                  "or travels along the chained frame's y-axis)") from None

    def prepare(self) -> None:
        """Build :meth:`sample`'s grid table now (40–100 ms for the paper's paths), not in the
        first cycle of a timed loop."""
        self._grid  # noqa: B018 - evaluating the cached property is the point

    @cached_property
    def _grid(self):
        """Lists ``times_s[i]``, ``phi_rad[i]``, ``states[i, 2]`` and rows
        ``(state, inputs, xd, ud)`` for ``i = 0..N-1``: the values :func:`sample_at` gives at
        the grid times, evaluated once with the vectorised functions."""
        N = self.n_steps
        v = self.extra["derivatives"][1]
        states = self.states.copy()
        heading = (elementwise(math.atan2, v[1], v[0])
                   + (math.pi if self.trajectory.direction < 0 else 0.0))
        states[:, 2] += wrap_angle(heading - states[:, 2])  # as sample_at does
        xd, ud = chained_desired(states, self.extra, self.phi_rad, self.geom)
        rows = zip(*(map(tuple, a[:N].tolist()) for a in (states, self.inputs, xd, ud)))
        return (self.times_s[:N].tolist(), self.phi_rad[:N].tolist(),
                self.states[:N, 2].tolist(), list(rows))


def build_reference(traj: Trajectory, geom: Geometry = Geometry(), limits: Limits = Limits(),
                    frames: str = "rotating") -> Reference:
    """Sample a trajectory on its time grid and check that the robot can follow it.

    Raises
    ------
    ControllerError
        The path stops (cusp, standstill), needs a wheel speed above ``limits.v1_max_mps`` or a
        steering angle/rate beyond the limits, or has non-finite values.
    SingularityError
        ``frames="fixed"`` (the paper's plain chained form) and the path's direction of travel
        becomes parallel to the world y-axis.
    """
    N, tau = traj.n_steps, traj.tau_s
    t = np.arange(N + 1) * tau
    states, inputs, extra = desired_states(traj.path, t, geom, traj.direction)
    name = traj.name
    if not (np.all(np.isfinite(extra["derivatives"]))):
        raise ControllerError(f"trajectory {name!r}: the path has NaN or infinite values")
    V = extra["speed_mps"]
    if V.min() < MIN_SPEED_MPS:
        i = int(np.argmin(V))
        raise ControllerError(
            f"trajectory {name!r} stops at t = {t[i]:.3f} s (speed {V[i]:.2g} m/s): a cusp or "
            "standstill has no direction of travel, which the tracking law needs")
    if not np.all(np.isfinite(states)) or not np.all(np.isfinite(inputs)):
        raise ControllerError(f"trajectory {name!r}: desired states are not finite")
    i = int(np.argmax(np.abs(inputs[:, 0])))
    if abs(inputs[i, 0]) > limits.v1_max_mps:
        raise ControllerError(
            f"trajectory {name!r} needs wheel speed {inputs[i, 0]:.3f} m/s at t = {t[i]:.2f} s, "
            f"above the limit v1_max = {limits.v1_max_mps} m/s: slow the path down")
    i = int(np.argmax(np.abs(states[:, 3])))
    if abs(states[i, 3]) > limits.steer_angle_max_rad:
        raise ControllerError(f"trajectory {name!r} needs steering {states[i, 3]:.2f} rad at "
                              f"t = {t[i]:.2f} s, beyond {limits.steer_angle_max_rad} rad")
    i = int(np.argmax(np.abs(inputs[:, 1])))
    if abs(inputs[i, 1]) > limits.steer_rate_max_radps:
        raise ControllerError(
            f"trajectory {name!r} needs steering rate {inputs[i, 1]:.2f} rad/s at "
            f"t = {t[i]:.2f} s, above the servo's {limits.steer_rate_max_radps} rad/s")
    phi = frame_schedule(states[:, 2], frames)
    margin = np.abs(elementwise(math.cos, states[:, 2] - phi))
    if frames == "fixed" and margin.min() < FIXED_FRAME_MIN_MARGIN:
        i = int(np.argmin(margin))
        raise SingularityError(
            f"trajectory {name!r} crosses the chained form's singular set at t = {t[i]:.2f} s "
            "(direction of travel parallel to the world y-axis, where x2, x4, u2, u3 are "
            "unbounded): the paper's plain chained-form law cannot track it; use the rotating "
            "frame law (--law rotating)", t_s=float(t[i]))
    xd, ud = chained_desired(states, extra, phi, geom)
    if not (np.all(np.isfinite(xd)) and np.all(np.isfinite(ud))):
        raise ControllerError(f"trajectory {name!r}: chained reference is not finite")
    return Reference(traj, geom, t, states, inputs, phi, xd, ud, frames, extra)
