"""The cache of exact discretisations: a hit gives the mpmath computation's bits without importing
mpmath, any changed input misses, a damaged file is recomputed, an unwritable folder only loses
the cache."""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from hypothesis import example, given, settings, strategies as st

from swerve.emulator.physics import discrete, exact
from swerve.emulator.physics.discrete import ExactCache, bessel_prototype, zoh

A = [[-3000.0, -12.5, 0.0], [40.0, -0.2, 0.0], [0.0, 1.0, 0.0]]
B = [[250.0, 0.0], [0.0, -900.0], [0.0, 0.0]]
DT = 1e-3


def _direct(a, b, dt_s):
    """``(Ad, Bd)`` straight from :mod:`.exact` (no cache)."""
    rows = np.array(exact.zoh_rows(np.asarray(a, float).tolist(), np.asarray(b, float).tolist(), dt_s))
    n = len(a)
    return rows[:, :n], rows[:, n:]


def _same_bits(x, y) -> bool:
    x, y = np.asarray(x), np.asarray(y)
    return x.dtype == y.dtype == np.float64 and x.shape == y.shape and x.tobytes() == y.tobytes()


def _refuse(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("computed although the cache holds the answer")

    monkeypatch.setattr(exact, "zoh_rows", refuse)
    monkeypatch.setattr(exact, "bessel_prototype", refuse)


def test_a_hit_returns_the_computed_bits_without_computing(tmp_path, monkeypatch):
    ad0, bd0 = _direct(A, B, DT)
    proto0 = exact.bessel_prototype(32.8, "mag")
    cache = ExactCache(tmp_path)
    ad1, bd1 = zoh(A, B, DT, cache)
    proto1 = bessel_prototype(32.8, "mag", cache)
    assert (cache.hits, cache.misses) == (0, 2)
    assert len(list(tmp_path.glob("exact-*.f8"))) == 2
    _refuse(monkeypatch)
    again = ExactCache(tmp_path)
    ad2, bd2 = zoh(A, B, DT, again)
    assert bessel_prototype(32.8, "mag", again) == proto1 == proto0
    assert (again.hits, again.misses) == (2, 0)
    for x, y in ((ad0, ad1), (ad0, ad2), (bd0, bd1), (bd0, bd2)):
        assert _same_bits(x, y)


@pytest.mark.parametrize("change", ["a", "b", "dt", "shape", "cutoff", "norm"])
def test_a_changed_input_misses(tmp_path, change):
    cache = ExactCache(tmp_path)
    zoh(A, B, DT, cache)
    bessel_prototype(32.8, "mag", cache)
    a, b, dt, cutoff, norm = np.array(A), np.array(B), DT, 32.8, "mag"
    if change == "a":
        a[1, 1] = np.nextafter(a[1, 1], 0.0)       # one ulp
    elif change == "b":
        b[0, 0] += 1e-12
    elif change == "dt":
        dt = np.nextafter(dt, 1.0)
    elif change == "shape":
        a, b = a[1:, 1:], b[1:, 1:]
    elif change == "cutoff":
        cutoff = np.nextafter(cutoff, 0.0)
    else:
        norm = "phase"
    ad, bd = zoh(a, b, dt, cache)
    proto = bessel_prototype(cutoff, norm, cache)
    assert (cache.hits, cache.misses) == (1, 3)        # the unchanged one of the two hits
    ad0, bd0 = _direct(a, b, dt)
    assert _same_bits(ad, ad0) and _same_bits(bd, bd0)
    assert proto == exact.bessel_prototype(cutoff, norm)


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty", "other key", "longer"])
def test_a_damaged_file_is_recomputed_and_rewritten(tmp_path, damage):
    ad0, bd0 = _direct(A, B, DT)
    zoh(A, B, DT, ExactCache(tmp_path))
    (path,) = tmp_path.glob("exact-*.f8")
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[:len(data) // 2])
    elif damage == "flip":
        i = len(discrete.LAYOUT) + 32 + 13          # inside the values
        path.write_bytes(data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1:])
    elif damage == "garbage":
        path.write_bytes(b"not a cache file\n" * 10)
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "longer":
        path.write_bytes(data + b"\0" * 8)
    else:                               # a whole valid file of another input under this name
        zoh(A, B, 2 * DT, ExactCache(tmp_path / "other"))
        path.write_bytes(next((tmp_path / "other").glob("*.f8")).read_bytes())
    cache = ExactCache(tmp_path)
    ad, bd = zoh(A, B, DT, cache)
    assert (cache.hits, cache.misses) == (0, 1)
    assert _same_bits(ad, ad0) and _same_bits(bd, bd0)
    again = ExactCache(tmp_path)
    ad2, _ = zoh(A, B, DT, again)
    assert again.hits == 1 and _same_bits(ad2, ad0)


def test_an_unwritable_folder_only_loses_the_cache(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder should be")
    cache = ExactCache(blocker / "swerve")
    ad, bd = zoh(A, B, DT, cache)
    assert cache.misses == 1 and _same_bits(ad, _direct(A, B, DT)[0]) and _same_bits(bd, _direct(A, B, DT)[1])
    assert blocker.read_text() == "a file where the cache folder should be"


def test_the_key_covers_the_code(tmp_path, monkeypatch):
    key = discrete.exact_key("zoh", b"inputs")
    edited = tmp_path / "exact.py"
    edited.write_bytes(discrete.EXACT_SOURCE.read_bytes() + b"\n# edited\n")
    monkeypatch.setattr(discrete, "EXACT_SOURCE", edited)
    assert discrete.exact_key("zoh", b"inputs") != key
    assert discrete.exact_key("bessel", b"inputs") != discrete.exact_key("zoh", b"inputs")


def test_bad_input_is_refused_before_the_cache(tmp_path):
    cache = ExactCache(tmp_path)
    with pytest.raises(ValueError, match="zoh"):
        zoh(np.eye(2), np.ones((3, 1)), DT, cache)
    with pytest.raises(ValueError, match="norm"):
        bessel_prototype(32.8, "bogus", cache)
    assert (cache.hits, cache.misses) == (0, 0) and not list(tmp_path.iterdir())


_finite = st.floats(-1e4, 1e4, allow_nan=False, allow_infinity=False)


@settings(max_examples=25, deadline=None)
@given(n=st.integers(1, 4), m=st.integers(1, 2), data=st.data(), dt_s=st.floats(1e-5, 1e-2))
@example(n=1, m=1, data=None, dt_s=1e-3)
def test_cached_and_direct_discretisations_are_the_same_bits(tmp_path_factory, n, m, data, dt_s):
    if data is None:
        a, b = np.array([[-1.0]]), np.array([[1.0]])
    else:
        a = np.array(data.draw(st.lists(_finite, min_size=n * n, max_size=n * n))).reshape(n, n) / 1e2
        b = np.array(data.draw(st.lists(_finite, min_size=n * m, max_size=n * m))).reshape(n, m)
    folder = tmp_path_factory.mktemp("cache")
    ad0, bd0 = _direct(a, b, dt_s)
    for _ in range(2):                  # the miss, then the hit
        ad, bd = zoh(a, b, dt_s, ExactCache(folder))
        assert _same_bits(ad, ad0) and _same_bits(bd, bd0)


_BUILD = ("import sys; from swerve.configs import shipped; "
          "from swerve.emulator.physics.params import load_config; "
          "from swerve.emulator.physics.robot import RobotPhysics, load_robot_geometry; "
          "robot = RobotPhysics(load_config(shipped('emulator.yaml')), load_robot_geometry()); "
          "[m.prepare(1e-3) for m in robot.servos.values()]; "
          "print('mpmath' in sys.modules, *(v.hex() for m in robot.servos.values() "
          "for part in m.motor.coefficients(1e-3, False) for row in part for v in row))")


def test_a_start_up_with_a_warm_cache_imports_no_mpmath(tmp_path):
    """A robot's physics built in a fresh process: the first one computes (and imports mpmath),
    the second finds every value in the cache and imports none, with the same coefficients."""
    env = {"XDG_CACHE_HOME": str(tmp_path), "SWERVE_NO_JIT": "1", "PATH": "/usr/bin:/bin"}
    runs = [subprocess.run([sys.executable, "-c", _BUILD], env=env, capture_output=True, text=True,
                           check=True).stdout.split() for _ in range(2)]
    assert runs[0][0] == "True" and runs[1][0] == "False"
    assert runs[0][1] == runs[1][1]
    assert list((tmp_path / "swerve").glob("exact-*.f8"))
