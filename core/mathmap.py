"""Python's :mod:`math` functions over arrays: the same bits whichever SIMD loops NumPy picks.

NumPy's ``tan``, ``arctan``, ``arctan2``, ``power`` and ``exp`` run loops chosen for the CPU at
run time (AVX-512, AVX2 or baseline) that differ in the last bit; the C library's functions
behind :mod:`math` do not depend on NumPy's choice. About 0.2 µs per element.
"""
from __future__ import annotations

import cmath

import numpy as np


def elementwise(fn, *args) -> np.ndarray:
    """``fn`` of floats (a :mod:`math` function) on each element of the broadcast ``args``, as a
    float array of their shape. Unlike NumPy's ``sin``, ``arctan2``, ``power``, ... it gives
    the same bits whichever SIMD loops NumPy picks for the CPU."""
    arrays = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in args))
    values = map(fn, *(a.ravel().tolist() for a in arrays))
    return np.fromiter(values, float, arrays[0].size).reshape(arrays[0].shape)


def cos_sin(angle) -> tuple[np.ndarray, np.ndarray]:
    """``(cos, sin)`` of the angles (rad, any shape): :func:`math.cos` and :func:`math.sin`'s
    bits, in one call per element (``cmath.exp(i angle) = 1.0 cos + 1.0 i sin``)."""
    a = np.asarray(angle, dtype=float)
    z = np.empty(a.shape, complex)
    z.real, z.imag = 0.0, a
    e = np.fromiter(map(cmath.exp, z.ravel().tolist()), complex, a.size).reshape(a.shape)
    return e.real, e.imag
