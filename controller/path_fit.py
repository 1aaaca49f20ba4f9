"""A path through drawn ``t, x, y`` samples that keeps their geometry, fitted in time linear in their number.

The samples are split into straight runs, circular arcs and free samples
(:mod:`controller.path_segments`). The path is described by its curvature over arc length,
``kappa(s)``, a quadratic B-spline: on a line its coefficients are fixed at 0, on an arc they
share one value, in a free stretch each is its own. A B-spline lies within the range of the
coefficients around it, so ``kappa`` is exactly 0 on straight runs, never exceeds an arc's
value, and between two primitives rises monotonically over ``blend_m``, centred on their
geometric junction, with the same total turn as the drawn corner. ``kappa`` is C1, so the desired
steering rate is continuous.

Heading is ``kappa``'s antiderivative (exact); position is integrated with 4-point
Gauss-Legendre on cells of a few millimetres. The coefficients, start point and start heading
are fitted to the samples by Levenberg-Marquardt over sliding windows of at most
:data:`WINDOW_PARAMS` parameters: each window starts from the state (point, heading) the
committed part of the path ends in, fits the samples up to the next window's first parameter
(so a straight run after it counts), projects the samples onto the curve and fits again, then
commits the first half of its parameters. The Jacobian is analytic (a curvature change at
``u`` turns the rest of the path about ``P(u)``), so a window costs ``O(samples x params)`` and
the whole fit ``O(n)``.

No BLAS or LAPACK call (``@``, ``np.linalg``) and no NumPy loop picked per CPU (``sin``,
``arctan2``, ``sum``): sums of products are sequential (``np.cumsum``) or
:func:`math.fsum`, the small normal equations are solved by :mod:`core.small_linalg`,
sines and cosines are :mod:`math`'s (:mod:`core.mathmap`). The fit's decisions and
bits are the same on every machine.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swerve.core import small_linalg as sl
from swerve.controller.errors import ControllerError
from swerve.controller.kinematics import Geometry, Limits
from swerve.core.mathmap import cos_sin, elementwise
from swerve.controller.path_csv import PathSamples, read_csv_samples
from swerve.controller.path_segments import Run, junctions, segment_samples, three_point_curvatures

#: Most parameters one window of the fit solves for (plus start point and heading in the first).
WINDOW_PARAMS = 12
#: Integration cell of the fit, m (Gauss-Legendre error far below a micrometre at 40 1/m).
FIT_CELL_M = 5e-3
#: Free curvature coefficients are spaced so the heading turns at most this much between them, rad.
FREE_TURN_RAD = 0.25
#: ... and hold at least this many samples between them (so noise is averaged, not fitted).
FREE_SAMPLES = 3
#: Levenberg-Marquardt iterations per round and rounds (fit, project, fit) per window.
LM_ITERATIONS = 30
ROUNDS = 1
#: A window's iterations stop when a nearly undamped step (damping at most the second number)
#: lowers the squared residuals by less than this fraction.
LM_RELATIVE_GAIN = 1e-2
LM_SMALL_DAMPING = 1e-2
#: Weight of the smoothness prior: a change of curvature of 1/m between neighbouring
#: coefficients costs as much as a sample this far (m) from the curve.
PRIOR_M = 2e-5
#: Least damping (relative to the normal matrix's diagonal).
LM_MIN_DAMPING = 1e-6
#: Damping increases (each a curve evaluation) tried before a window's iterations stop.
LM_TRIALS = 8
#: A window's iterations stop once the rms distance of its samples is below this fraction of
#: the tolerance.
FLOOR_FRACTION = 0.05
#: Samples closer than this along the path (m) mark a cusp check's scale: chords between
#: samples at least this far apart must not turn back.
CUSP_SCALE_M = 5e-3
#: The first estimate of the samples' arc length sums chords about this long, m (longer ones cut
#: tight turns short, shorter ones count drawing noise as length).
ARC_CHORD_M = 1e-2
#: Projections of consecutive samples onto the fitted path may step back by at most this many
#: rms distances of the samples from it (noise along the path); a longer step back is refused.
BACKSTEP_RMS = 4.0
#: The timing spline s(t) has a knot every this many samples.
TIMING_KNOT_SAMPLES = 8
#: A fit expected to take longer than about two seconds shows a progress bar (samples).
PROGRESS_SAMPLES = 20_000


def _gauss_legendre_4():
    """4-point Gauss-Legendre nodes (4,) and weights (4 floats) on [0, 1], in closed form."""
    a, b = (math.sqrt(3 / 7 + sg * 2 / 7 * math.sqrt(6 / 5)) for sg in (-1, 1))
    wa, wb = (18 + math.sqrt(30)) / 36, (18 - math.sqrt(30)) / 36
    nodes = np.array([0.5 * (1 - b), 0.5 * (1 - a), 0.5 * (1 + a), 0.5 * (1 + b)])
    return nodes, (0.5 * wb, 0.5 * wa, 0.5 * wa, 0.5 * wb)


_GL_X, _GL_W = _gauss_legendre_4()


def _gl_sum(f):
    """``sum_k f[..., k] _GL_W[k]`` added in index order, shape ``f.shape[:-1]``."""
    out = f[..., 0] * _GL_W[0]
    for k in range(1, len(_GL_W)):
        out = out + f[..., k] * _GL_W[k]
    return out


def _colsum(a):
    """Sum over axis 0 added in index order (``np.cumsum``'s last row): the same bits on every CPU."""
    return np.cumsum(a, axis=0)[-1]


class CurvatureCurve:
    """A planar curve given by its curvature ``kappa(s)`` over arc length ``s`` (m).

    Parameters
    ----------
    knots : ndarray, shape (m + 3,)
        Knot vector of the quadratic B-spline ``kappa``, m; the first and last three equal.
    coef : ndarray, shape (m,)
        Its coefficients, 1/m.
    start_m : (2,) start point, m.  theta0_rad : start heading, rad.  length_m : length, m.
    cell_m : integration cell of the position table, m.
    """

    def __init__(self, knots, coef, start_m, theta0_rad, length_m, cell_m=2e-3):
        self.knots = np.asarray(knots, float)
        self.coef = np.asarray(coef, float)
        self.length_m = float(length_m)
        from scipy.interpolate import BSpline  # ~0.4 s to import: only drawn paths load it

        self._k = BSpline(self.knots, self.coef, 2, extrapolate=True)
        self._dk = self._k.derivative()
        self._th = self._k.antiderivative()
        self._th0 = float(theta0_rad) - float(self._th(0.0))
        m = max(int(math.ceil(self.length_m / cell_m)), 1)
        self._grid = np.linspace(0.0, self.length_m, m + 1)
        steps = self._integrate(self._grid[:-1], np.diff(self._grid))
        self._P = np.asarray(start_m, float)[:, None] + np.concatenate(
            [np.zeros((2, 1)), np.cumsum(steps, axis=1)], axis=1)

    def _integrate(self, s0, ds):
        """``int_{s0}^{s0+ds} (cos, sin) theta``, arrays (n,) -> (2, n)."""
        c, s = cos_sin(self.heading(s0[:, None] + ds[:, None] * _GL_X))
        return np.stack([_gl_sum(c) * ds, _gl_sum(s) * ds])

    def heading(self, s):
        """Heading of travel ``theta(s)``, rad (unwrapped), shape of ``s``."""
        return self._th0 + self._th(s)

    def curvature(self, s):
        """``kappa(s)``, 1/m."""
        return self._k(s)

    def curvature_slope(self, s):
        """``d kappa / d s``, 1/m^2."""
        return self._dk(s)

    def position(self, s):
        """``P(s)``, m, shape (2, n), for ``0 <= s <= length_m``."""
        s = np.clip(np.atleast_1d(np.asarray(s, float)), 0.0, self.length_m)
        k = np.clip(np.searchsorted(self._grid, s, side="right") - 1, 0, len(self._grid) - 2)
        return self._P[:, k] + self._integrate(self._grid[k], s - self._grid[k])

    def project(self, p, s, iterations: int = 3):
        """Arc length (m, (n,)) of the points ``p`` (n, 2) nearest the curve, Newton from ``s``."""
        s = np.array(s, float)
        for _ in range(iterations):
            c, sn = cos_sin(self.heading(s))
            d = p.T - self.position(s)
            s = np.clip(s + d[0] * c + d[1] * sn, 0.0, self.length_m)
        return s


@dataclass(frozen=True)
class FitReport:
    """How far a fitted path is from its samples (all maxima over the samples).

    ``position_m``: distance of a sample from the curve. ``heading_rad``: curve heading versus
    the chord between consecutive samples, at the chord's middle. ``curvature_1pm``: fitted
    versus drawn curvature (0 on lines, the circle fit's on arcs, three-point estimates on free
    samples) outside the blends between primitives. ``overshoot``: largest
    ``|kappa| / |kappa_drawn| - 1`` over the arcs and their blends (``kappa_drawn``: the largest
    of the arc and its neighbours). ``lines``, ``arcs``, ``free``: counts of runs.
    ``evaluations``: curve evaluations the fit made (its work, summed over the windows).
    """

    position_m: float
    heading_rad: float
    curvature_1pm: float
    overshoot: float
    lines: int
    arcs: int
    free: int
    evaluations: int = 0

    def as_dict(self) -> dict:
        """The report under the keys that ``swerve sim`` prints."""
        return dict(fit_max_position_deviation_m=self.position_m,
                    fit_max_heading_deviation_rad=self.heading_rad,
                    fit_max_curvature_deviation_1pm=self.curvature_1pm,
                    fit_curvature_overshoot=self.overshoot,
                    fit_runs=dict(lines=self.lines, arcs=self.arcs, free=self.free))


def check_advances(t, p) -> None:
    """Refuse samples that stop or turn back (a cusp), before any fitting.

    ``t`` (n,) s, ``p`` (n, 2) m. Chords are taken between samples at least
    :data:`CUSP_SCALE_M` apart (finer steps are drawing noise); two consecutive chords that turn
    by 90 degrees or more are a cusp.
    """
    seg = np.hypot(*np.diff(p, axis=0).T)
    if np.any(seg == 0):
        i = int(np.argmax(seg == 0))
        raise ControllerError(f"samples {i + 1} and {i + 2} are at the same point (t = {t[i]:.3f} "
                              "s): the path stops there, which the tracking law cannot follow")
    s = np.concatenate([[0.0], np.cumsum(seg)])
    keep = [0]
    for i in range(1, len(p)):
        if s[i] - s[keep[-1]] >= CUSP_SCALE_M or i == len(p) - 1:
            keep.append(i)
    k = np.array(keep)
    if len(k) < 3:
        return
    d = np.diff(p[k], axis=0)
    back = d[1:, 0] * d[:-1, 0] + d[1:, 1] * d[:-1, 1] <= 0
    if np.any(back):
        m = int(np.argmax(back))
        # the turning point: the sample farthest along the chord before the turn
        seg_i = np.arange(k[m + 1], k[m + 2] + 1)
        along = (p[seg_i, 0] - p[k[m], 0]) * d[m, 0] + (p[seg_i, 1] - p[k[m], 1]) * d[m, 1]
        i = int(seg_i[int(np.argmax(along))])
        raise ControllerError(f"the path stops at t = {t[i]:.3f} s (sample {i + 1}) and turns back "
                              "(a cusp): the tracking law needs a direction of travel; split the "
                              "path there and mark the part driven backwards as reverse")


def _curvature_estimate(p, s, scale_m):
    """Curvature at every sample from its neighbours ``scale_m`` before and after (1/m, (n,))."""
    n = len(p)
    i = np.arange(n)
    a = np.clip(np.searchsorted(s, s - scale_m, side="right") - 1, 0, n - 1)
    b = np.clip(np.searchsorted(s, s + scale_m, side="left"), 0, n - 1)
    a = np.minimum(a, np.maximum(i - 1, 0))
    b = np.maximum(b, np.minimum(i + 1, n - 1))
    A, B, C = p[a], p[i], p[b]
    cross = (B[:, 0] - A[:, 0]) * (C[:, 1] - A[:, 1]) - (B[:, 1] - A[:, 1]) * (C[:, 0] - A[:, 0])
    den = (np.hypot(*(B - A).T) * np.hypot(*(C - B).T) * np.hypot(*(C - A).T))
    out = np.zeros(n)
    ok = den > 0
    out[ok] = 2.0 * cross[ok] / den[ok]
    return out


@dataclass(frozen=True)
class _Zone:
    """Runs of one kind merged: arc length ``lo_m``..``hi_m``, ``kind``, arc ``curvature_1pm``."""

    lo_m: float
    hi_m: float
    kind: str
    curvature_1pm: float


class _Layout:
    """Knots, coefficients and parameters of ``kappa``: coefficient ``j`` is 0 when
    ``param[j] < 0``, else the value of parameter ``param[j]``."""

    def __init__(self, zones, length_m, blend_m, kappa_at, spacing_at):
        half = 0.5 * blend_m
        knots = []
        for z in zones[1:]:
            knots += [z.lo_m - half, z.lo_m, z.lo_m + half]
        for z in zones:
            if z.kind != "free":
                continue
            u = z.lo_m
            while True:
                u += max(min(FREE_TURN_RAD / max(abs(kappa_at(u)), 1e-9), half), FREE_SAMPLES * spacing_at(u))
                if u >= z.hi_m:
                    break
                knots.append(u)
        knots = np.sort(np.clip(np.asarray(knots, float), 0.0, length_m))
        gap = blend_m / 20
        inner, last = [], 0.0
        for u in knots.tolist():
            if u - last >= gap and length_m - u >= gap:
                inner.append(u)
                last = u
        self.knots = np.array([0.0] * 3 + inner + [length_m] * 3)
        m = len(self.knots) - 3
        greville = 0.5 * (self.knots[1:m + 1] + self.knots[2:m + 2])
        bounds = np.array([z.lo_m for z in zones[1:]])
        zone_of = np.searchsorted(bounds, greville, side="right")
        param, init, arc_param = np.full(m, -1), [], {}
        for j, zi in enumerate(zone_of.tolist()):
            z = zones[zi]
            if z.kind == "line":
                continue
            if z.kind == "arc":
                if zi not in arc_param:
                    arc_param[zi] = len(init)
                    init.append(z.curvature_1pm)
                param[j] = arc_param[zi]
            else:
                param[j] = len(init)
                init.append(float(kappa_at(greville[j])))
        self.param = param
        self.init = np.array(init, float)
        # first and last coefficient of each parameter (an arc's coefficients are consecutive)
        n_par = len(init)
        self.first = np.full(n_par, m, int)
        self.last = np.full(n_par, -1, int)
        for j, q in enumerate(param.tolist()):
            if q >= 0:
                self.first[q] = min(self.first[q], j)
                self.last[q] = max(self.last[q], j)

    def coefficients(self, x):
        """Coefficients (m,) for parameter values ``x`` (n_par,)."""
        c = np.zeros(len(self.param))
        sel = self.param >= 0
        c[sel] = np.asarray(x, float)[self.param[sel]]
        return c


class _Window:
    """The curve from ``s_a`` on, given its start point and heading there, at fixed arc lengths.

    Heading is linear in the coefficients: ``theta(u) = theta_a + sum_j c_j (IB_j(u) - IB_j(s_a))``
    with ``IB_j`` the antiderivative of the ``j``-th quadratic B-spline. The cubic basis that
    gives ``IB_j`` is evaluated once at the integration nodes (cells from ``s_a`` and the
    partial cell before each query), so each evaluation costs ``O(nodes)`` and the derivative of
    the positions with respect to a parameter ``O(nodes)`` more.

    Parameters
    ----------
    knots : (m + 3,) knot vector of ``kappa``, m.  s_a : start, m.  s_q : (n,) query arc lengths, m.
    s_b : end of the cells, m (at least ``max(s_q)``).  cell_m : cell length, m.
    """

    def __init__(self, knots, s_a, s_q, s_b, cell_m):
        m = len(knots) - 3
        self.s_a = float(s_a)
        self.s_b = float(min(max(s_b, s_a), knots[-1]))
        i0 = int(np.searchsorted(knots, self.s_a, side="right")) - 1
        i1 = int(np.searchsorted(knots, self.s_b, side="right")) - 1
        self.ja = max(min(i0, m - 1) - 2, 0)
        self.jb = min(max(i1, 2) + 1, m)
        tl = knots[self.ja:self.jb + 3]
        self.dt3 = (tl[3:] - tl[:-3]) / 3.0                 # (n_loc,)
        n_cells = max(int(math.ceil((self.s_b - self.s_a) / cell_m)), 1)
        e = np.linspace(self.s_a, self.s_b, n_cells + 1)
        self.h = np.diff(e)
        s_q = np.clip(np.asarray(s_q, float), self.s_a, self.s_b)
        self.k = np.clip(np.searchsorted(e, s_q, side="right") - 1, 0, n_cells - 1)
        self.dl = s_q - e[self.k]
        full = e[:-1, None] + self.h[:, None] * _GL_X
        part = e[self.k][:, None] + self.dl[:, None] * _GL_X
        self.n_full, self.n_q = n_cells, len(s_q)
        u = np.concatenate([full.ravel(), part.ravel(), s_q, [self.s_a]])
        te = np.concatenate([tl[:1], tl, tl[-1:]])
        from scipy.interpolate import BSpline  # ~0.4 s to import: only drawn paths load it

        D = BSpline.design_matrix(u, te, 3, extrapolate=True)
        self._idx = D.indices.reshape(len(u), 4)
        self._val = D.data.reshape(len(u), 4)
        self._n_anti = len(te) - 4

    def _basis_sum(self, w):
        """``sum_i w_i N_i(u)`` at every node for weights ``w`` (n_anti,), added in index order."""
        out = self._val[:, 0] * w[self._idx[:, 0]]
        for r in range(1, 4):
            out = out + self._val[:, r] * w[self._idx[:, r]]
        return out

    def sensitivities(self, indicators):
        """``d theta / d x_q`` at the nodes, minus its value at ``s_a``, for each parameter's
        coefficient indicator (arrays (m,)): shape (nodes, len(indicators))."""
        cols = []
        for ind in indicators:
            w = np.cumsum(ind[self.ja:self.jb] * self.dt3)
            g = self._basis_sum(np.concatenate([[0.0], w]))
            cols.append(g - g[-1])
        return np.stack(cols, axis=1) if cols else np.zeros((self._val.shape[0], 0))

    def _split(self, a):
        nf, nq = 4 * self.n_full, 4 * self.n_q
        return (a[:nf].reshape(self.n_full, 4, *a.shape[1:]),
                a[nf:nf + nq].reshape(self.n_q, 4, *a.shape[1:]), a[nf + nq:nf + nq + self.n_q])

    def evaluate(self, c, P_a, th_a, G=None):
        """Positions (n, 2) and headings (n,) at the queries for coefficients ``c`` (m,); with
        ``G`` (nodes, p) from :meth:`sensitivities`, also their derivatives (n, 2, p)."""
        w = np.cumsum(c[self.ja:self.jb] * self.dt3)
        A = self._basis_sum(np.concatenate([[0.0], w]))
        th = th_a + (A - A[-1])
        cs, sn = cos_sin(th)
        cf, cp, _ = self._split(cs)
        sf, sp, _ = self._split(sn)
        h, dl = self.h, self.dl
        cell = np.stack([_gl_sum(cf) * h, _gl_sum(sf) * h], axis=-1)
        edges = np.concatenate([np.zeros((1, 2)), np.cumsum(cell, axis=0)])
        P = edges[self.k] + np.stack([_gl_sum(cp) * dl, _gl_sum(sp) * dl], axis=-1) + P_a
        if G is None:
            return P, self._split(th)[2], None
        gf, gp, _ = self._split(G)
        hh, dd = h[:, None], dl[:, None]
        cell = np.stack([-_gl_sum_mid(gf * sf[:, :, None]) * hh,
                         _gl_sum_mid(gf * cf[:, :, None]) * hh], axis=1)
        edges = np.concatenate([np.zeros((1,) + cell.shape[1:]), np.cumsum(cell, axis=0)])
        dP = edges[self.k] + np.stack([-_gl_sum_mid(gp * sp[:, :, None]) * dd,
                                       _gl_sum_mid(gp * cp[:, :, None]) * dd], axis=1)
        return P, self._split(th)[2], dP


def _gl_sum_mid(f):
    """``sum_k f[:, k, ...] _GL_W[k]`` added in index order (nodes on axis 1)."""
    out = f[:, 0] * _GL_W[0]
    for k in range(1, len(_GL_W)):
        out = out + f[:, k] * _GL_W[k]
    return out


def _fsum_sq(r) -> float:
    return math.fsum((r * r).ravel().tolist())


def _solve(win, layout, x, qs, P_a, th_a, pts, with_start, floor_m):
    """Levenberg-Marquardt on the parameters ``qs`` (and the start point and heading when
    ``with_start``) for the samples ``pts`` (k, 2) at the window's query arc lengths, until the
    rms distance is below ``floor_m`` or an iteration gains less than :data:`LM_RELATIVE_GAIN`.

    Returns the parameters (n_par,), the window's start point (2,) and heading, and the number
    of curve evaluations."""
    x = x.copy()
    n_q = len(qs)
    m = n_q + (3 if with_start else 0)
    inds = []
    for q in qs:
        ind = np.zeros(len(layout.param))
        ind[layout.param == q] = 1.0
        inds.append(ind)
    G = win.sensitivities(inds)
    evals = 0
    # smoothness prior: PRIOR_M times the change of kappa between neighbouring coefficients
    # that a window parameter moves (so a sparse or noisy stretch does not chase its noise)
    pairs = [j for j in range(max(win.ja, 1), win.jb)
             if any(ind[j] != ind[j - 1] for ind in inds)]
    Dp = np.array([[PRIOR_M * (ind[j] - ind[j - 1]) for ind in inds] + [0.0] * (m - n_q)
                   for j in pairs]).reshape(len(pairs), m)

    def prior(xx):
        c = layout.coefficients(xx)
        return np.array([PRIOR_M * (c[j] - c[j - 1]) for j in pairs])

    def unpack(z):
        xx = x.copy()
        xx[qs] = z[:n_q]
        if with_start:
            return xx, z[n_q:n_q + 2], float(z[n_q + 2])
        return xx, np.asarray(P_a, float), th_a

    z = np.concatenate([x[qs], [P_a[0], P_a[1], th_a]] if with_start else [x[qs]])
    lam = 1e-3
    for _ in range(LM_ITERATIONS if m else 0):
        xx, Pa, tha = unpack(z)
        P, _, dP = win.evaluate(layout.coefficients(xx), Pa, tha, G)
        evals += 1
        r = (P - pts).ravel()
        J = dP.reshape(2 * len(P), n_q)
        if with_start:
            ones, zeros = np.ones(len(P)), np.zeros(len(P))
            extra = np.stack([np.stack([ones, zeros], -1).ravel(),
                              np.stack([zeros, ones], -1).ravel(),
                              np.stack([-(P[:, 1] - Pa[1]), P[:, 0] - Pa[0]], -1).ravel()], axis=1)
            J = np.concatenate([J, extra], axis=1)
        rp = prior(xx)
        J = np.concatenate([J, Dp])
        r = np.concatenate([r, rp])
        A = [[0.0] * m for _ in range(m)]
        for a_ in range(m):
            row = _colsum(J[:, a_:a_ + 1] * J[:, a_:]).tolist()
            for b_, v in enumerate(row, start=a_):
                A[a_][b_] = A[b_][a_] = v
        g = _colsum(J * r[:, None]).tolist()
        cost = _fsum_sq(r)
        dmax = max(A[i][i] for i in range(m))
        if dmax == 0.0 or cost <= len(P) * floor_m * floor_m:
            break
        new = cost
        for _ in range(LM_TRIALS):
            M = [[A[i][j] + (lam * (A[i][i] + 1e-12 * dmax) if i == j else 0.0)
                  for j in range(m)] for i in range(m)]
            try:
                dz = np.array(sl.solve(M, [[-v] for v in g]))[:, 0]
            except sl.SingularMatrixError:
                lam *= 10
                continue
            xx, Pa, tha = unpack(z + dz)
            P, _, _ = win.evaluate(layout.coefficients(xx), Pa, tha)
            evals += 1
            new = _fsum_sq(np.concatenate([(P - pts).ravel(), prior(xx)]))
            if new < cost:
                z = z + dz
                lam = max(lam * 0.3, LM_MIN_DAMPING)
                break
            lam *= 10
        if not new < cost or (cost - new <= LM_RELATIVE_GAIN * cost and lam <= LM_SMALL_DAMPING):
            break
    xx, Pa, tha = unpack(z)
    return xx, np.asarray(Pa, float), tha, evals


def _free_ends(runs, s, blend_m, kappa):
    """Free the primitive next to a free end of the path shorter than ``blend_m`` (m): bending
    onto that end's samples within less than a blend would ask for a steering-rate spike.
    ``s`` (n,) arc lengths, m; ``kappa`` (n,) three-point curvatures, 1/m."""
    def short_free(run_list):
        k = 0
        while k < len(run_list) and run_list[k].kind == "free":
            k += 1
        if 0 < k < len(run_list) and abs(s[run_list[k - 1].last] - s[run_list[0].first]) < blend_m:
            nxt = run_list[k]
            lo, hi = sorted((nxt.first, nxt.last))
            return k, [Run(j, j + 1, "free", float(kappa[j])) for j in range(lo, hi)]
        return 0, None

    k, free = short_free(runs)
    if free is not None:
        runs = runs[:k] + free + runs[k + 1:]
    rev = [Run(r.last, r.first, r.kind, r.curvature_1pm) for r in reversed(runs)]
    k, free = short_free(rev)
    if free is not None:
        runs = runs[:len(runs) - k - 1] + free + runs[len(runs) - k:]
    return runs


def _arc_length_estimate(p, seg, chord_m):
    """Arc length of the samples ``p`` (n, 2), m, shape (n,): chords between samples about
    ``chord_m`` apart, shared out within each by the samples' own steps ``seg`` (n - 1,). Summing
    the samples' own steps would count drawing noise as length (a 1 mm jitter on samples 1 mm
    apart doubles it)."""
    raw = np.concatenate([[0.0], np.cumsum(seg)])
    keep = [0]
    for i in range(1, len(p)):
        if raw[i] - raw[keep[-1]] >= chord_m:
            keep.append(i)
    if keep[-1] != len(p) - 1:
        keep.append(len(p) - 1)
    k = np.array(keep)
    chords = np.hypot(*np.diff(p[k], axis=0).T)
    out = np.empty(len(p))
    out[k] = np.concatenate([[0.0], np.cumsum(chords)])
    for a, b, c in zip(k[:-1].tolist(), k[1:].tolist(), chords.tolist()):
        if b - a > 1:
            frac = (raw[a + 1:b] - raw[a]) / (raw[b] - raw[a])
            out[a + 1:b] = out[a] + frac * c
    return out


def _timing_spline(t, s):
    """``s(t)``: the least-squares quintic spline of the samples' arc lengths ``s`` (m) over their
    times ``t`` (s), both (n,), with a knot every :data:`TIMING_KNOT_SAMPLES` samples: one
    banded least-squares pass (FITPACK, no BLAS), linear in the samples, that averages their
    noise."""
    n = len(t)
    step = TIMING_KNOT_SAMPLES
    if n < 2 * step:
        step = max(n // 2, 1)
    inner = t[step:n - step + 1:step] if n > 2 * 5 + 2 else t[:0]
    inner = inner[(inner > t[0]) & (inner < t[-1])]
    from scipy.interpolate import LSQUnivariateSpline  # ~0.4 s to import: only drawn paths load it

    return LSQUnivariateSpline(t, s, inner, k=min(5, n - 1))


class FittedPath:

    """A path through ``t, x, y`` samples that keeps the drawn geometry.

    Parameters
    ----------
    t_s, x_m, y_m : array_like, shape (n,)
        Sample times (s, strictly increasing) and positions (m).
    tolerance_m : float
        Lines and arcs are recognised within this distance of the samples, m.
    blend_m : float
        Length over which curvature blends between two primitives, m.
    direction : int
        +1: the body faces the direction of travel; -1: driven in reverse (v1 < 0).
    progress : bool or None
        Progress bar on stderr for a fit of more than :data:`PROGRESS_SAMPLES` samples
        (``None``: only on a terminal).

    Time enters only through the arc length travelled, ``s(t)``: a least-squares quintic spline
    of the samples' projections onto the curve (:func:`_timing_spline`). ``report`` is a
    :class:`FitReport`.

    Raises
    ------
    ControllerError
        Samples at one point, a cusp (the time and sample), or samples that do not advance
        along the fitted curve.
    """

    def __init__(self, t_s, x_m, y_m, tolerance_m: float = 2e-5, blend_m: float = 0.05,
                 direction: int = 1, progress: bool | None = None):
        t = np.asarray(t_s, dtype=float)
        t = t - t[0]
        p = np.column_stack([np.asarray(x_m, float), np.asarray(y_m, float)])
        check_advances(t, p)
        seg = np.hypot(*np.diff(p, axis=0).T)
        s = _arc_length_estimate(p, seg, ARC_CHORD_M)
        self.direction = 1 if direction >= 0 else -1
        self.tolerance_m, self.blend_m = float(tolerance_m), float(blend_m)
        runs = segment_samples(p, tol_m=self.tolerance_m, min_run_m=self.blend_m)
        # a lone free sample between two primitives straddles their junction: drop it
        runs = [r for k, r in enumerate(runs)
                if not (r.kind == "free" and 0 < k < len(runs) - 1
                        and runs[k - 1].kind != "free" and runs[k + 1].kind != "free")]
        runs = _free_ends(runs, s, self.blend_m, three_point_curvatures(p))
        self.runs = runs
        zones, junc = self._zones(runs, p, s)
        L = float(s[-1])
        kap = _curvature_estimate(p, s, 0.5 * self.blend_m)
        spacing = np.concatenate([np.diff(s), np.diff(s)[-1:]])

        def at(arr):
            return lambda u: arr[min(int(np.searchsorted(s, u)), len(s) - 1)]
        layout = _Layout(zones, L, self.blend_m, at(kap), at(spacing))
        self._layout = layout
        # start heading along the chord to the first sample half a blend away (noise-proof)
        d0 = p[min(max(int(np.searchsorted(s, 0.5 * self.blend_m)), 1), len(p) - 1)] - p[0]
        x, start, th0, s_fit, evals = self._fit(layout, p, s, np.array(p[0]),
                                                math.atan2(d0[1], d0[0]), progress)
        curve = CurvatureCurve(layout.knots, layout.coefficients(x), start, th0, L)
        s_fit = curve.project(p, s_fit)
        s_fit[0] = 0.0
        resid = p.T - curve.position(s_fit)
        # the drawing noise, robustly (the blends' systematic deviation is not noise)
        rms = max(1.4826 * float(np.median(np.hypot(*resid))), 0.1 * self.tolerance_m)
        # drawing noise moves samples along the path too: a step back within it is smoothed
        # by s(t) below; a longer one is a turn back
        back = np.diff(s_fit) <= -BACKSTEP_RMS * rms
        if np.any(back) or s_fit[-1] <= 0.0:
            i = int(np.argmax(back))
            raise ControllerError(f"samples {i + 1} and {i + 2} (t = {t[i]:.3f} s) do not advance "
                                  "along the fitted path (a cusp, or a turn sharper than the "
                                  "samples resolve)")
        self.curve = CurvatureCurve(layout.knots, layout.coefficients(x), start, th0,
                                    float(s_fit.max()))
        self.sample_arc_m = s_fit
        self.t_end_s = float(t[-1])
        self._s_of_t = _timing_spline(t, s_fit)
        self.samples = (t, p)
        self.report = self._report(p, s_fit, junc, evals)

    @staticmethod
    def _zones(runs, p, s):
        """Merge consecutive free runs and place the zone boundaries at the geometric junctions."""
        merged: list[Run] = []
        for r in runs:
            if merged and r.kind == "free" and merged[-1].kind == "free":
                merged[-1] = Run(merged[-1].first, r.last, "free", 0.0)
            else:
                merged.append(r)
        junc = junctions(merged, p, s)
        bounds = [0.0] + junc + [float(s[-1])]
        zones = [_Zone(bounds[k], bounds[k + 1], r.kind, r.curvature_1pm)
                 for k, r in enumerate(merged)]
        return zones, junc

    def _fit(self, layout, p, s, start, th0, progress):
        """Sliding-window Levenberg-Marquardt: parameter values (n_par,), start point (2,),
        start heading, the samples' arc lengths (n,) and the number of curve evaluations."""
        x = layout.init.copy()
        n_par = len(x)
        knots = layout.knots
        s_fit = s.copy()
        P_a, th_a, s_a = start.astype(float), float(th0), 0.0
        start_state = (P_a, th_a)
        first_window, q0, evals = True, 0, 0
        if progress is None:
            progress = len(p) > PROGRESS_SAMPLES and sys.stderr.isatty()
        from tqdm import tqdm  # as the Riccati and CG progress bars: only a fit loads it

        bar = tqdm(total=max(n_par, 1), desc="fitting path", unit="param", leave=False,
                   disable=not progress)
        while True:
            q1 = min(q0 + WINDOW_PARAMS, n_par)
            final = q1 == n_par
            s_end = knots[-1] if final else float(knots[layout.first[q1]])
            lo = 0 if first_window else int(np.searchsorted(s_fit, s_a, side="left"))
            hi = int(np.searchsorted(s_fit, s_end, side="right"))
            sel = slice(lo, max(hi, lo + 1))
            qs = list(range(q0, q1))
            for _ in range(ROUNDS):
                ss = s_fit[sel]
                s_b = max(min(float(ss.max()) + self.blend_m, float(knots[-1])), s_end)
                win = _Window(knots, s_a, ss, s_b, FIT_CELL_M)
                x, P_a, th_a, n_ev = _solve(win, layout, x, qs, P_a, th_a, p[sel], first_window,
                                            FLOOR_FRACTION * self.tolerance_m)
                evals += n_ev
                c = layout.coefficients(x)
                for _ in range(3):
                    P, th, _ = win.evaluate(c, P_a, th_a)
                    cs, sn = cos_sin(th)
                    d = p[sel] - P
                    ss = np.clip(ss + d[:, 0] * cs + d[:, 1] * sn, win.s_a, win.s_b)
                    win = _Window(knots, s_a, ss, s_b, FIT_CELL_M)
                    evals += 1
                s_fit[sel] = ss
                if first_window:
                    s_fit[0] = 0.0
                    start_state = (P_a, th_a)
            if final:
                bar.update(q1 - q0)
                break
            qn = q0 + max((q1 - q0) // 2, 1)
            bar.update(qn - q0)
            s_next = float(knots[layout.first[qn]])
            win = _Window(knots, s_a, [s_next], s_next, FIT_CELL_M)
            P, th, _ = win.evaluate(layout.coefficients(x), P_a, th_a)
            P_a, th_a = P[0], float(th[0])
            evals += 1
            s_a, q0, first_window = s_next, qn, False
        bar.close()
        return x, start_state[0], start_state[1], s_fit, evals

    def _report(self, p, s_fit, junc, evals):
        c = self.curve
        d = p.T - c.position(s_fit)
        pos = float(np.hypot(*d).max())
        chord = np.diff(p, axis=0)
        hd = elementwise(math.atan2, chord[:, 1], chord[:, 0])
        mid = 0.5 * (s_fit[1:] + s_fit[:-1])
        dev = (c.heading(mid) - hd + np.pi) % (2 * np.pi) - np.pi
        head = float(np.abs(dev).max())
        half = 0.5 * self.blend_m
        jj = np.asarray(junc, float)
        near = np.zeros(len(p), bool)
        if len(jj):
            k = np.clip(np.searchsorted(jj, s_fit), 1, len(jj)) - 1
            near = np.abs(s_fit - jj[k]) <= half
            k2 = np.clip(k + 1, 0, len(jj) - 1)
            near |= np.abs(s_fit - jj[k2]) <= half
        kap = c.curvature(s_fit)
        drawn = np.zeros(len(p))
        over = 0.0
        for k, run in enumerate(self.runs):
            drawn[run.first:run.last + 1] = run.curvature_1pm
            if run.kind == "arc":
                lo, hi = s_fit[run.first] - half, s_fit[run.last] + half
                ss = np.linspace(lo, hi, 200)
                peak = max(abs(r.curvature_1pm) for r in self.runs[max(k - 1, 0):k + 2])
                over = max(over, float(np.abs(c.curvature(ss)).max() / peak) - 1.0)
        for run in self.runs:       # end samples shared with a neighbour keep their own run's
            if run.kind != "free":
                drawn[run.first + 1:run.last] = run.curvature_1pm
        err = np.abs(kap - drawn)[~near]
        n = {k: sum(r.kind == k for r in self.runs) for k in ("line", "arc", "free")}
        return FitReport(pos, head, float(err.max()) if err.size else 0.0, max(over, 0.0),
                         n["line"], n["arc"], n["free"], evals)

    def derivatives(self, t):
        """Position, velocity, acceleration and jerk at times ``t`` (s): shape (4, 2, len(t))."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.t_end_s)
        c = self.curve
        s = np.clip(self._s_of_t(t), 0.0, c.length_m)
        v, a, j = (self._s_of_t(t, nu) for nu in (1, 2, 3))
        th = c.heading(s)
        k, dk = c.curvature(s), c.curvature_slope(s)
        T = np.array(cos_sin(th))
        N = np.array([-T[1], T[0]])
        P = c.position(s)
        vel = v * T
        acc = a * T + v * v * k * N
        v3 = v * v * v
        jerk = (j - v3 * k * k) * T + (3 * v * a * k + v3 * dk) * N
        return np.array([P, vel, acc, jerk])


def fit_samples(smp: PathSamples, tolerance_m: float = 2e-5, blend_m: float = 0.05,
                source: str = "path", progress: bool | None = None) -> FittedPath:
    """:class:`FittedPath` of :class:`~controller.path_csv.PathSamples`; errors name ``source``."""
    try:
        return FittedPath(smp.t_s, smp.x_m, smp.y_m, tolerance_m, blend_m, smp.direction, progress)
    except ControllerError as exc:
        raise ControllerError(f"{source}: {exc}", file=source) from None


def read_csv_path(path: str | Path, tolerance_m: float = 2e-5, blend_m: float = 0.05,
                  limits: Limits = Limits(), geom: Geometry = Geometry()) -> FittedPath:
    """A :class:`FittedPath` through the samples of a trajectory CSV file, checked first
    (:func:`controller.path_csv.read_csv_samples`)."""
    return fit_samples(read_csv_samples(path, limits, geom), tolerance_m, blend_m, str(path))
