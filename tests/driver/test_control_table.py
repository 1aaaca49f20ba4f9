"""Control tables as data: loading, lookups, raw/SI conversion, malformed files."""
import math

import pytest
import yaml

from swerve.driver import control_table as ct
from swerve.driver.control_table import Reg, load_table, models, table_for
from swerve.driver.errors import ConfigError, OutOfRangeError, RegisterError


# model numbers and gear ratios: e-Manual control table and Specifications of each model
@pytest.mark.parametrize("name,number,gear", [("xh430-w210", 1010, 212.6), ("xh430-w350", 1000, 353.5),
                                              ("xh540-w150", 1110, 152.3), ("xl430-w250", 1060, 258.5),
                                              ("xl330-m288", 1200, 288.4), ("xl330-m077", 1190, 77.5),
                                              ("xm430-w210", 1030, 212.6), ("xm430-w350", 1020, 353.5),
                                              ("xm540-w270", 1120, 272.5)])
def test_models_load_with_their_numbers(name, number, gear):
    t = table_for(name)
    assert t.model_number == number and t.gear_ratio == gear
    assert table_for(number) is t
    assert t[Reg.MODEL_NUMBER].default == number
    assert t[Reg.GOAL_POSITION].address == 116 and t[Reg.GOAL_POSITION].size == 4
    assert t[Reg.PRESENT_POSITION].address == 132 and t[Reg.PRESENT_POSITION].signed


def test_every_enum_name_used_by_some_model_and_tables_do_not_overlap():
    names = set().union(*(t.registers.keys() for t in models().values()))
    assert names == {r.value for r in Reg}


def test_model_specific_defaults():
    assert table_for("xh430-w210")[Reg.VELOCITY_LIMIT].default == 210
    assert table_for("xh430-w350")[Reg.VELOCITY_LIMIT].default == 130
    assert table_for("xh540-w150")[Reg.CURRENT_LIMIT].max == 2047
    assert Reg.EXTERNAL_PORT_DATA_1 in table_for("xh540-w150")
    assert Reg.EXTERNAL_PORT_DATA_1 not in table_for("xh430-w210")
    assert Reg.EXTERNAL_PORT_DATA_1 in table_for("xm540-w270")


def test_xl330_and_xl430_differ_from_the_xh_table():
    xl330, xl430 = table_for("xl330-m288"), table_for("xl430-w250")
    assert xl330[Reg.PRESENT_CURRENT].scale == pytest.approx(1e-3)          # 1 mA, not 2.69 mA
    assert xl330[Reg.BAUD_RATE].max == 6 and xl330[Reg.PWM_SLOPE].address == 62
    assert (xl330.indirect[0].data_start, xl330.indirect[0].target_max) == (208, 227)
    assert Reg.PRESENT_CURRENT not in xl430 and xl430[Reg.PRESENT_LOAD].address == 126
    assert Reg.GOAL_CURRENT not in xl430 and xl430[Reg.OPERATING_MODE].allowed == (1, 3, 4, 16)


def _library_with(tmp_path, files: dict[str, str]) -> ct.ModelLibrary:
    """A :class:`ModelLibrary` of the shipped reference model plus ``files`` (name -> YAML text)."""
    folder = tmp_path / "models"
    folder.mkdir()
    ref = f"{ct.REFERENCE_MODEL}.yaml"
    (folder / ref).write_bytes(ct.MODELS_DIR.joinpath(ref).read_bytes())
    for name, text in files.items():
        (folder / name).write_text(text)
    return ct.ModelLibrary(folder)


def test_baud_lists_must_begin_the_reference_list(tmp_path):
    doc = yaml.safe_load(ct.MODELS_DIR.joinpath("xl330-m288.yaml").read_text())
    baud = next(r for r in doc["registers"] if r["name"] == "baud_rate")
    baud["values_bps"] = [9600, 57600, 115200, 1000000, 2000000, 3000000, 4500000]
    library = _library_with(tmp_path, {"xl330-bad.yaml": yaml.safe_dump(doc)})
    assert library.table_for(ct.REFERENCE_MODEL).model_number == 1010    # the good file loads alone
    with pytest.raises(ConfigError, match="XL330-M288: baud_rate.values_bps does not begin XH430-W210's"):
        library.table_for("xl330-bad")                                     # the bad one fails when used
    with pytest.raises(ConfigError, match="does not begin"):
        library.all()
    with pytest.raises(ConfigError, match="does not begin"):
        library.table_for(1200)                                            # a number needs every file


