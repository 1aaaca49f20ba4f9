"""The campaign file loader: every bad input is one ``FILE:LINE: KEY: problem`` error, before
anything runs; good files load; the shipped campaigns load."""
from __future__ import annotations

import importlib.util
import math
import re

import pytest
import yaml
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from swerve.configs import shipped
from swerve.core.errors import ConfigError
from swerve.tools.campaign.spec import SAMPLES_MAX, load_campaign, parse_campaign_text, profile_data
from swerve.tools.cli import main

TRAJ = str(shipped("campaigns/trajectories/line-6s.yaml"))


def base() -> dict:
    return dict(seed=3, samples=2, trajectories=[TRAJ], profiles=["realistic"], calibrate=[False, True],
                parameters={"contact.friction_coefficient": dict(dist="uniform", min=0.5, max=1.0),
                            "tolerances.wheel_radius_scale": dict(dist="normal", mean=1.0, std=0.01, min=0.97,
                                                                  max=1.03, wheels="each")})


def load(data: dict):
    text = yaml.safe_dump(data, sort_keys=False)
    return parse_campaign_text(text, "c.yaml", shipped("campaigns"))


def assert_one_line(exc: ConfigError, key: str) -> None:
    msg = str(exc)
    assert "\n" not in msg
    assert re.match(r"^c\.yaml:\d+: ", msg), msg
    assert key in msg, msg
    assert exc.line is not None and exc.key is not None and key.split(".")[0] in exc.key


def test_a_good_file_loads():
    c = load(base())
    assert c.scenarios == 4 and len(c.cells) == 2
    assert [p.columns for p in c.parameters][1] == tuple(f"tolerances.wheel_radius_scale[{w}]" for w in range(4))


@pytest.mark.parametrize("name", ["smoke", "tolerances"])
def test_shipped_campaigns_load(name):
    c = load_campaign(name)
    assert c.scenarios >= 1 and c.parameters


_names = st.text(st.sampled_from("abcdefghijklmnopqrstuvwxyz_"), min_size=1, max_size=12)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_names)
@example("sample")
def test_unknown_top_key(key):
    data = base()
    if key in data or key in ("name", "robot", "gains", "faults", "calibration"):
        return
    data[key] = 1
    with pytest.raises(ConfigError) as e:
        load(data)
    assert_one_line(e.value, key)
    assert "unknown key" in str(e.value)


@settings(max_examples=25, deadline=None)
@given(_names, _names)
@example("tolerances", "wheel_radius")
@example("contact", "friction")
def test_unknown_parameter(section, key):
    if key in profile_data("realistic").get(section, {}):
        return                  # a key the emulator reads: not unknown
    data = base()
    data["parameters"] = {f"{section}.{key}": dict(dist="uniform", min=0.5, max=1.0)}
    with pytest.raises(ConfigError) as e:
        load(data)
    assert_one_line(e.value, f"{section}.{key}")


@settings(max_examples=40, deadline=None)
@given(st.floats(allow_nan=True, allow_infinity=True), st.floats(allow_nan=True, allow_infinity=True),
       st.sampled_from(["uniform", "normal"]))
@example(1.0, 0.5, "uniform")
@example(0.7, 0.7, "uniform")
@example(math.nan, 1.0, "normal")
@example(0.5, math.inf, "uniform")
def test_bounds_inverted_or_not_finite(lo, hi, kind):
    if math.isfinite(lo) and math.isfinite(hi) and lo < hi:
        return
    data = base()
    spec = dict(dist=kind, min=lo, max=hi)
    if kind == "normal":
        spec.update(mean=0.8, std=0.1)
    data["parameters"] = {"contact.friction_coefficient": spec}
    with pytest.raises(ConfigError) as e:
        load(data)
    assert_one_line(e.value, "contact.friction_coefficient")


@settings(max_examples=40, deadline=None)
@given(st.one_of(st.integers(max_value=0), st.integers(min_value=SAMPLES_MAX // 4 + 1, max_value=10**12)))
@example(0)
@example(-1)
@example(SAMPLES_MAX + 1)
def test_sample_count_out_of_range(n):
    data = base()              # 4 grid cells... 2 cells: n * 2 > 1e6 is refused too
    data["samples"] = n
    if 0 < n and n * 2 <= SAMPLES_MAX:
        return
    with pytest.raises(ConfigError) as e:
        load(data)
    assert_one_line(e.value, "samples")


@settings(max_examples=25, deadline=None)
@given(_names, st.sampled_from(["", ".yaml", ".csv"]))
@example("no_such_path", ".yaml")
def test_missing_trajectory(name, suffix):
    data = base()
    data["trajectories"] = [TRAJ, f"missing/{name}{suffix}" if suffix else f"{name}_nope"]
    with pytest.raises(ConfigError) as e:
        load(data)
    assert_one_line(e.value, "trajectories")


def test_a_value_the_emulator_refuses_is_named():
    data = base()
    data["parameters"] = {"contact.friction_coefficient": dict(dist="uniform", min=-1.0, max=1.0)}
    with pytest.raises(ConfigError, match=r"c\.yaml:\d+: parameters\.contact\.friction_coefficient: "
                                          r"the emulator refuses -1\.0"):
        load(data)


def test_bad_fault_spec_is_named():
    data = base()
    data["faults"] = ["", "drop=2"]
    with pytest.raises(ConfigError, match=r"c\.yaml:\d+: faults\[1\]: .*drop"):
        load(data)


def test_a_normal_mostly_outside_its_bounds_is_refused():
    data = base()
    data["parameters"] = {"contact.friction_coefficient": dict(dist="normal", mean=0.5, std=100.0, min=0.5,
                                                               max=0.51)}
    with pytest.raises(ConfigError, match="std"):
        load(data)


def test_cli_names_the_file_and_line(tmp_path, capsys):
    from swerve.tools.cli import main

    bad = tmp_path / "bad.yaml"
    data = base()
    data["samples"] = 0
    bad.write_text(yaml.safe_dump(data, sort_keys=False))
    assert main(["campaign", "run", str(bad), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert re.fullmatch(rf"swerve campaign: error: {re.escape(str(bad))}:\d+: samples: .*", err), err
    assert not (tmp_path / "out").exists()


def test_ray_missing_is_one_line_before_any_output(tmp_path, capsys, monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "ray" else real(name, *a))
    out = tmp_path / "out"
    assert main(["campaign", "run", "smoke", "--out", str(out), "--ray", "auto"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and 'pip install "swerve[cluster]"' in err[0], err
    assert not out.exists()
