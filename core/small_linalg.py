"""Small dense linear algebra in a fixed order of IEEE-754 operations: the same bits on every machine.

NumPy's ``@`` and LAPACK (``np.linalg.solve``, ``np.linalg.pinv``, ``scipy.linalg.expm``) run
OpenBLAS kernels picked for the CPU at run time (``OPENBLAS_CORETYPE`` overrides the pick). The
kernels differ in FMA use and summation order, so the same inputs give results that differ in the
last bits from one machine to the next: the line's Riccati gain schedule changes between
``OPENBLAS_CORETYPE=Sandybridge`` and ``Haswell``, and the emulated body's least-squares operator
between ``Haswell`` and ``SkylakeX``. A lockstep run feeds such bits back through the physics and
the law, so its log would differ between machines.

Here every product and sum is one correctly rounded Python float operation, done term by term in
index order, so a result depends only on the inputs. (Not the builtin ``sum`` either: from Python
3.12 it adds floats with compensation.) Meant for matrices of a few rows: a 5 x 5 product costs
about 15 µs.

Matrices are sequences of rows (lists or tuples of floats), shape (n, m); results are lists of lists.
"""
from __future__ import annotations

from typing import Sequence

Matrix = Sequence[Sequence[float]]


class SingularMatrixError(ArithmeticError):
    """A pivot of exactly zero: the matrix is singular (or the system has no unique solution)."""


def dot(a: Sequence[float], b: Sequence[float]) -> float:
    """``a[0] b[0] + a[1] b[1] + ...``, added left to right from ``0.0``."""
    s = 0.0
    for x, y in zip(a, b, strict=True):
        s += x * y
    return s


def transpose(a: Matrix) -> list[list[float]]:
    """``a'``, shape (m, n)."""
    return [list(col) for col in zip(*a)]


def matmul(a: Matrix, b: Matrix) -> list[list[float]]:
    """``a b`` for ``a`` (n, k) and ``b`` (k, m), shape (n, m)."""
    cols = list(zip(*b))
    return [[dot(row, col) for col in cols] for row in a]


def matvec(a: Matrix, x: Sequence[float]) -> list[float]:
    """``a x`` for ``a`` (n, k) and ``x`` (k,), shape (n,)."""
    return [dot(row, x) for row in a]


def add(a: Matrix, b: Matrix, scale_b: float = 1.0) -> list[list[float]]:
    """``a + scale_b b``, elementwise, same shape."""
    return [[x + scale_b * y for x, y in zip(ra, rb, strict=True)] for ra, rb in zip(a, b, strict=True)]


def solve(a: Matrix, b: Matrix) -> list[list[float]]:
    """``x`` with ``a x = b`` for square ``a`` (n, n) and ``b`` (n, m): Gaussian elimination with
    partial pivoting (the first row of largest magnitude in the column), shape (n, m).

    Raises :class:`SingularMatrixError` on a zero pivot.
    """
    n = len(a)
    if len(b) != n or any(len(row) != n for row in a):
        raise ValueError(f"solve: a must be square and b have {n} rows")
    m = [[float(v) for v in ra] + [float(v) for v in rb] for ra, rb in zip(a, b)]
    width = len(m[0])
    for k in range(n):
        p = k
        for i in range(k + 1, n):
            if abs(m[i][k]) > abs(m[p][k]):
                p = i
        if m[p][k] == 0.0:
            raise SingularMatrixError(f"singular matrix (zero pivot in column {k})")
        m[k], m[p] = m[p], m[k]
        pivot = m[k]
        for i in range(k + 1, n):
            row = m[i]
            f = row[k] / pivot[k]
            if f != 0.0:
                for j in range(k, width):
                    row[j] -= f * pivot[j]
    x = [[0.0] * (width - n) for _ in range(n)]
    for i in range(n - 1, -1, -1):
        row = m[i]
        for c in range(width - n):
            s = row[n + c]
            for j in range(i + 1, n):
                s -= row[j] * x[j][c]
            x[i][c] = s / row[i]
    return x


def pinv(a: Matrix) -> list[list[float]]:
    """Moore-Penrose pseudo-inverse of a full-rank ``a`` (n, m), shape (m, n).

    Tall or square (rank m): ``(a' a)^-1 a'``, the least-squares solution operator; wide (rank n):
    ``a' (a a')^-1``, the minimum-norm one. Raises :class:`SingularMatrixError` if ``a`` is not of
    full rank. Through the normal equations, so for well-conditioned matrices only.
    """
    at = transpose(a)
    if len(a) >= len(at):
        return solve(matmul(at, a), at)
    return transpose(solve(matmul(a, at), a))
