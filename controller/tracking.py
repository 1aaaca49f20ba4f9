"""The online tracking law: chained-form time-varying LQ feedback, 62.5 Hz on the robot.

At time t with the robot's state estimate s (x, y, theta, delta1, delta2)::

    i   = floor(t / tau)                       gain-schedule step, frame phi_i
    x   = chained coordinates of s in the frame phi_i      (controller.chained)
    x~  = x - xd(t)          (heading component wrapped)
    u   = r ud(t) + K_i x~                      (sign convention u = ud + K x~)
    (v1, omega1, omega2) = inverse input map of u at s, then saturated

``phi_i = 0`` everywhere is the paper's plain law, singular where the travel direction is
parallel to the world y-axis. The default reference re-anchors the frame by multiples of
pi/2 (:func:`controller.reference.frame_schedule`), so ``|sigma - phi| <= 1.2 rad`` on the
reference; for the robot's own state the chained coordinates are evaluated with
``|cos(sigma - phi)|`` floored at :data:`STATE_MARGIN` (large heading errors saturate the
error instead of producing infinities).

Saturation: ``|v1| <= v1_max``, ``|omega| <= steer_rate_max`` and steering angles kept in
``[-steer_angle_max, steer_angle_max]``. The law has no integrator, so nothing inside it winds
up; what would wind up is the tracking error while the robot is held back by the limits. The
optional reference governor (``governor=True``) therefore slows the reference clock by
``r = min(1, v1_max / |v1 requested|)`` after each saturated step (and scales ``ud`` by r), so
the reference waits for the robot instead of running away.

Cost: :meth:`TrackingLaw.command` runs at the loop rate, so it is float math (``K_i x~`` by
:func:`core.small_linalg.matvec`: fixed order, the same bits whichever BLAS kernel numpy
would use) and takes the reference from :meth:`controller.reference.Reference.sample` (a
precomputed table on the grid, a scalar evaluation of the path off it); the vectorised numpy
functions it must agree with are pinned in tests/controller/test_tracking.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swerve.core import small_linalg as sl
from swerve.controller.chained import wrap_angle
from swerve.controller.errors import ControllerError, SingularityError
from swerve.controller.gains_io import GainSchedule
from swerve.controller.kinematics import Limits, wheel_commands
from swerve.controller.reference import Reference

#: Floor of |cos(sigma - phi)| used for the robot's own state (about 84 degrees).
STATE_MARGIN = 0.1
#: The plain chained law (fixed frame) refuses states with |cos(sigma)| below this.
PLAIN_MIN_MARGIN = 0.02


def _diagnostic(k: int, doc: str) -> property:
    """A :class:`LawOutput` property: its ``diagnostics[k]`` as a new float array."""
    return property(lambda self: np.array(self.diagnostics[k], dtype=float), doc=doc)


@dataclass(frozen=True, slots=True)
class LawOutput:
    """One step of :meth:`TrackingLaw.step`: the inputs, the steering goals and why.

    ``v1_mps`` (saturated ground speed of every wheel), ``omega1_radps``/``omega2_radps``
    (saturated front/rear steering rates), ``delta1_rad``/``delta2_rad`` (steering goals: the
    state's angles advanced by ``omega * tau`` and kept within the steering limit),
    ``finished`` (the reference has ended: inputs are zero, the diagnostics NaN),
    ``reference_time_s`` (the governor's clock), ``index`` (gain-schedule step, -1 when
    finished), ``phi_rad`` (chained frame), ``saturated`` (a limit was hit). The diagnostics
    are kept as the law computed them, floats, and read as arrays: :attr:`error` (5,) chained
    error ``x - xd``, :attr:`u` (3,) chained inputs ``r ud + K x~``, :attr:`ud` (3,) desired
    chained inputs, :attr:`raw` (3,) unsaturated ``(v1_mps, omega1_radps, omega2_radps)``,
    :attr:`desired_state` (5,) reference state ``(x_m, y_m, theta_rad, delta1_rad, delta2_rad)``
    (each access makes a new array, so a control loop reads them off its critical path).
    """

    v1_mps: float
    omega1_radps: float
    omega2_radps: float
    delta1_rad: float
    delta2_rad: float
    finished: bool
    reference_time_s: float
    index: int
    phi_rad: float
    saturated: bool
    #: ``(error, u, ud, raw, desired_state)``, sequences of 5, 3, 3, 3 and 5 floats.
    diagnostics: tuple

    @property
    def inputs(self) -> tuple[float, float, float]:
        """``(v1_mps, omega1_radps, omega2_radps)``, the saturated inputs."""
        return self.v1_mps, self.omega1_radps, self.omega2_radps

    error = _diagnostic(0, "Chained error ``x - xd`` (heading wrapped), shape (5,).")
    u = _diagnostic(1, "Chained inputs ``r ud + K x~``, shape (3,).")
    ud = _diagnostic(2, "Desired chained inputs, shape (3,).")
    raw = _diagnostic(3, "Unsaturated ``(v1_mps, omega1_radps, omega2_radps)``, shape (3,).")
    desired_state = _diagnostic(4, "Reference state ``(x_m, y_m, theta_rad, delta1_rad, delta2_rad)``, "
                                   "shape (5,).")

    @property
    def wheel_goals(self) -> np.ndarray:
        """The eight actuator goals ``[v1, v1, v1, v1, d1, d2, d2, d1]``, m/s and rad, shape (8,)."""
        return wheel_commands(self.v1_mps, self.delta1_rad, self.delta2_rad)


_NAN3, _NAN5 = (math.nan,) * 3, (math.nan,) * 5
_FINISHED = (_NAN5, _NAN3, _NAN3, _NAN3, _NAN5)


def _chained_terms(state, phi, geom, floor, sign_hint=0.0):
    """Chained coordinates and the pieces of the inverse input map, with |cos sigma'| floored.

    ``state``: 5 floats, ``phi``: frame (rad). Returns the chained state (5 floats), the terms
    ``(C, D, B1, B2, s1, s2, Kden)`` and the sign of cos(sigma') used. Inside the floored band
    that sign is taken from ``sign_hint`` (the previous step's) when given, so that the law
    does not flip between travelling forwards and backwards across the singular direction.
    """
    x, y, th, d1, d2 = state
    c, s = math.cos(phi), math.sin(phi)
    xr, yr, thr = c * x + s * y, -s * x + c * y, th - phi
    a, r2 = geom.a_m, geom.r2_m2
    c1, c2 = math.cos(d1 + thr), math.cos(d2 + thr)
    s1, s2 = math.sin(d1 + thr), math.sin(d2 + thr)
    D = a * (math.sin(d1) - math.sin(d2)) / r2
    B1, B2 = a * math.cos(d1) / r2, -a * math.cos(d2) / r2
    sig = 0.5 * (d1 + d2) + thr
    cs = math.cos(sig)
    floored = abs(cs) < floor
    sgn = math.copysign(1.0, sign_hint if (floored and sign_hint != 0) else cs)
    cs_f = sgn * max(abs(cs), floor)
    C = c1 + c2
    if floored:                 # scale the travel term as if |cos sigma'| were the floor
        C = 2 * cs_f * math.cos(0.5 * (d1 - d2))
    Kden = 2 * cs_f ** 2
    chained = (xr, D / C, thr, math.sin(sig) / cs_f, yr)
    return chained, (C, D, B1, B2, s1, s2, Kden), sgn


def _inverse_input_map(u, C, D, B1, B2, s1, s2, Kden):
    """``(v1, omega1, omega2)`` for chained inputs ``u`` (3 floats) with the floored terms of
    :func:`_chained_terms` (:func:`controller.chained.inputs_from_chained` otherwise).
    NaN where the map is singular or its inputs are not finite."""
    v1 = 2.0 * u[0] / C
    a11 = (B1 * C + D * s1) / C ** 2
    a12 = (B2 * C + D * s2) / C ** 2
    r1 = u[1] - v1 * D ** 2 * (s1 + s2) / (2.0 * C ** 2)
    r2 = u[2] * Kden - v1 * D
    den = a11 - a12
    if abs(den) < 1e-12 or not all(map(math.isfinite, (v1, r1, r2))):
        return math.nan, math.nan, math.nan
    w1 = (r1 - a12 * r2) / den
    return v1, w1, r2 - w1


def _steer_rate_limit(w, delta, w_max, delta_max, tau):
    """Steering rate ``w`` (rad/s) within ``+-w_max`` and such that the angle ``delta`` (rad)
    stays within ``+-delta_max`` over one step ``tau`` (s)."""
    w = min(max(w, -w_max), w_max)
    return min(max(w, min(0.0, (-delta_max - delta) / tau)), max(0.0, (delta_max - delta) / tau))


class TrackingLaw:
    """Chained-form LQ tracking law, usable at any rate (the robot runs it at 62.5 Hz).

    Parameters
    ----------
    reference : controller.reference.Reference
        Desired states/inputs (:func:`controller.reference.build_reference`).
    gains : controller.gains_io.GainSchedule
        ``K`` (N, 3, 5) on the same grid and frames as ``reference``.
    limits : controller.kinematics.Limits
        Wheel-speed and steering limits (``configs/robot.yaml``).
    governor : bool
        Slow the reference clock while the wheel speed saturates (see module docstring).

    Notes
    -----
    :meth:`step` (and :meth:`command`, :meth:`wheel_goals`) is stateful only through the
    governor (reference clock); call :meth:`reset` before a new run.
    """

    def __init__(self, reference: Reference, gains: GainSchedule, limits: Limits = Limits(),
                 governor: bool = True):
        if gains.n_steps != reference.n_steps or abs(gains.tau_s - reference.tau_s) > 1e-12:
            raise ControllerError(
                f"gain schedule ({gains.n_steps} steps of {gains.tau_s} s, trajectory "
                f"{gains.trajectory!r}) does not fit trajectory {reference.trajectory.name!r} "
                f"({reference.n_steps} steps of {reference.tau_s} s)")
        if not np.allclose(gains.phi_rad, reference.phi_rad[:-1]):
            raise ControllerError("gain schedule and reference use different chained frames "
                                  "(synthesised for the other law?)")
        self.reference = reference
        self.gains = gains
        self.limits = limits
        self.governor = governor
        self.plain = reference.frames == "fixed"
        self._phi = gains.phi_rad.tolist()
        self._K = gains.K.tolist()
        self.reset()

    def reset(self) -> None:
        """Restart the reference clock (call before each run; builds the reference's table)."""
        self.reference.prepare()
        self._t_prev = None
        self._s = 0.0
        self._rate = 1.0
        self._sign = 0.0
        self._phi_prev = None

    @property
    def reference_time_s(self) -> float:
        """Current reference time (equals t unless the governor has slowed it)."""
        return self._s

    def finished(self) -> bool:
        """True once the reference clock has reached tf."""
        return self._s >= self.reference.tf_s - 1e-9

    def command(self, t_s: float, state) -> tuple[float, float, float]:
        """Inputs ``(v1_mps, omega1_radps, omega2_radps)`` for the state estimate at ``t_s``
        (:meth:`step`'s saturated inputs; zeros once the reference has ended)."""
        return self.step(t_s, state).inputs

    def step(self, t_s: float, state) -> LawOutput:
        """One control step for the state estimate at ``t_s``: inputs, steering goals, diagnostics.

        Parameters
        ----------
        t_s : float
            Time since the start of the trajectory, s (non-decreasing between calls).
        state : array_like, shape (5,)
            ``(x_m, y_m, theta_rad, delta1_rad, delta2_rad)``.

        Returns a :class:`LawOutput` (zero inputs and ``finished`` once the reference has
        ended). Raises :class:`ControllerError` for a non-finite state and
        :class:`SingularityError` if the plain (fixed-frame) law meets the chained form's
        singular set.
        """
        try:
            st = list(map(float, state))
        except (TypeError, ValueError):
            st = []
        if len(st) != 5 or not all(map(math.isfinite, st)) or not math.isfinite(t_s):
            raise ControllerError(f"state must be 5 finite numbers, got {state!r} at t = {t_s}")
        self._advance_clock(float(t_s))
        lim, tau = self.limits, self.reference.tau_s
        dmax = lim.steer_angle_max_rad
        if self.finished():
            return LawOutput(0.0, 0.0, 0.0, min(max(st[3], -dmax), dmax), min(max(st[4], -dmax), dmax),
                             True, self._s, -1, math.nan, False, _FINISHED)
        i = self.reference.index(self._s)
        phi = self._phi[i]
        sd, _, xd, ud = self.reference.sample(self._s, phi)
        sig = 0.5 * (st[3] + st[4]) + st[2] - phi
        if self.plain and abs(math.cos(sig)) < PLAIN_MIN_MARGIN:
            raise SingularityError(
                f"at t = {t_s:.3f} s the robot travels parallel to the world y-axis "
                f"(sigma = {np.degrees(wrap_angle(sig)):.1f} deg): the paper's plain "
                "chained-form law is singular there; use the rotating-frame law",
                t_s=float(t_s))
        e, u, (v1, w1, w2) = self._feedback(st, i, phi, xd, ud)
        if not math.isfinite(v1):
            raise ControllerError(f"inverse input map is singular at t = {t_s:.3f} s "
                                  f"(state {np.round(st, 4).tolist()})")
        vmax, wmax = lim.v1_max_mps, lim.steer_rate_max_radps
        ws = [_steer_rate_limit(w, d, wmax, dmax, tau) for w, d in ((w1, st[3]), (w2, st[4]))]
        self._rate = min(1.0, vmax / abs(v1)) if v1 != 0 else 1.0
        return LawOutput(
            min(max(v1, -vmax), vmax), ws[0], ws[1],
            min(max(st[3] + ws[0] * tau, -dmax), dmax), min(max(st[4] + ws[1] * tau, -dmax), dmax),
            False, self._s, i, phi, abs(v1) > vmax or abs(w1) > wmax or abs(w2) > wmax,
            (e, u, ud, (v1, w1, w2), sd))

    def _feedback(self, st, i, phi, xd, ud):
        """The law at schedule step ``i`` (frame ``phi``) for the state ``st`` (5 floats).

        Returns the chained error ``x - xd`` (5 floats, heading wrapped, as
        :func:`controller.ltv.chained_error`), the chained inputs ``u = r ud + K_i x~`` (3 floats)
        and the unsaturated ``(v1, omega1, omega2)``, NaN where the input map is singular.
        """
        try:
            x, terms, self._sign = _chained_terms(
                st, phi, self.reference.geom, PLAIN_MIN_MARGIN if self.plain else STATE_MARGIN,
                self._sign if phi == self._phi_prev else 0.0)
        except ZeroDivisionError:   # c1 + c2 = 0 with |cos sigma'| above the floor
            return None, None, (math.nan,) * 3
        self._phi_prev = phi
        d = [a - b for a, b in zip(x, xd)]
        d[2] = (d[2] + math.pi) % (2 * math.pi) - math.pi
        r = self._rate if self.governor else 1.0
        u = [r * a + b for a, b in zip(ud, sl.matvec(self._K[i], d))]
        return d, u, _inverse_input_map(u, *terms)

    def _advance_clock(self, t_s: float) -> None:
        """Advance the reference clock to robot time ``t_s`` (at the governor's rate)."""
        if self._t_prev is None:
            self._s = max(t_s, 0.0)
        else:
            dt = t_s - self._t_prev
            if dt < 0:
                raise ControllerError(f"time went backwards ({self._t_prev} -> {t_s} s)")
            self._s += dt * (self._rate if self.governor else 1.0)
        self._t_prev = t_s

    def wheel_goals(self, t_s: float, state) -> np.ndarray:
        """The eight actuator goals ``[v1, v1, v1, v1, d1, d2, d2, d1]`` for one control step
        (:attr:`LawOutput.wheel_goals` of :meth:`step`). Shape (8,), m/s and rad."""
        return self.step(t_s, state).wheel_goals
