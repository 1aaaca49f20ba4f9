"""Fixed-order small linear algebra: agrees with NumPy to round-off, and gives the same bits
whichever BLAS kernel NumPy would have used."""
from __future__ import annotations

import json

import numpy as np
import pytest

from swerve.core import small_linalg as sl


@pytest.mark.parametrize("seed", range(5))
def test_products_and_solves_agree_with_numpy(seed):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(5, 3)), rng.normal(size=(3, 4))
    np.testing.assert_allclose(sl.matmul(a.tolist(), b.tolist()), a @ b, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(sl.matvec(a.tolist(), b[:, 0].tolist()), a @ b[:, 0], rtol=1e-14,
                               atol=1e-14)
    s = rng.normal(size=(4, 4)) + 4 * np.eye(4)
    rhs = rng.normal(size=(4, 2))
    np.testing.assert_allclose(sl.solve(s.tolist(), rhs.tolist()), np.linalg.solve(s, rhs),
                               rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(sl.pinv(a.tolist()), np.linalg.pinv(a), rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(sl.pinv(a.T.tolist()), np.linalg.pinv(a.T), rtol=1e-11, atol=1e-12)


def test_solve_pivots_on_a_zero_leading_entry():
    x = sl.solve([[0.0, 2.0], [3.0, 1.0]], [[4.0], [5.0]])
    assert x == [[1.0], [2.0]]


def test_singular_and_rank_deficient_matrices_are_refused():
    with pytest.raises(sl.SingularMatrixError):
        sl.solve([[1.0, 2.0], [2.0, 4.0]], [[1.0], [2.0]])
    with pytest.raises(sl.SingularMatrixError):
        sl.pinv([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])
    with pytest.raises(ValueError):
        sl.solve([[1.0, 2.0]], [[1.0]])


def test_the_sum_order_is_left_to_right():
    # 1e16 + 1 + 1 rounds to 1e16 at each step; compensated or pairwise summation gives 1e16 + 2
    assert sl.dot([1e16, 1.0, 1.0], [1.0, 1.0, 1.0]) == 1e16


_PROBE = """
import json, numpy as np
from swerve.core import small_linalg as sl
rng = np.random.default_rng(7)
a = rng.normal(size=(8, 3)).tolist(); s = (rng.normal(size=(5, 5)) + 5 * np.eye(5)).tolist()
b = rng.normal(size=(5, 3)).tolist()
print(json.dumps([float.hex(v) for r in sl.pinv(a) + sl.solve(s, b) + sl.matmul(s, b) for v in r]
                 + [float.hex(v) for v in (np.array(s) @ np.array(b)).ravel()]))
"""


def test_same_bits_under_different_blas_kernels(other_cpu):
    out = {core: json.loads(other_cpu({"OPENBLAS_CORETYPE": core}, "-c", _PROBE))
           for core in ("Nehalem", "Haswell")}
    n = len(out["Nehalem"]) - 15
    assert out["Nehalem"][:n] == out["Haswell"][:n]
    # the probe can tell the kernels apart: NumPy's own product of the same matrices differs
    assert out["Nehalem"][n:] != out["Haswell"][n:]
