"""The log's overlay poses, simulated as the log asks for them, are those of ``simulate``."""
import numpy as np
import pytest

from swerve.controller.simulate import simulate
from swerve.tools.run.geometry import load_robot
from swerve.tools.run.orchestrate import OverlayPoses, prepare_law


@pytest.mark.parametrize("name", ["line", "circle"])
def test_overlay_poses_equal_the_whole_simulation_and_leave_the_law_alone(name):
    geom, limits = load_robot()
    traj, law = prepare_law(name, None, geom, limits)
    start = traj.start_state(geom)
    overlay = OverlayPoses(law, start)
    first = [law.step(0.0, start).inputs]              # the run's law in use while the overlay steps
    asked = [overlay[k] for k in (0, 1, 5, 4, 40)]      # in order, skipping ahead, and back
    whole = simulate(law, start).states[:, :3]
    law.reset()
    assert law.step(0.0, start).inputs == first[0]
    assert all(np.array_equal(p, whole[k]) for p, k in zip(asked, (0, 1, 5, 4, 40)))
    n = len(whole)
    assert all(np.array_equal(overlay[k], whole[k]) for k in range(n))      # bit for bit
    assert np.isnan(overlay[n]).all() and np.isnan(overlay[n + 10]).all()   # after its end
