import dataclasses

import numpy as np
import pytest

from swerve.controller.gain_schedule import synthesize
from swerve.controller.errors import ControllerError
from swerve.controller.gains_io import load_gains, save_gains
from swerve.controller.trajectory import load_trajectory



def short(traj, n_steps):
    """The first ``n_steps`` of a trajectory."""
    return dataclasses.replace(traj, n_steps=n_steps, tf_s=n_steps * traj.tau_s)


@pytest.fixture(scope="module")
def gains(robot):
    geom, limits = robot
    return synthesize(short(load_trajectory("circle", geom), 1200), "riccati", geom, limits)[1]


@pytest.mark.parametrize("suffix", [".npz", ".dat"])
def test_round_trip(tmp_path, gains, suffix):
    p = save_gains(tmp_path / f"g{suffix}", gains)
    g = load_gains(p)
    np.testing.assert_allclose(g.K, gains.K, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(g.phi_rad, gains.phi_rad, rtol=1e-8)
    np.testing.assert_allclose(g.Q, gains.Q)
    np.testing.assert_allclose(g.R, gains.R)
    assert (g.trajectory, g.method, g.tau_s) == ("circle", "riccati", 0.016)
    assert g.cost == pytest.approx(gains.cost)


def test_dat_is_a_62_5_hz_table(tmp_path, gains):
    p = save_gains(tmp_path / "g.dat", gains)
    table = np.loadtxt(p)
    assert table.shape == (1200, 17)
    np.testing.assert_allclose(np.diff(table[:, 0]), 1 / 62.5, rtol=1e-6)
    np.testing.assert_allclose(table[5, 1:16], gains.K[5].ravel(), rtol=1e-8)
    assert "sign_convention" in p.read_text().splitlines()[1]


def test_bad_files(tmp_path, gains):
    with pytest.raises(ControllerError, match="does not exist"):
        load_gains(tmp_path / "none.npz")
    p = save_gains(tmp_path / "g.dat", gains)
    text = p.read_text().splitlines()
    text[5] = " ".join(["nan"] * 17)
    p.write_text("\n".join(text))
    with pytest.raises(ControllerError, match="NaN"):
        load_gains(p)
    q = tmp_path / "short.dat"
    q.write_text("0 1 2\n")
    with pytest.raises(ControllerError, match="17 columns"):
        load_gains(q)
    with pytest.raises(ControllerError, match=".npz or .dat"):
        save_gains(tmp_path / "g.txt", gains)
