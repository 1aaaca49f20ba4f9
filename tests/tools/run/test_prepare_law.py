"""Loading a gain schedule for a run: the reference is rebuilt in the schedule's own frames."""
from swerve.controller.gain_schedule import synthesize
from swerve.controller.gains_io import save_gains
from swerve.controller.trajectory import load_trajectory
from swerve.tools.run.orchestrate import prepare_law
from swerve.tools.run.geometry import load_robot


def test_gains_for_the_plain_law_load_with_fixed_frames(tmp_path):
    geom, limits = load_robot()
    _, gains = synthesize(load_trajectory("line", geom), "riccati", geom, limits, frames="fixed")
    path = save_gains(tmp_path / "line_fixed.npz", gains)
    _, law = prepare_law("line", path, geom, limits)
    assert law.plain and law.reference.frames == "fixed"
    _, default = prepare_law("line", None, geom, limits)
    assert not default.plain