def test_a_model_file_is_parsed_at_its_first_use_only(tmp_path):
    library = _library_with(tmp_path, {"xl330-broken.yaml": "registers: 3"})
    assert library.names() == ("xh430-w210", "xl330-broken")
    t = library.table_for("XH430-W210")                                     # the broken file is not read
    assert library.table_for("xh430-w210") is t
    with pytest.raises(ConfigError, match=r"xl330-broken\.yaml:1: registers: expected a list, got 3"):
        library.table_for("xl330-broken")
    with pytest.raises(ConfigError, match="unknown servo model 'xl330-m288'; known: xh430-w210, xl330-broken"):
        library.table_for("xl330-m288")
    with pytest.raises(ConfigError, match="unknown servo model"):
        library.table_for("../models/xh430-w210")                             # names, never paths


def test_lazy_tables_are_the_tables_of_a_full_load():
    fresh = ct.ModelLibrary(ct.MODELS_DIR)
    one = fresh.table_for("xm430-w350")
    every = {p.stem: load_table(p) for p in sorted(ct.MODELS_DIR.glob("*.yaml"))}
    assert fresh.all() == every == models()
    assert fresh.all()["xm430-w350"] is one
    assert [fresh.table_for(t.model_number).model for t in every.values()] == [t.model for t in every.values()]


def test_si_conversion_round_trip_and_signs():
    t = table_for("xh430-w210")
    pos, vel = t[Reg.GOAL_POSITION], t[Reg.GOAL_VELOCITY]
    assert pos.to_si(2048) == pytest.approx(math.pi)
    assert pos.from_si(math.pi) == 2048
    assert vel.to_si(-1) == pytest.approx(-0.229 * 2 * math.pi / 60)
    assert vel.from_si(-1.0) == round(-1.0 / (0.229 * 2 * math.pi / 60))
    assert vel.decode(vel.encode(-5)) == -5
    assert vel.encode(-1) == b"\xff\xff\xff\xff"
    assert t[Reg.PRESENT_CURRENT].to_si(100) == pytest.approx(0.269)


def test_out_of_range_raises_instead_of_clamping():
    t = table_for("xh430-w210")
    with pytest.raises(OutOfRangeError, match="goal_velocity"):
        t[Reg.GOAL_VELOCITY].from_si(100.0)  # rad/s, far above 1023 units
    with pytest.raises(OutOfRangeError):
        t[Reg.GOAL_POSITION].from_si(float("nan"))
    with pytest.raises(OutOfRangeError):
        t[Reg.OPERATING_MODE].check_raw(2)  # not an allowed mode


def test_unknown_register_is_a_clear_error():
    with pytest.raises(RegisterError, match="no register named 'goal_velocty'"):
        table_for("xh430-w210")["goal_velocty"]
    with pytest.raises(ConfigError, match="unknown servo model"):
        table_for("xh430-w150")


@pytest.mark.parametrize("text,match", [
    ("registers: 3", r"bad\.yaml:1: registers: expected a list, got 3"),
    ("model: X\nmodel_number: 1\ngear_ratio: 1\nregisters:\n  - {name: bogus, address: 0, size: 1, access: R, area: RAM, default: 0}",
     "unknown register name 'bogus'"),
    ("model: X\nmodel_number: 1\ngear_ratio: 1\nregisters:\n  - {name: led, address: 0, size: 3, access: R, area: RAM, default: 0}",
     "size must be"),
    ("model: X\nmodel_number: 1\ngear_ratio: 1\nregisters:\n  - {name: led, address: 0, size: 2, access: R, area: RAM, default: 0}\n"
     "  - {name: id, address: 1, size: 1, access: R, area: RAM, default: 0}", "overlap"),
    ("{{{", "not valid YAML"),
])
def test_malformed_table_files(tmp_path, text, match):
    p = tmp_path / "bad.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_table(p)


def test_registers_within_a_span_are_the_wholly_covered_ones():
    t = table_for("xh430-w210")
    names = [r.name for r in t.within(126, 10)]          # Present Current .. Present Position
    assert names == ["present_current", "present_velocity", "present_position"]
    assert [r.name for r in t.within(127, 9)] == ["present_velocity", "present_position"]   # half an item: out
    assert t.within(126, 10) is t.within(126, 10)        # cached
    assert t.within(0, 1) == ()                           # no 1-byte item at 0 (Model Number is 2 bytes)
