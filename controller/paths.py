"""Smooth planar paths ``t -> (x(t), y(t))`` with derivatives up to the third.

Every path has ``derivatives(t) -> ndarray shape (4, 2, len(t))``: position (m), velocity
(m/s), acceleration (m/s^2) and jerk (m/s^3) at the times ``t`` (s), and ``t_end_s``.

The fit of samples makes no BLAS or LAPACK call (``@``, ``np.linalg``; SciPy's MINPACK and
FITPACK use none either): their kernels are picked per CPU and round differently, and the fit's
decisions (which samples form a line or an arc) would follow those bits. Sums of products are
written out elementwise or taken with :func:`math.fsum` (correctly rounded). Sines, cosines and
arc tangents are :mod:`math`'s, mapped over the arrays (:mod:`controller.mathmap`): NumPy's own loops
for them are picked per CPU (SIMD) and differ in the last bit.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swerve.controller import small_linalg as sl
from swerve.controller.errors import ControllerError
from swerve.controller.mathmap import cos_sin, elementwise


@dataclass(frozen=True)
class LinePath:
    """Straight line ``p(t) = start + velocity * t`` (the paper's (61): start 0, velocity 1/20)."""

    start_m: tuple[float, float] = (0.0, 0.0)
    velocity_mps: tuple[float, float] = (0.05, 0.05)
    t_end_s: float = 40.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.zeros((4, 2, t.size))
        v = np.asarray(self.velocity_mps, dtype=float)
        out[0] = np.asarray(self.start_m, dtype=float)[:, None] + v[:, None] * t
        out[1] = v[:, None]
        return out


@dataclass(frozen=True)
class CirclePath:
    """The paper's circle (64): ``x = R sin(w t)``, ``y = R (1 - cos(w t))``, ``w = 2 pi / T``."""

    radius_m: float = 1.0
    period_s: float = 56.0
    t_end_s: float = 56.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        R, w = self.radius_m, 2 * math.pi / self.period_s
        c, s = cos_sin(w * t)
        w2, w3 = w * w, w * w * w
        return np.array([[R * s, R * (1 - c)],
                         [R * w * c, R * w * s],
                         [-R * w2 * s, R * w2 * c],
                         [-R * w3 * c, -R * w3 * s]])


@dataclass(frozen=True)
class CurvilinearPath:
    """The paper's curvilinear path (67), ``w = 2 pi / T``::

        x = cos(w t)/2 + sin(2 w t)/2 - 1/2,    y = cos(2 w t)/2 + sin(w t)/2 - offset
    """

    offset_m: float = 0.6
    period_s: float = 140.0
    t_end_s: float = 140.0

    def derivatives(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        w = 2 * math.pi / self.period_s
        c1, s1 = cos_sin(w * t)
        c2, s2 = cos_sin(2 * w * t)
        w2, w3 = w * w, w * w * w
        return np.array([
            [0.5 * c1 + 0.5 * s2 - 0.5, 0.5 * c2 + 0.5 * s1 - self.offset_m],
            [w * (-0.5 * s1 + c2), w * (-s2 + 0.5 * c1)],
            [w2 * (-0.5 * c1 - 2 * s2), w2 * (-2 * c2 - 0.5 * s1)],
            [w3 * (0.5 * s1 - 4 * c2), w3 * (4 * s2 - 0.5 * c1)]])


def _gauss_legendre_4():
    """4-point Gauss-Legendre nodes (4,) and weights (4 floats) on [0, 1], in closed form (exact
    for degree 7)."""
    a, b = (math.sqrt(3 / 7 + sg * 2 / 7 * math.sqrt(6 / 5)) for sg in (-1, 1))
    wa, wb = (18 + math.sqrt(30)) / 36, (18 - math.sqrt(30)) / 36
    nodes = np.array([0.5 * (1 - b), 0.5 * (1 - a), 0.5 * (1 + a), 0.5 * (1 + b)])
    return nodes, (0.5 * wb, 0.5 * wa, 0.5 * wa, 0.5 * wb)


_GL_X, _GL_W = _gauss_legendre_4()


def _gl_sum(f):
    """``sum_k f[..., k] _GL_W[k]``, added in index order, shape ``f.shape[:-1]``."""
    out = f[..., 0] * _GL_W[0]
    for k in range(1, len(_GL_W)):
        out = out + f[..., k] * _GL_W[k]
    return out


@dataclass(frozen=True)
class Run:
    """A run of samples on one drawn primitive: ``first``..``last`` (sample indices, inclusive),
    ``kind`` (``"line"``, ``"arc"`` or ``"free"``) and its curvature ``curvature_1pm`` (0 for a
    line, the circle fit's signed curvature for an arc, the three-point estimate for a free
    sample)."""

    first: int
    last: int
    kind: str
    curvature_1pm: float


def _line_fits(p, tol):
    """Whether all points ``p`` (n, 2) lie within ``tol`` of the chord from first to last."""
    d = p[-1] - p[0]
    L = math.hypot(*d)
    if L == 0:
        return False
    dist = np.abs((p[:, 0] - p[0, 0]) * d[1] - (p[:, 1] - p[0, 1]) * d[0]) / L
    along = ((p[:, 0] - p[0, 0]) * d[0] + (p[:, 1] - p[0, 1]) * d[1]) / L
    return bool(dist.max() <= tol and np.all(np.diff(along) > 0))


def _lstsq(cols, b):
    """Least-squares ``x`` of ``sum_k x_k cols[k] ~ b`` (columns and ``b`` arrays (n,)), by
    modified Gram-Schmidt on ``[cols, b]`` (backward stable) with :func:`math.fsum` dot
    products; ``None`` if the columns are linearly dependent."""
    v = [np.asarray(c, float) for c in cols] + [np.asarray(b, float)]
    m = len(cols)
    R = [[0.0] * (m + 1) for _ in range(m)]
    for k in range(m):
        R[k][k] = math.sqrt(math.fsum((v[k] * v[k]).tolist()))
        if R[k][k] == 0.0:
            return None
        v[k] = v[k] / R[k][k]
        for j in range(k + 1, m + 1):
            R[k][j] = math.fsum((v[k] * v[j]).tolist())
            v[j] = v[j] - R[k][j] * v[k]
    x = [0.0] * m
    for i in range(m - 1, -1, -1):
        s = R[i][m]
        for j in range(i + 1, m):
            s -= R[i][j] * x[j]
        x[i] = s / R[i][i]
    return x


def _circle_fit(p):
    """Least-squares circle through ``p`` (n, 2) (Kasa): centre (2,), radius, max residual."""
    m = p.mean(axis=0)
    q = p - m
    sol = _lstsq([q[:, 0], q[:, 1], np.ones(len(q))], -(q[:, 0] * q[:, 0] + q[:, 1] * q[:, 1]))
    if sol is None:
        return None
    c = np.array([-0.5 * sol[0], -0.5 * sol[1]])
    r2 = c[0] * c[0] + c[1] * c[1] - sol[2]
    if not r2 > 0:
        return None
    r = math.sqrt(r2)
    res = np.abs(np.hypot(*(q - c).T) - r).max()
    return c + m, r, res


def _arc_curvature(p, centre):
    """Signed curvature of travel along ``p`` around ``centre`` (+: turning left)."""
    r0, r1 = p[0] - centre, p[-1] - centre
    turn = r0[0] * r1[1] - r0[1] * r1[0]
    return math.copysign(1.0 / math.hypot(*r0), turn)


def segment_samples(p, tol_m: float, min_run_m: float) -> list[Run]:
    """Split samples ``p`` (n, 2) into runs on lines and circular arcs, greedily from the start.

    From each sample the longest run of points within ``tol_m`` of a line and of a circle are
    grown; a line shorter than ``min_run_m`` or an arc shorter than ``3 min_run_m`` (chord) is
    not a primitive (on a smooth free-form curve short arcs fit anywhere), and the sample is
    ``free``. A line wins over an arc that is not longer. Consecutive runs share their end
    sample.
    """
    n = len(p)
    runs: list[Run] = []
    i = 0

    def grow(test):
        j = i + 1
        while j + 1 < n and test(p[i:j + 2]):
            j += 1
        return j

    while i < n - 1:
        jl = grow(lambda q: _line_fits(q, tol_m)) if _line_fits(p[i:i + 2], tol_m) else i + 1

        def arc_ok(q):
            if len(q) < 3:
                return True
            fit = _circle_fit(q)
            return fit is not None and fit[2] <= tol_m
        ja = grow(arc_ok)
        long_l = math.hypot(*(p[jl] - p[i])) >= min_run_m and jl - i >= 2
        long_a = math.hypot(*(p[ja] - p[i])) >= 3 * min_run_m and ja - i >= 4
        if long_l and jl >= ja - 1:
            runs.append(Run(i, jl, "line", 0.0))
            i = jl
        elif long_a:
            c, r, _ = _circle_fit(p[i:ja + 1])
            runs.append(Run(i, ja, "arc", _arc_curvature(p[i:ja + 1], c)))
            i = ja
        else:
            runs.append(Run(i, i + 1, "free", _menger(p, i)))
            i += 1
    return runs


def _menger(p, i):
    """Three-point (circumcircle) curvature at sample i (the ends use their neighbours)."""
    i = min(max(i, 1), len(p) - 2)
    a, b, c = p[i - 1], p[i], p[i + 1]
    cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    den = math.hypot(*(b - a)) * math.hypot(*(c - b)) * math.hypot(*(c - a))
    return 2.0 * cross / den if den > 0 else 0.0


class CurvatureFit:
    """A planar curve given by its curvature ``kappa(s)`` over arc length ``s`` (m).

    ``kappa`` is a monotone piecewise-cubic (PCHIP) interpolant of knot values, so it is C1,
    never overshoots its knots, and is exactly 0 between two zero knots. Heading
    ``theta(s) = theta0 + int kappa`` is exact; position ``P(s) = P0 + int (cos, sin) theta`` is
    integrated with 4-point Gauss-Legendre on a dense grid (error far below a micrometre).
    """

    def __init__(self, knots_m, kappa_1pm, start_m, theta0_rad, length_m, grid_m=2e-3):
        from scipy.interpolate import PchipInterpolator

        self.knots_m = np.asarray(knots_m, float)
        self.kappa_knots = np.asarray(kappa_1pm, float)
        self.length_m = float(length_m)
        self._k = PchipInterpolator(self.knots_m, self.kappa_knots, extrapolate=True)
        self._dk = self._k.derivative()
        self._th = self._k.antiderivative()
        self._th0 = float(theta0_rad) - float(self._th(0.0))
        m = max(int(math.ceil(self.length_m / grid_m)), 1)
        self._grid = np.linspace(0.0, self.length_m, m + 1)
        steps = self._integrate(self._grid[:-1], np.diff(self._grid))
        self._P = np.asarray(start_m, float)[:, None] + np.concatenate(
            [np.zeros((2, 1)), np.cumsum(steps, axis=1)], axis=1)

    def _integrate(self, s0, ds):
        """``int_{s0}^{s0+ds} (cos, sin) theta``, arrays (n,) -> (2, n)."""
        nodes = s0[:, None] + ds[:, None] * _GL_X
        c, s = cos_sin(self.heading(nodes))
        return np.stack([_gl_sum(c) * ds, _gl_sum(s) * ds])

    def heading(self, s):
        """Heading of travel ``theta(s)``, rad (unwrapped)."""
        return self._th0 + self._th(s)

    def curvature(self, s):
        """``kappa(s)``, 1/m."""
        return self._k(s)

    def curvature_slope(self, s):
        """``d kappa / d s``, 1/m^2."""
        return self._dk(s)

    def position(self, s):
        """``P(s)``, shape (2, n), for ``0 <= s <= length_m``."""
        s = np.clip(np.atleast_1d(np.asarray(s, float)), 0.0, self.length_m)
        k = np.clip(np.searchsorted(self._grid, s, side="right") - 1, 0, len(self._grid) - 2)
        return self._P[:, k] + self._integrate(self._grid[k], s - self._grid[k])

    def project(self, p, s):
        """Arc length of the points ``p`` (n, 2) nearest the curve, Newton from guesses ``s``."""
        s = np.array(s, float)
        for _ in range(3):
            c, sn = cos_sin(self.heading(s))
            d = p.T - self.position(s)
            s = np.clip(s + d[0] * c + d[1] * sn, 0.0, self.length_m)
        return s


@dataclass(frozen=True)
class FitReport:
    """How far a fitted path is from its samples (all maxima over the samples).

    ``position_m``: distance of a sample from the curve. ``heading_rad``: curve heading versus
    the direction of the chord between consecutive samples, at the chord's middle. ``curvature_1pm``: fitted versus drawn
    curvature (0 on lines, the circle fit's on arcs, three-point estimates on free samples)
    outside the blends between primitives. ``overshoot``: largest ``|kappa| / |kappa_drawn| - 1``
    over the arcs and their blends (``kappa_drawn``: the largest of the arc and its neighbours). ``lines``, ``arcs``, ``free``: counts of runs.
    """

    position_m: float
    heading_rad: float
    curvature_1pm: float
    overshoot: float
    lines: int
    arcs: int
    free: int

    def as_dict(self) -> dict:
        """The report under the keys that ``swerve sim`` prints."""
        return dict(fit_max_position_deviation_m=self.position_m,
                    fit_max_heading_deviation_rad=self.heading_rad,
                    fit_max_curvature_deviation_1pm=self.curvature_1pm,
                    fit_curvature_overshoot=self.overshoot,
                    fit_runs=dict(lines=self.lines, arcs=self.arcs, free=self.free))


def _junctions(runs, p, s):
    """Arc length of the geometric junction between consecutive runs (tangent point of a line
    and an arc, or the point on the line of centres between two arcs; else the shared sample)."""
    out = []
    for a, b in zip(runs, runs[1:]):
        k = a.last
        J = None
        if {a.kind, b.kind} == {"line", "arc"}:
            ln, ar = (a, b) if a.kind == "line" else (b, a)
            c, _, _ = _circle_fit(p[ar.first:ar.last + 1])
            d = p[ln.last] - p[ln.first]
            d = d / math.hypot(*d)
            J = p[ln.first] + sl.dot(c - p[ln.first], d) * d
        elif a.kind == b.kind == "arc":
            ca, ra, _ = _circle_fit(p[a.first:a.last + 1])
            cb, rb, _ = _circle_fit(p[b.first:b.last + 1])
            d = cb - ca
            L = math.hypot(*d)
            if L > 0:
                J = ca + d / L * (ra if L > max(ra, rb) else (ra if ra > rb else -ra))
        if J is None:
            out.append(s[k])
            continue
        t = p[min(k + 1, len(p) - 1)] - p[max(k - 1, 0)]
        t = t / math.hypot(*t)
        out.append(float(s[k] + sl.dot(J - p[k], t)))
    return out


class FittedPath:
    """A path through ``t, x, y`` samples that keeps the drawn geometry.

    The samples are split into straight runs, circular arcs and free samples
    (:func:`segment_samples`, tolerance ``tolerance_m``). The curvature over arc length is
    PCHIP through knots: 0 on lines, one value per arc, one per free knot (at most one per
    ``blend_m / 2``); between two primitives it blends over ``blend_m`` centred on their
    geometric junction (a smooth step with the same total turn as a corner). Start point, start
    heading, arc and free curvatures are least-squares fitted to the samples
    (:func:`scipy.optimize.least_squares`). Time enters only through the arc length travelled,
    ``s(t)``, a quintic smoothing spline of the samples' projections onto the curve. So
    straight runs have curvature 0 exactly and arcs never exceed their fitted curvature.

    ``direction`` is +1 (the body faces the direction of travel) or -1 (driven in reverse:
    heading opposite to travel, v1 < 0). ``report`` is a :class:`FitReport`.
    """

    def __init__(self, t_s, x_m, y_m, tolerance_m: float = 2e-5, blend_m: float = 0.05,
                 direction: int = 1):
        from scipy.interpolate import UnivariateSpline
        from scipy.optimize import least_squares

        t = np.asarray(t_s, dtype=float)
        t = t - t[0]
        p = np.column_stack([np.asarray(x_m, float), np.asarray(y_m, float)])
        seg = np.hypot(*np.diff(p, axis=0).T)
        if np.any(seg == 0):
            i = int(np.argmax(seg == 0))
            raise ControllerError(f"samples {i + 1} and {i + 2} are at the same point: the path "
                                  "stops there, which the tracking law cannot follow")
        d = np.diff(p, axis=0)
        back = d[1:, 0] * d[:-1, 0] + d[1:, 1] * d[:-1, 1] <= 0
        if np.any(back):
            i = int(np.argmax(back)) + 1
            raise ControllerError(f"the path stops at t = {t[i]:.3f} s and turns back (a cusp): "
                                  "the tracking law needs a direction of travel; split the path "
                                  "there and mark the part driven backwards as reverse")
        s = np.concatenate([[0.0], np.cumsum(seg)])
        L = float(s[-1])
        self.direction = 1 if direction >= 0 else -1
        self.tolerance_m, self.blend_m = float(tolerance_m), float(blend_m)
        runs = segment_samples(p, tol_m=self.tolerance_m, min_run_m=self.blend_m)
        # a lone free sample between two primitives straddles their junction: drop it
        runs = [r for k, r in enumerate(runs)
                if not (r.kind == "free" and 0 < k < len(runs) - 1
                        and runs[k - 1].kind != "free" and runs[k + 1].kind != "free")]
        self.runs = runs
        # knots: (arc length, parameter index or None for a fixed zero)
        junc = _junctions(runs, p, s)
        half = 0.5 * self.blend_m
        knots, params, init = [], [], []
        last_free = -np.inf
        for r_i, run in enumerate(runs):
            lo = 0.0 if r_i == 0 else junc[r_i - 1] + half
            hi = L if r_i == len(runs) - 1 else junc[r_i] - half
            if run.kind == "free":
                sk = 0.5 * (lo + hi) if hi > lo else s[run.first]
                if sk - last_free < half:
                    continue
                last_free = sk
                knots.append(sk)
                params.append(len(init))
                init.append(run.curvature_1pm)
                continue
            if hi <= lo:
                lo = hi = 0.5 * (lo + hi)
            idx = None
            if run.kind == "arc":
                idx = len(init)
                init.append(run.curvature_1pm)
            knots += [lo, hi] if hi > lo else [lo]
            params += [idx, idx] if hi > lo else [idx]
        order = np.argsort(knots, kind="stable")
        knots = np.asarray(knots)[order]
        params = [params[k] for k in order]
        keep = np.concatenate([[True], np.diff(knots) > 1e-9])
        knots = knots[keep]
        params = [q for q, k in zip(params, keep) if k]
        if len(knots) < 2:
            knots = np.array([0.0, L])
            params = params[:1] * 2
        self._knots, self._params = knots, params
        d0 = p[1] - p[0]
        x0 = np.concatenate([p[0], [math.atan2(d0[1], d0[0])], init])
        scale = self.tolerance_m
        s_fit = s.copy()

        def build(x, grid_m=0.01):
            kap = np.array([0.0 if q is None else x[3 + q] for q in params])
            return CurvatureFit(knots, kap, x[:2], x[2], L, grid_m)

        def residual(x):
            c = build(x)
            return ((c.position(s_fit).T - p) / scale).ravel()

        sol = None
        for _ in range(2):           # fit, project the samples onto the curve, fit again
            sol = least_squares(residual, x0, method="lm", x_scale="jac")
            x0 = sol.x
            s_fit = build(x0).project(p, s_fit)
            s_fit[0] = 0.0
        self.curve = build(x0, 2e-3)
        s_fit = self.curve.project(p, s_fit)
        if np.any(np.diff(s_fit) <= 0):
            i = int(np.argmax(np.diff(s_fit) <= 0))
            raise ControllerError(f"samples {i + 1} and {i + 2} do not advance along the fitted "
                                  "path (a cusp or a turn sharper than the blend)")
        self.sample_arc_m = s_fit
        self.t_end_s = float(t[-1])
        n = len(t)
        rms = 0.1 * self.tolerance_m
        self._s_of_t = UnivariateSpline(t, s_fit, k=5, s=n * (rms * rms))
        self.samples = (t, p)
        self.report = self._report(p, s_fit, junc)

    def _report(self, p, s_fit, junc):
        c = self.curve
        d = p.T - c.position(s_fit)
        pos = float(np.hypot(*d).max())
        chord = np.diff(p, axis=0)
        hd = elementwise(math.atan2, chord[:, 1], chord[:, 0])
        mid = 0.5 * (s_fit[1:] + s_fit[:-1])
        dev = (c.heading(mid) - hd + np.pi) % (2 * np.pi) - np.pi
        head = float(np.abs(dev).max())
        half = 0.5 * self.blend_m
        near = np.zeros(len(p), bool)
        for j in junc:
            near |= np.abs(s_fit - j) <= half
        kap = c.curvature(s_fit)
        drawn = np.zeros(len(p))
        over = 0.0
        for k, run in enumerate(self.runs):
            sl = slice(run.first, run.last + 1)
            drawn[sl] = run.curvature_1pm
            if run.kind == "arc":
                lo, hi = s_fit[run.first] - half, s_fit[run.last] + half
                ss = np.linspace(lo, hi, 200)
                # a blend may rise to a neighbour's larger drawn curvature, not beyond
                peak = max(abs(r.curvature_1pm) for r in self.runs[max(k - 1, 0):k + 2])
                over = max(over, float(np.abs(c.curvature(ss)).max() / peak) - 1.0)
        for run in self.runs:       # end samples shared with a neighbour keep their own run's
            if run.kind != "free":
                drawn[run.first + 1:run.last] = run.curvature_1pm
        err = np.abs(kap - drawn)[~near]
        n = {k: sum(r.kind == k for r in self.runs) for k in ("line", "arc", "free")}
        return FitReport(pos, head, float(err.max()) if err.size else 0.0, max(over, 0.0),
                         n["line"], n["arc"], n["free"])

    def derivatives(self, t):
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


@dataclass(frozen=True)
class PathSamples:
    """What a trajectory CSV file holds: samples ``t_s``, ``x_m``, ``y_m`` (n,), the travel
    ``direction`` (+1 forwards, -1 reverse), and an optional ``start`` state (5,) or pose (3,)."""

    t_s: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    direction: int = 1
    start: tuple | None = None


def read_csv_samples(path: str | Path) -> PathSamples:
    """Read a trajectory CSV file (format: ``controller/README.md``, "Trajectory files").

    Raises
    ------
    ControllerError
        Unreadable file, wrong column count, non-numbers, NaN/inf, fewer than 6 rows, times
        that do not strictly increase, a bad ``# start`` line, or a change of direction.
    """
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ControllerError(f"cannot read path file {path}: {exc}") from exc
    rows, start, ncol = [], None, None
    for no, line in enumerate(lines, start=1):
        text = line.strip()
        if text.startswith("#"):
            key, _, val = text[1:].partition("=")
            if key.strip().lower() == "start":
                try:
                    start = tuple(float(v) for v in val.split(","))
                except ValueError:
                    start = ()
                if len(start) not in (3, 5) or not all(map(math.isfinite, start)):
                    raise ControllerError(f"{path}:{no}: '# start = x, y, theta[, delta1, "
                                          f"delta2]' needs 3 or 5 numbers (m, rad), got {val!r}")
            continue
        if not text:
            continue
        fields = [f.strip() for f in text.split(",")]
        if ncol is None and not rows and [f.lower() for f in fields] in (
                ["t", "x", "y"], ["t", "x", "y", "reverse"]):
            ncol = len(fields)
            continue
        if len(fields) not in (3, 4) or (ncol is not None and len(fields) != ncol):
            raise ControllerError(f"{path}:{no}: expected columns t,x,y[,reverse], "
                                  f"got {len(fields)}")
        try:
            vals = [float(f) for f in fields]
        except ValueError:
            raise ControllerError(f"{path}:{no}: not a number in {text!r}") from None
        if not all(np.isfinite(vals)):
            raise ControllerError(f"{path}:{no}: NaN or infinite value in {text!r}")
        if len(vals) == 4 and vals[3] not in (0.0, 1.0):
            raise ControllerError(f"{path}:{no}: reverse must be 0 or 1, got {fields[3]!r}")
        ncol = len(vals)
        rows.append((vals + [0.0])[:4] + [no])
    if len(rows) < 6:
        raise ControllerError(f"{path}: need at least 6 samples t,x,y, found {len(rows)}")
    data = np.array(rows)
    dt = np.diff(data[:, 0])
    if np.any(dt <= 0):
        i = int(np.argmax(dt <= 0))
        raise ControllerError(f"{path}: time must strictly increase (sample {i + 2}: "
                              f"t = {data[i + 1, 0]} after {data[i, 0]})")
    rev = data[:, 3]
    if np.any(rev != rev[0]):
        i = int(np.argmax(rev != rev[0]))
        raise ControllerError(
            f"{path}:{int(data[i, 4])}: the direction changes (reverse {int(rev[0])} -> "
            f"{int(rev[i])}); that needs a stop, which the tracking law cannot pass: put each "
            "direction in its own file")
    return PathSamples(data[:, 0], data[:, 1], data[:, 2], -1 if rev[0] else 1, start)


def read_csv_path(path: str | Path, tolerance_m: float = 2e-5,
                  blend_m: float = 0.05) -> FittedPath:
    """A :class:`FittedPath` through the samples of a trajectory CSV file."""
    smp = read_csv_samples(path)
    return fit_samples(smp, tolerance_m, blend_m, str(path))


def fit_samples(smp: PathSamples, tolerance_m: float = 2e-5, blend_m: float = 0.05,
                source: str = "path") -> FittedPath:
    """:class:`FittedPath` of :class:`PathSamples`; errors name ``source``."""
    try:
        return FittedPath(smp.t_s, smp.x_m, smp.y_m, tolerance_m, blend_m, smp.direction)
    except ControllerError as exc:
        raise ControllerError(f"{source}: {exc}") from None


def draw_primitives(segments, start=(0.0, 0.0, 0.0), spacing_m: float = 0.01):
    """Sample a path drawn from lines and arcs, as a user or CAD tool would.

    Parameters
    ----------
    segments : sequence of ``("line", length_m)`` and ``("arc", radius_m, turn_rad)``
        (``turn_rad`` > 0 turns left).
    start : ``(x_m, y_m, heading_rad)`` of the first sample.
    spacing_m : distance between samples along the path, m.

    Returns
    -------
    s_m, x_m, y_m, kappa_1pm : ndarrays, shape (n,)
        Arc length, position and drawn curvature of the samples (at a junction the curvature
        of the segment that starts there).
    """
    x, y, th = map(float, start)
    total = sum(seg[1] if seg[0] == "line" else abs(seg[1] * seg[2]) for seg in segments)
    n = int(round(total / spacing_m))
    s_all = np.linspace(0.0, total, n + 1)
    out = np.empty((4, n + 1))
    s0 = 0.0
    for seg in segments:
        length = seg[1] if seg[0] == "line" else abs(seg[1] * seg[2])
        k = 0.0 if seg[0] == "line" else math.copysign(1.0 / seg[1], seg[2])
        sel = (s_all >= s0 - 1e-12) & (s_all <= s0 + length + 1e-12)
        u = s_all[sel] - s0
        if k == 0.0:
            px, py = x + u * math.cos(th), y + u * math.sin(th)
        else:
            cu, su = cos_sin(th + k * u)
            px = x + (su - math.sin(th)) / k
            py = y - (cu - math.cos(th)) / k
        out[:, sel] = [s_all[sel], px, py, np.full(u.size, k)]
        if k == 0.0:
            x, y = x + length * math.cos(th), y + length * math.sin(th)
        else:
            x = x + (math.sin(th + k * length) - math.sin(th)) / k
            y = y - (math.cos(th + k * length) - math.cos(th)) / k
            th += k * length
        s0 += length
    return out[0], out[1], out[2], out[3]
