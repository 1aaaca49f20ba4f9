"""Split drawn samples into straight runs, circular arcs and free samples, in time linear in their number.

A run is grown from its first sample by doubling its length while the samples stay within the
tolerance of a line (or of a least-squares circle), then by bisection between the last length
that fits and the first that does not: a run of ``m`` samples costs ``O(m log m)``. Where no
primitive long enough starts, half of the samples the attempt covered become free at once, so
a smooth free-form curve is not re-fitted from every one of its samples.

Sums of products are :func:`math.fsum` (correctly rounded) or elementwise: no BLAS, LAPACK or
SIMD-dispatched NumPy loops, so the split is the same on every CPU.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swerve.core import small_linalg as sl


@dataclass(frozen=True)
class Run:
    """Samples ``first``..``last`` (indices, inclusive) on one drawn primitive.

    ``kind`` is ``"line"``, ``"arc"`` or ``"free"``; ``curvature_1pm`` is 0 for a line, the
    circle fit's signed curvature for an arc, the three-point estimate for a free sample.
    """

    first: int
    last: int
    kind: str
    curvature_1pm: float


def line_fits(p: np.ndarray, tol_m: float) -> bool:
    """Whether all points ``p`` (n, 2), m, lie within ``tol_m`` of the chord from first to last
    and advance along it."""
    d = p[-1] - p[0]
    L = math.hypot(*d)
    if L == 0:
        return False
    dist = np.abs((p[:, 0] - p[0, 0]) * d[1] - (p[:, 1] - p[0, 1]) * d[0]) / L
    along = ((p[:, 0] - p[0, 0]) * d[0] + (p[:, 1] - p[0, 1]) * d[1]) / L
    return bool(dist.max() <= tol_m and np.all(np.diff(along) > 0))


def _lstsq(cols, b):
    """Least-squares ``x`` of ``sum_k x_k cols[k] ~ b`` (arrays (n,)), by modified Gram-Schmidt
    on ``[cols, b]`` with :func:`math.fsum` dot products; ``None`` if the columns are linearly
    dependent."""
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


def circle_fit(p: np.ndarray):
    """Least-squares (Kasa) circle through ``p`` (n, 2), m: ``(centre (2,), radius, largest
    distance of a point from the circle)``, or ``None`` for collinear points."""
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
    d = q - c
    res = np.abs(np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) - r).max()
    return c + m, r, float(res)


def _arc_fits(p: np.ndarray, tol_m: float) -> bool:
    if len(p) < 3:
        return True
    fit = circle_fit(p)
    return fit is not None and fit[2] <= tol_m


def arc_curvature(p: np.ndarray, centre) -> float:
    """Signed curvature of travel along ``p`` (n, 2) around ``centre`` (2,), 1/m (+: left)."""
    r = p - np.asarray(centre, float)
    # the signed angle swept about the centre (a half turn or more has no sign in its ends)
    turn = math.fsum((r[:-1, 0] * r[1:, 1] - r[:-1, 1] * r[1:, 0]).tolist())
    return math.copysign(1.0 / math.hypot(*r[0]), turn)


def menger(p: np.ndarray, i: int) -> float:
    """Three-point (circumcircle) curvature at sample ``i`` of ``p`` (n, 2), 1/m (the ends use
    their neighbours)."""
    i = min(max(i, 1), len(p) - 2)
    a, b, c = p[i - 1], p[i], p[i + 1]
    cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
    den = math.hypot(*(b - a)) * math.hypot(*(c - b)) * math.hypot(*(c - a))
    return 2.0 * cross / den if den > 0 else 0.0


def _grow(p: np.ndarray, i: int, j0: int, fits) -> int:
    """Largest ``j >= j0`` with ``fits(p[i:j + 1])`` (``fits(p[i:j0 + 1])`` holds), searched by
    doubling the span then bisection."""
    n = len(p)
    good, span = j0, 2 * max(j0 - i, 1)
    if good == n - 1:
        return good
    while True:
        j = min(i + span, n - 1)
        if not fits(p[i:j + 1]):
            bad = j
            break
        good = j
        if j == n - 1:
            return good
        span *= 2
    while bad - good > 1:
        mid = (good + bad) // 2
        if fits(p[i:mid + 1]):
            good = mid
        else:
            bad = mid
    return good


def three_point_curvatures(p: np.ndarray) -> np.ndarray:
    """:func:`menger` at every sample of ``p`` (n, 2), 1/m, shape (n,)."""
    n = len(p)
    i = np.clip(np.arange(n), 1, n - 2)
    a, b, c = p[i - 1], p[i], p[i + 1]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    den = np.hypot(*(b - a).T) * np.hypot(*(c - b).T) * np.hypot(*(c - a).T)
    out = np.zeros(n)
    ok = den > 0
    out[ok] = 2.0 * cross[ok] / den[ok]
    return out


def _extend_back(p, runs, i, j, fits) -> int:
    """Move the start ``i`` of a primitive ending at ``j`` back over the free samples before it
    while it still fits (free samples skipped in bulk may hold its first samples); the free runs
    it takes over are removed from ``runs``. Returns the new start."""
    b = i
    while runs and runs[-1].kind == "free" and runs[-1].last == b and fits(p[b - 1:j + 1]):
        runs.pop()
        b -= 1
    return b


def segment_samples(p: np.ndarray, tol_m: float, min_run_m: float) -> list[Run]:
    """Split samples ``p`` (n, 2), m, into runs on lines, circular arcs and free samples.

    A line shorter than ``min_run_m`` or an arc shorter than ``3 min_run_m`` is not a primitive
    (on a smooth free-form curve short arcs fit anywhere). From a sample, the shortest line and
    arc that would be primitives are tried; one that fits within ``tol_m`` is grown to the
    longest that does. A line wins over an arc that is not longer. Where neither fits, the
    samples over the first half of the shortest line become free runs of one interval each (at
    least one); a primitive found after them takes back those of its samples that fit it.
    Consecutive runs share their end sample.
    """
    n = len(p)
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    kap = three_point_curvatures(p)
    runs: list[Run] = []
    i = 0
    while i < n - 1:
        # the shortest line and arc that would be primitives; grown only if they fit
        jl0 = min(int(np.searchsorted(s, s[i] + min_run_m)), n - 1)
        ja0 = min(int(np.searchsorted(s, s[i] + 3 * min_run_m)), n - 1)
        jl = ja = i + 1
        if jl0 - i >= 2 and line_fits(p[i:jl0 + 1], tol_m):
            jl = _grow(p, i, jl0, lambda q: line_fits(q, tol_m))
        if ja0 - i >= 4 and _arc_fits(p[i:ja0 + 1], tol_m):
            ja = _grow(p, i, ja0, lambda q: _arc_fits(q, tol_m))
        long_l = math.hypot(*(p[jl] - p[i])) >= min_run_m and jl - i >= 2
        long_a = math.hypot(*(p[ja] - p[i])) >= 3 * min_run_m and ja - i >= 4
        if long_l and jl >= ja - 1:
            b = _extend_back(p, runs, i, jl, lambda q: line_fits(q, tol_m))
            runs.append(Run(b, jl, "line", 0.0))
            i = jl
        elif long_a:
            b = _extend_back(p, runs, i, ja, lambda q: _arc_fits(q, tol_m))
            c, _, _ = circle_fit(p[b:ja + 1])
            runs.append(Run(b, ja, "arc", arc_curvature(p[b:ja + 1], c)))
            i = ja
        else:
            stop = min(i + max(1, (jl0 - i) // 2), n - 1)
            for k in range(i, stop):
                runs.append(Run(k, k + 1, "free", float(kap[k])))
            i = stop
    return runs


def junctions(runs: list[Run], p: np.ndarray, s: np.ndarray) -> list[float]:
    """Arc length (m) of the geometric junction between consecutive runs: the tangent point of a
    line and an arc, or the point on the line of centres between two arcs; else the shared
    sample's arc length ``s`` (n,)."""
    out = []
    for a, b in zip(runs, runs[1:]):
        k = a.last
        J = None
        if {a.kind, b.kind} == {"line", "arc"}:
            ln, ar = (a, b) if a.kind == "line" else (b, a)
            c, _, _ = circle_fit(p[ar.first:ar.last + 1])
            d = p[ln.last] - p[ln.first]
            d = d / math.hypot(*d)
            J = p[ln.first] + sl.dot(c - p[ln.first], d) * d
        elif a.kind == b.kind == "arc":
            ca, ra, _ = circle_fit(p[a.first:a.last + 1])
            cb, rb, _ = circle_fit(p[b.first:b.last + 1])
            d = cb - ca
            L = math.hypot(*d)
            if L > 0:
                J = ca + d / L * (ra if L > max(ra, rb) else (ra if ra > rb else -ra))
        if J is None:
            out.append(float(s[k]))
            continue
        t = p[min(k + 1, len(p) - 1)] - p[max(k - 1, 0)]
        t = t / math.hypot(*t)
        step = sl.dot(J - p[k], t)
        # a junction stays within the two runs
        out.append(float(min(max(s[k] + step, s[a.first]), s[b.last])))
    return out
