"""A kernel kept as native code (emulator/physics/native.py): compiled once, loaded without numba,
the same results as the Python function, and every damaged or unusable cache entry recompiled."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swerve.emulator.physics import jit, native
from swerve.emulator.physics.native import NativeKernel, NativeLoadError

pytestmark = pytest.mark.skipif(not jit.ENABLED, reason="numba is not installed (or SWERVE_NO_JIT is set)")

PARAMS = ("i8", "f8", "f8[:]", "f8[:,:]", "i8[:]")


def blend(n, a, x, m, counts):
    """``x[i] = a * x[i] + exp(-m[i, 0]) * sin(m[i, 1])`` for ``i < n``; counts the rows done."""
    done = 0
    for i in range(n):
        x[i] = a * x[i] + math.exp(-m[i, 0]) * math.sin(m[i, 1])
        counts[0] += 1
        done += 1
    return done


@pytest.fixture
def cache_dir(tmp_path, monkeypatch):
    monkeypatch.setattr(jit, "CACHE_DIR", tmp_path / "kernels")
    (tmp_path / "kernels").mkdir()
    return tmp_path / "kernels"


def _arrays(rows: int, seed: int = 1):
    rng = np.random.default_rng(seed)
    return rng.normal(size=rows), rng.normal(size=(rows, 2)), np.zeros(1, np.int64)


def _python(n, a, x, m, counts):
    x, counts = x.copy(), counts.copy()
    done = blend(n, a, x, m, counts)
    return done, x, counts


def test_compiled_then_loaded_from_the_cache_gives_the_python_bits(cache_dir):
    x, m, counts = _arrays(16)
    want = _python(16, 0.75, x, m, counts)
    first = NativeKernel(blend, PARAMS)
    first.load()
    assert first.hit is False and len(list(cache_dir.glob("native-blend-*.o"))) == 1
    second = NativeKernel(blend, PARAMS)
    second.load()
    assert second.hit is True
    for kernel in (first, second):
        xs, cs = x.copy(), counts.copy()
        done = kernel.bind(xs, m, cs)(16, 0.75)
        assert (done, xs.tobytes(), cs.tobytes()) == (want[0], want[1].tobytes(), want[2].tobytes())


@pytest.fixture(scope="module")
def loaded_blend(tmp_path_factory) -> NativeKernel:
    with pytest.MonkeyPatch.context() as mp:            # the kernel keeps its folder from here
        mp.setattr(jit, "CACHE_DIR", tmp_path_factory.mktemp("native"))
        kernel = NativeKernel(blend, PARAMS)
    kernel.load()
    return kernel


@settings(max_examples=60, deadline=None)
@given(rows=st.integers(0, 40), n=st.integers(0, 40), a=st.floats(-1e3, 1e3), seed=st.integers(0, 2**32 - 1))
def test_any_inputs_give_the_python_bits(loaded_blend, rows, n, a, seed):
    """Any row count, any number of rows asked for (up to the rows), any factor."""
    n = min(n, rows)
    x, m, counts = _arrays(rows, seed)
    want = _python(n, a, x, m, counts)
    xs, cs = x.copy(), counts.copy()
    assert loaded_blend.bind(xs, m, cs)(n, a) == want[0]
    assert xs.tobytes() == want[1].tobytes() and cs.tobytes() == want[2].tobytes()


def test_a_damaged_cache_file_is_compiled_again(cache_dir):
    NativeKernel(blend, PARAMS).load()
    path, = cache_dir.glob("native-blend-*.o")
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x40                    # one bit inside the object code
    path.write_bytes(bytes(data))
    kernel = NativeKernel(blend, PARAMS)
    kernel.load()
    assert kernel.hit is False
    x, m, counts = _arrays(5)
    assert kernel.bind(x.copy(), m, counts)(5, 2.0) == 5
    again = NativeKernel(blend, PARAMS)             # the file was written anew
    again.load()
    assert again.hit is True


def test_an_object_needing_a_symbol_this_process_lacks_is_compiled_instead(cache_dir):
    kernel = NativeKernel(blend, PARAMS)
    kernel.load()
    data, _ = kernel._cache.payload(kernel._key(), bytes)
    obj = native._Object.unpack(data)
    assert "exp" in obj.externals or "__exp_finite" in obj.externals      # the C library's exp
    damaged = native._Object(obj.symbol, (*obj.externals, "swerve_no_such_symbol"), obj.code)
    kernel._cache._store(kernel._key(), damaged.pack())
    with pytest.raises(NativeLoadError, match="swerve_no_such_symbol"):
        native._load(damaged)
    fresh = NativeKernel(blend, PARAMS)
    fresh.load()
    assert fresh.hit is False and fresh._dispatcher is not None      # numba's own kernel instead
    x, m, counts = _arrays(3)
    xs = x.copy()
    assert fresh.bind(xs, m, counts)(3, 1.5) == 3
    assert xs.tobytes() == _python(3, 1.5, x, m, np.zeros(1, np.int64))[1].tobytes()


def test_the_key_follows_the_target_cpu_and_numba_settings(cache_dir, monkeypatch):
    kernel = NativeKernel(blend, PARAMS)
    keys = {kernel._key()}
    monkeypatch.setenv("NUMBA_CPU_NAME", "generic")
    keys.add(kernel._key())
    monkeypatch.setenv("NUMBA_OPT", "1")
    keys.add(kernel._key())
    monkeypatch.setenv("NUMBA_CACHE_DIR", "/elsewhere")           # where, not what: the same key
    keys.add(kernel._key())
    assert len(keys) == 3


def test_bind_refuses_arrays_of_another_kind(cache_dir):
    kernel = NativeKernel(blend, PARAMS)
    x, m, counts = _arrays(4)
    for bad, match in (((x, m), "2 arrays given, 3 expected"),
                       ((x.astype(np.float32), m, counts), "array 0 is float32"),
                       ((x, m[:, 0], counts), "array 1 is float64\\[4\\]"),
                       ((x, np.asfortranarray(np.ones((4, 2))), counts), "C-contiguous"),
                       ((x, m, counts.astype(np.float64)), "array 2")):
        with pytest.raises(ValueError, match=match):
            kernel.bind(*bad)
    assert not kernel.loaded                         # refused before any compile


def test_parameter_lists_are_checked():
    with pytest.raises(ValueError, match="unknown parameter types"):
        NativeKernel(blend, ("i8", "f4", "f8[:]", "f8[:,:]", "i8[:]"))
    with pytest.raises(ValueError, match="scalar parameters must come before"):
        NativeKernel(blend, ("i8", "f8[:]", "f8", "f8[:,:]", "i8[:]"))


def test_only_elf_objects_are_read():
    with pytest.raises(NativeLoadError, match="not ELF64"):
        native._undefined_symbols(b"\xcf\xfa\xed\xfe" + bytes(64))       # a Mach-O header


def test_where_objects_are_not_elf_the_kernel_is_numbas_own(cache_dir, monkeypatch):
    """Not Linux: no object is cached; numba compiles (and caches) the function itself, bound the same way."""
    monkeypatch.setattr(native, "OBJECTS_LOADABLE", False)
    kernel = NativeKernel(blend, PARAMS)
    x, m, counts = _arrays(7)
    xs, cs = x.copy(), counts.copy()
    assert kernel.bind(xs, m, cs)(7, -0.5) == 7
    want = _python(7, -0.5, x, m, counts)
    assert kernel.hit is False and not list(cache_dir.glob("native-*"))
    assert xs.tobytes() == want[1].tobytes() and cs.tobytes() == want[2].tobytes()


def test_a_numba_without_readable_object_code_falls_back_to_its_own_kernel(cache_dir, monkeypatch):
    """The object cannot be taken apart: this process runs the compiled cfunc, and the empty entry
    sends later starts straight to numba's ``njit`` of the same function."""
    def unreadable(code):
        raise NativeLoadError("no symbol table")

    monkeypatch.setattr(native, "_undefined_symbols", unreadable)
    first = NativeKernel(blend, PARAMS)
    first.load()
    assert first.hit is False and first._function is not None
    data, hit = first._cache.payload(first._key(), lambda: b"not used")
    assert (data, hit) == (b"", True)
    later = NativeKernel(blend, PARAMS)
    later.load()
    assert later._dispatcher is not None and later._function is None
    for kernel in (first, later):
        x, m, counts = _arrays(6)
        xs, cs = x.copy(), counts.copy()
        assert kernel.bind(xs, m, cs)(6, 0.25) == 6
        assert xs.tobytes() == _python(6, 0.25, x, m, counts)[1].tobytes()
