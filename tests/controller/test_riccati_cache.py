"""The Riccati cache: a hit gives the solver's bits, any changed input misses, a damaged file is
recomputed, an unwritable folder only loses the cache."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from swerve.controller import riccati, riccati_cache
from swerve.controller.gain_schedule import synthesize
from swerve.controller.riccati_cache import RiccatiCache, riccati_key
from swerve.controller.trajectory import load_trajectory

from .conftest import damage_cache_file


def _problem(n_steps=40, seed=0):
    rng = np.random.default_rng(seed)
    Ad = np.eye(5) + 0.05 * rng.standard_normal((n_steps, 5, 5))
    Bd = 0.1 * rng.standard_normal((n_steps, 5, 3))
    return Ad, Bd, np.diag([1.0, 1.0, 0.5, 0.1, 0.1]), np.eye(3), 0.016


def _same_bits(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_a_hit_returns_the_solvers_bits_without_solving(tmp_path, monkeypatch):
    Ad, Bd, Q, R, tau = _problem()
    K0, P0 = riccati.finite_horizon_lqr(Ad, Bd, Q, R, tau)
    cache = RiccatiCache(tmp_path)
    K1, P1 = cache.solve(Ad, Bd, Q, R, tau)
    assert (cache.hits, cache.misses) == (0, 1)
    assert len(list(tmp_path.glob("riccati-*.f8"))) == 1

    def refuse(*args, **kwargs):
        raise AssertionError("solved although the cache holds the answer")

    monkeypatch.setattr(riccati, "finite_horizon_lqr", refuse)
    K2, P2 = RiccatiCache(tmp_path).solve(Ad, Bd, Q, R, tau)
    for a, b in ((K0, K1), (K0, K2), (P0, P1), (P0, P2)):
        assert _same_bits(a, b)


@pytest.mark.parametrize("change", ["Ad", "Bd", "Q", "R", "tau", "steps"])
def test_a_changed_input_misses(tmp_path, change):
    Ad, Bd, Q, R, tau = _problem()
    cache = RiccatiCache(tmp_path)
    cache.solve(Ad, Bd, Q, R, tau)
    if change == "Ad":
        Ad = Ad.copy()
        Ad[7, 2, 3] = np.nextafter(Ad[7, 2, 3], np.inf)     # one ulp
    elif change == "Bd":
        Bd = Bd.copy()
        Bd[-1, 4, 0] += 1e-12
    elif change == "Q":
        Q = Q * 2
    elif change == "R":
        R = R * 0.5
    elif change == "tau":
        tau = np.nextafter(tau, 1.0)
    else:
        Ad, Bd = Ad[:-1], Bd[:-1]
    K, P = cache.solve(Ad, Bd, Q, R, tau)
    assert (cache.hits, cache.misses) == (0, 2)
    K0, P0 = riccati.finite_horizon_lqr(Ad, Bd, Q, R, tau)
    assert _same_bits(K, K0) and _same_bits(P, P0)


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty", "other key"])
def test_a_damaged_file_is_recomputed_and_rewritten(tmp_path, damage):
    Ad, Bd, Q, R, tau = _problem()
    K0, P0 = riccati.finite_horizon_lqr(Ad, Bd, Q, R, tau)
    RiccatiCache(tmp_path).solve(Ad, Bd, Q, R, tau)
    (path,) = tmp_path.glob("riccati-*.f8")
    def other():                        # a whole valid file of another input under this name
        RiccatiCache(tmp_path / "other").solve(*_problem(seed=1))
        return next((tmp_path / "other").glob("*.f8")).read_bytes()

    damage_cache_file(path, damage, len(riccati_cache.LAYOUT) + 32 + 200, other)     # flip: inside the K values
    cache = RiccatiCache(tmp_path)
    K, P = cache.solve(Ad, Bd, Q, R, tau)
    assert (cache.hits, cache.misses) == (0, 1)
    assert _same_bits(K, K0) and _same_bits(P, P0)
    again = RiccatiCache(tmp_path)
    K2, _ = again.solve(Ad, Bd, Q, R, tau)
    assert again.hits == 1 and _same_bits(K2, K0)


def test_an_unwritable_folder_only_loses_the_cache(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder should be")
    Ad, Bd, Q, R, tau = _problem()
    cache = RiccatiCache(blocker / "swerve")
    K, _ = cache.solve(Ad, Bd, Q, R, tau)
    assert cache.misses == 1 and _same_bits(K, riccati.finite_horizon_lqr(Ad, Bd, Q, R, tau)[0])


def test_the_key_covers_the_code(tmp_path, monkeypatch):
    Ad, Bd, Q, R, tau = _problem()
    key = riccati_key(Ad, Bd, Q, R, tau)
    edited = tmp_path / "riccati.py"
    edited.write_bytes(open(riccati.__file__, "rb").read() + b"\n# edited\n")
    monkeypatch.setattr(riccati, "__file__", str(edited))
    assert riccati_key(Ad, Bd, Q, R, tau) != key


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_steps=st.integers(1, 30),
       tau=st.floats(1e-3, 0.1, allow_nan=False))
def test_cached_and_direct_solutions_are_the_same_bits(tmp_path_factory, seed, n_steps, tau):
    Ad, Bd, Q, R, _ = _problem(n_steps, seed)
    folder = tmp_path_factory.mktemp("cache")
    direct = riccati.finite_horizon_lqr(Ad, Bd, Q, R, tau)
    for _ in range(2):                  # the miss, then the hit
        cached = RiccatiCache(folder).solve(Ad, Bd, Q, R, tau)
        assert all(_same_bits(a, b) for a, b in zip(cached, direct))


def test_synthesize_with_the_cache_gives_the_same_schedule(tmp_path, robot):
    geom, limits = robot
    traj = load_trajectory("line", geom, limits)
    _, plain = synthesize(traj, "riccati", geom, limits)
    for _ in range(2):
        _, cached = synthesize(traj, "riccati", geom, limits, lqr=RiccatiCache(tmp_path).solve)
        assert _same_bits(cached.K, plain.K) and cached.cost == plain.cost and cached.meta == plain.meta
