"""The overlay cache: a hit gives the simulation's bits without simulating, any changed input of
the law misses, a damaged file is simulated again, an unwritable folder only loses the cache."""
import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import assume, given, settings, strategies as st

from swerve.controller import overlay_cache, simulate as simulate_module
from swerve.controller.errors import ControllerError
from swerve.controller.gain_schedule import synthesize
from swerve.controller.kinematics import Limits
from swerve.controller.overlay_cache import OverlayCache, overlay_key, simulated_poses
from swerve.controller.paths import CirclePath
from swerve.controller.tracking import TrackingLaw
from swerve.controller.trajectory import load_trajectory

from .conftest import damage_cache_file, short


def _law(robot, name="line", n_steps=120, limits=None):
    geom, lim = robot
    traj = short(load_trajectory(name, geom, lim), n_steps)
    ref, gains = synthesize(traj, "riccati", geom, limits or lim)
    return TrackingLaw(ref, gains, limits or lim), traj.start_state(geom)


def _same_bits(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def test_a_hit_returns_the_simulations_bits_without_simulating(tmp_path, robot, monkeypatch):
    law, start = _law(robot)
    direct = simulated_poses(law, start)
    cache = OverlayCache(tmp_path)
    first = cache.poses(law, start)
    assert (cache.hits, cache.misses) == (0, 1) and len(list(tmp_path.glob("overlay-*.f8"))) == 1

    def refuse(*args, **kwargs):
        raise AssertionError("simulated although the cache holds the poses")

    monkeypatch.setattr(overlay_cache, "simulate", refuse)
    again = OverlayCache(tmp_path)
    second = again.poses(law, start)
    assert again.hits == 1
    assert direct.shape == (120, 3) and _same_bits(first, direct) and _same_bits(second, direct)


def test_the_law_is_left_as_a_fresh_one(tmp_path, robot):
    law, start = _law(robot)
    fresh, _ = _law(robot)
    for _ in range(2):                  # the miss, then the hit
        OverlayCache(tmp_path).poses(law, start)
        a, b = law.step(0.0, start), fresh.step(0.0, start)
        assert a.inputs == b.inputs and a.reference_time_s == b.reference_time_s
        law.reset()
        fresh.reset()


@pytest.mark.parametrize("change", ["start", "K", "limits", "path", "steps", "governor", "trajectory name"])
def test_a_changed_input_misses(tmp_path, robot, change):
    law, start = _law(robot)
    cache = OverlayCache(tmp_path)
    cache.poses(law, start)
    if change == "start":
        start = start.copy()
        start[0] = np.nextafter(start[0], 1.0)             # one ulp
    elif change == "K":
        gains = law.gains
        K = gains.K.copy()
        K[60, 1, 2] = np.nextafter(K[60, 1, 2], np.inf)
        law = TrackingLaw(law.reference, dataclasses.replace(gains, K=K), law.limits)
    elif change == "limits":
        lim = law.limits
        law = TrackingLaw(law.reference, law.gains, dataclasses.replace(lim, v1_max_mps=lim.v1_max_mps * 0.5))
    elif change == "path":                  # the same grid tables, another path off the grid
        ref = law.reference
        traj = dataclasses.replace(ref.trajectory, path=CirclePath(1e6, 1e9, 1e9))
        law = TrackingLaw(dataclasses.replace(ref, trajectory=traj), law.gains, law.limits)
    elif change == "steps":
        law, start = _law(robot, n_steps=119)
    elif change == "governor":
        law = TrackingLaw(law.reference, law.gains, law.limits, governor=False)
    else:
        ref = law.reference
        law = TrackingLaw(dataclasses.replace(ref, trajectory=dataclasses.replace(ref.trajectory, name="other")),
                          law.gains, law.limits)
    poses = cache.poses(law, start)
    assert (cache.hits, cache.misses) == (0, 2)
    assert _same_bits(poses, simulated_poses(law, start))


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty", "other key"])
def test_a_damaged_file_is_simulated_again_and_rewritten(tmp_path, robot, damage):
    law, start = _law(robot)
    direct = simulated_poses(law, start)
    OverlayCache(tmp_path).poses(law, start)
    (path,) = tmp_path.glob("overlay-*.f8")
    def other():                        # a whole valid file of another law under this name
        other_law, other_start = _law(robot, n_steps=100)
        OverlayCache(tmp_path / "other").poses(other_law, other_start)
        return next((tmp_path / "other").glob("*.f8")).read_bytes()

    damage_cache_file(path, damage, len(overlay_cache.LAYOUT) + 32 + 100, other)     # flip: inside the poses
    cache = OverlayCache(tmp_path)
    assert _same_bits(cache.poses(law, start), direct) and (cache.hits, cache.misses) == (0, 1)
    again = OverlayCache(tmp_path)
    assert _same_bits(again.poses(law, start), direct) and again.hits == 1


def test_an_unwritable_folder_only_loses_the_cache(tmp_path, robot):
    blocker = tmp_path / "file"
    blocker.write_text("a file where the cache folder should be")
    law, start = _law(robot)
    cache = OverlayCache(blocker / "swerve")
    assert _same_bits(cache.poses(law, start), simulated_poses(law, start)) and cache.misses == 1


def test_an_unpicklable_trajectory_is_simulated_every_time(tmp_path, robot):
    law, start = _law(robot)
    ref = law.reference
    traj = dataclasses.replace(ref.trajectory, path=_LocalPath(ref.trajectory.path))
    law = TrackingLaw(dataclasses.replace(ref, trajectory=traj), law.gains, law.limits)
    assert overlay_key(law, start) is None
    cache = OverlayCache(tmp_path)
    assert _same_bits(cache.poses(law, start), simulated_poses(law, start))
    assert (cache.hits, cache.misses) == (0, 0) and not list(tmp_path.iterdir())


class _LocalPath:
    """A path holding a local function, which pickle refuses."""

    def __init__(self, inner):
        self.inner = inner
        self.derivatives = lambda t: inner.derivatives(t)
        self.t_end_s = inner.t_end_s


def test_the_key_covers_the_code(tmp_path, robot, monkeypatch):
    law, start = _law(robot)
    key = overlay_key(law, start)
    package = Path(simulate_module.__file__).parent
    for source in package.glob("*.py"):
        (tmp_path / source.name).write_bytes(source.read_bytes())
    monkeypatch.setattr(overlay_cache, "tracking", SimpleNamespace(__file__=str(tmp_path / "tracking.py")))
    overlay_cache._code_digest.cache_clear()
    try:
        assert overlay_key(law, start) == key                   # a copy of the same code
        overlay_cache._code_digest.cache_clear()
        (tmp_path / "simulate.py").write_bytes(Path(simulate_module.__file__).read_bytes() + b"\n# edited\n")
        assert overlay_key(law, start) != key
    finally:
        overlay_cache._code_digest.cache_clear()


@settings(max_examples=10, deadline=None)
@given(n_steps=st.integers(10, 80), x0=st.floats(-0.05, 0.05), theta0=st.floats(-0.3, 0.3),
       v1_max=st.floats(0.02, 0.2), name=st.sampled_from(["line", "circle", "curvilinear"]))
def test_cached_and_simulated_poses_are_the_same_bits(tmp_path_factory, robot, n_steps, x0, theta0, v1_max, name):
    geom, lim = robot
    limits = Limits(v1_max, lim.steer_rate_max_radps, lim.steer_angle_max_rad)
    try:
        law, start = _law(robot, name, n_steps, limits)
    except ControllerError:             # the path needs more than these limits allow
        assume(False)
    start = start + np.array([x0, 0.0, theta0, 0.0, 0.0])
    folder = tmp_path_factory.mktemp("cache")
    direct = simulated_poses(law, start)
    for _ in range(2):                  # the miss, then the hit
        assert _same_bits(OverlayCache(folder).poses(law, start), direct)
