"""Draws are a pure function of (campaign, seed, sample): repeatable, independent of the order
or the other samples, within their bounds."""
from __future__ import annotations

import dataclasses

import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from swerve.configs import shipped
from swerve.tools.campaign.draw import draw_robot
from swerve.tools.campaign.scenario import scenario
from swerve.tools.campaign.spec import load_campaign, parse_campaign_text

TRAJ = str(shipped("campaigns/trajectories/line-6s.yaml"))


def campaign(lo: float, hi: float, kind: str, seed: int = 1, samples: int = 50):
    spec = dict(dist=kind, min=lo, max=hi)
    if kind == "normal":
        spec.update(mean=(lo + hi) / 2, std=(hi - lo) / 4)
    data = dict(seed=seed, samples=samples, trajectories=[TRAJ], profiles=["realistic"],
                parameters={"tolerances.wheel_radius_scale": dict(spec, wheels="each"),
                            "contact.friction_coefficient": dict(dist="choice", values=[0.6, 0.7, 0.9]),
                            "tolerances.encoder_offset_pulse": dict(dist="uniform", min=-5, max=5,
                                                                    wheels="same", integer=True)})
    return parse_campaign_text(yaml.safe_dump(data), "c.yaml", shipped("campaigns"))


@settings(max_examples=30, deadline=None)
@given(st.floats(0.5, 1.0), st.floats(0.001, 0.9), st.sampled_from(["uniform", "normal"]),
       st.integers(0, 2**32), st.integers(0, 10**5))
def test_draws_are_in_bounds_and_repeatable(lo, width, kind, seed, sample):
    c = campaign(lo, min(2.0, lo + width), kind, seed)
    a, b = draw_robot(c, sample), draw_robot(c, sample)
    assert a == b
    radius = a.values["tolerances.wheel_radius_scale"]
    assert len(radius) == 4 and all(lo <= r <= min(2.0, lo + width) for r in radius)
    assert a.values["contact.friction_coefficient"] in (0.6, 0.7, 0.9)
    enc = a.values["tolerances.encoder_offset_pulse"]
    assert len(set(enc)) == 1 and isinstance(enc[0], int) and -5 <= enc[0] <= 5


def test_a_sample_does_not_depend_on_order_sample_count_or_other_draws():
    c = campaign(0.97, 1.03, "normal", seed=11, samples=50)
    forward = [draw_robot(c, i) for i in range(50)]
    backward = [draw_robot(c, i) for i in reversed(range(50))][::-1]
    assert forward == backward
    assert draw_robot(c.with_samples(3), 2) == forward[2]
    # different samples and seeds are different robots
    assert len({r.values["tolerances.wheel_radius_scale"] for r in forward}) == 50
    other = dataclasses.replace(c, seed=12)
    assert draw_robot(other, 0) != forward[0]


def test_scenario_index_maps_to_sample_and_grid_cell():
    c = load_campaign("smoke")
    cells = len(c.cells)
    big = c.with_samples(3)
    for index in range(3 * cells):
        sc = scenario(big, index)
        assert sc.robot.sample == index // cells and sc.cell == c.cells[index % cells]
        assert sc.robot == draw_robot(c, index // cells)


def test_pinned_draw():
    """The first smoke robot, pinned: a change here changes every campaign's robots."""
    r = draw_robot(load_campaign("smoke"), 0)
    assert r.values["contact.friction_coefficient"] == 0.8
    assert r.values["tolerances.wheel_radius_scale"][0] == 0.9994577102407904
