"""The one config loader: malformed files give one-line errors naming file, line and key."""
from __future__ import annotations

import re
import warnings

import pytest

from swerve.configs import shipped
from swerve.core.errors import ConfigError
from swerve.configs.loader import ConfigWarning, document, parse_yaml_text, read_yaml
from swerve.controller.errors import ControllerError
from swerve.controller.trajectory import load_trajectory
from swerve.driver.robot_config import load_robot_config
from swerve.emulator.physics.params import load_config

ROBOT = shipped("robot.yaml").read_text()
EMULATOR = shipped("emulator.yaml").read_text()


def _line_of(text: str, needle: str) -> int:
    """1-based line of the first line containing ``needle``."""
    for no, line in enumerate(text.splitlines(), 1):
        if needle in line:
            return no
    raise AssertionError(f"{needle!r} not in text")


def _replace(text: str, old: str, new: str) -> str:
    assert text.count(old) == 1, old
    return text.replace(old, new)


def _check_file_error(tmp_path, base: str, old: str, new: str, name: str, load, error, key: str,
                      problem: str, needle: str | None = None) -> None:
    """Write ``base`` with ``old`` -> ``new`` to ``name``; ``load`` must raise ``error`` on the
    line holding ``needle`` (default: the last line of ``new``), naming ``key``."""
    text = _replace(base, old, new)
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(error) as ei:
        load(p)
    line = _line_of(text, needle or new.strip().splitlines()[-1])
    assert re.search(problem, _one_line(ei.value, p, line, key)), str(ei.value)


def _one_line(exc: ConfigError, file, line, key) -> str:
    msg = str(exc)
    assert "\n" not in msg
    assert (exc.file, exc.line, exc.key) == (str(file), line, key)
    prefix = f"{file}:{line}: {key}: " if key else f"{file}:{line}: "
    assert msg.startswith(prefix), msg
    return msg[len(prefix):]


# -- robot.yaml --------------------------------------------------------------------------------

ROBOT_BAD = [
    # (old text, new text, key, line needle (None: the replaced line), problem regex)
    ("a_m: 0.1125 ", "a_m: .nan ", "geometry.a_m", None, r"expected a finite number, got nan"),
    ("a_m: 0.1125 ", "a_m: .inf ", "geometry.a_m", None, r"expected a finite number, got inf"),
    ("a_m: 0.1125 ", "a_m: 1.0e+300 ", "geometry.a_m", None, r"1e\+300 is outside \[0.02, 5\] m"),
    ("a_m: 0.1125 ", "a_m: 1e300 ", "geometry.a_m", None, r"expected a number, got the string '1e300' \(YAML"),
    ("wheel_radius_m: 0.033", "wheel_radius_m: -0.033", "geometry.wheel_radius_m", None, r"-0.033 is outside \[0.005, 1\] m"),
    ("a_m: 0.1125 ", "a_m: [1, 2] ", "geometry.a_m", None, r"expected a number, got a list"),
    ("protocol: 2.0", "protocol: two", "link.protocol", None, r"expected a number, got the string 'two'"),
    ("protocol: 2.0", "protocol: 1.0", "link.protocol", None, r"expected one of 2, got 1"),
    ("port: /dev/ttyUSB0", "port: 5", "link.port", None, r"expected a non-empty string, got 5"),
    ("baud: 1000000", "baud: 1000001", "link.baud", None, r"expected one of 9600, .*, got 1000001"),
    ("operating_mode: velocity", "operating_mode: warp", "drive.operating_mode", None,
     r"expected one of current, velocity, position, .*got the string 'warp'"),
    ("operating_mode: velocity", "operating_mode: true", "drive.operating_mode", None,
     r"expected one of .* got a boolean"),
    ("bus_watchdog_s: 0.1", "bus_watchdog_s: 3.0", "safety.bus_watchdog_s", None, r"3 is outside \[0, 2.54\]"),
    ("max_consecutive_timeouts: 3", "max_consecutive_timeouts: 2.5", "safety.max_consecutive_timeouts",
     None, r"expected an integer, got 2.5"),
    ("center_pulse: [2048, 2048, 2048, 2048]", "center_pulse: [2048, 2048, 9999, 2048]",
     "steering.center_pulse[2]", None, r"9999 is outside \[0, 4095\]"),
    ("drive_id: 3,", "drive_id: 1,", "wheels[2].drive_id", "steer_id: 7,",
     r"duplicate servo ID 1 \(also wheels\[0\]\.drive_id\)"),
    ("  bus_watchdog_s: 0.1 ", "  bus_watchdog: 0.1 ", "safety.bus_watchdog_s", "safety:", r"missing$"),
]


@pytest.mark.parametrize("old, new, key, needle, problem", ROBOT_BAD,
                         ids=[f"{b[2]}={b[1].split(':', 1)[1].strip()[:20]}" for b in ROBOT_BAD])
def test_robot_file_errors_name_file_line_and_key(tmp_path, old, new, key, needle, problem):
    _check_file_error(tmp_path, ROBOT, old, new, "robot.yaml", load_robot_config, ConfigError, key, problem,
                      needle)


def test_unknown_key_is_a_warning_naming_file_line_and_key(tmp_path):
    text = _replace(ROBOT, "  a_m: 0.1125 ", "  a_mm: 3\n  a_m: 0.1125 ")
    p = tmp_path / "robot.yaml"
    p.write_text(text)
    with pytest.warns(ConfigWarning) as rec:
        cfg = load_robot_config(p)
    assert cfg.a_m == 0.1125
    assert [str(w.message) for w in rec] == [f"{p}:{_line_of(text, 'a_mm')}: geometry.a_mm: unknown key, ignored"]


def test_shipped_files_have_no_unknown_keys():
    with warnings.catch_warnings():
        warnings.simplefilter("error", ConfigWarning)
        load_robot_config()
        load_config()
        for name in ("line", "circle", "curvilinear"):
            load_trajectory(name)


# -- whole-file problems -------------------------------------------------------------------------

@pytest.mark.parametrize("content, line, problem", [
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", None, r"binary file"),
    (b"name: caf\xe9\n", 1, r"not UTF-8 text \(byte 0xe9 at offset 9\)"),
    (b"", 1, r"expected a mapping at the top level, got an empty document"),
    (b"# only a comment\n", 1, r"expected a mapping at the top level, got an empty document"),
    (b"- 1\n- 2\n", 1, r"expected a mapping at the top level, got list"),
    (b"just text\n", 1, r"expected a mapping at the top level, got str"),
    (b"geometry:\n  a_m: [1, 2\n", 3, r"not valid YAML: .*expected ',' or ']'"),
    (b"geometry:\n  a_m: 1.0\n  b_m: 1.0\n  a_m: 2.0\n", 4, r"geometry\.a_m: duplicate key \(first on line 2\)"),
])
def test_malformed_files(tmp_path, content, line, problem):
    p = tmp_path / "robot.yaml"
    p.write_bytes(content)
    with pytest.raises(ConfigError) as ei:
        load_robot_config(p)
    msg = str(ei.value)
    assert "\n" not in msg and ei.value.file == str(p) and ei.value.line == line
    head = f"{p}:{line}: " if line is not None else f"{p}: "
    key = "(top level): " if "top level" in problem else ""
    assert msg.startswith(head + key), msg
    assert re.search(problem, msg), msg


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match=r"missing\.yaml: cannot read robot config: No such file"):
        load_robot_config(tmp_path / "missing.yaml")


# -- emulator.yaml -------------------------------------------------------------------------------

EMU_BAD = [
    ("  rate_hz: 2000 ", "  rate_hz: 500 ", "physics.rate_hz", r"500 is outside \[1000, "),
    ("friction_nm_s_per_rad: 3.6e-7", "friction_nm_s_per_rad: -3.6e-7", "motors.drive.friction_nm_s_per_rad",
     r"must be >= 0, got -3.6e-07"),
    ("  norm: mag ", "  norm: bogus ", "bessel.norm", r"expected one of mag, phase, delay; got the string 'bogus'"),
    ("  load_enabled: true ", "  load_enabled: yes please ", "body.load_enabled", r"expected true or false"),
    ("  velocity_p_gain: 250\n", "  velocity_p_gain: 99999\n", "paper_spec_gains.velocity_p_gain",
     r"99999 is outside \[0, 16383\]"),
    ("  xh430-w210: 212.6", "  xh430-w210: .inf", "gear_ratios.xh430-w210", r"expected a finite number"),
]


@pytest.mark.parametrize("old, new, key, problem", EMU_BAD, ids=[b[2] for b in EMU_BAD])
def test_emulator_file_errors(tmp_path, old, new, key, problem):
    _check_file_error(tmp_path, EMULATOR, old, new, "emulator.yaml", load_config, ConfigError, key, problem)


def test_missing_top_level_section_names_the_first_line(tmp_path):
    text = EMULATOR.replace("physics:", "physic:")
    p = tmp_path / "emulator.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    assert _one_line(ei.value, p, _line_of(text, "physic:"), "physics") == "missing"


# -- trajectory files ----------------------------------------------------------------------------

TRAJ = "name: t\ntf_s: 16\ntau_s: 0.016\npath: {type: circle, radius_m: 1.0}\n"


@pytest.mark.parametrize("old, new, key, problem", [
    ("path: {type: circle, radius_m: 1.0}", "path: hello", "path", r"expected a mapping, got the string 'hello'"),
    ("radius_m: 1.0", "radius_m: -1.0", "path.radius_m", r"must be > 0"),
    ("radius_m: 1.0", "radius_m: .nan", "path.radius_m", r"expected a finite number"),
    ("tf_s: 16", "tf_s: 1.0e+300", "tf_s", r"is outside"),
    ("tau_s: 0.016", "tau_s: fast", "tau_s", r"expected a number, got the string 'fast'"),
    ("tf_s: 16", "tf_s: 16\nQ_diag: [1, 2, 3]", "Q_diag", r"expected a list of 5 numbers"),
    ("tf_s: 16", "tf_s: 16\nR_diag: [1, 0, 3]", "R_diag[1]", r"must be > 0"),
    ("tf_s: 16", "tf_s: 16\nn_steps: 999", "n_steps", r"need tf_s = n_steps \* tau_s"),
    ("tf_s: 16", "tf_s: 16\nstart: {x_m: 0, steering_rad: [0.1]}", "start.steering_rad",
     r"expected a list of 2 numbers"),
])
def test_trajectory_file_errors(tmp_path, old, new, key, problem):
    _check_file_error(tmp_path, TRAJ, old, new, "t.yaml", load_trajectory, ControllerError, key, problem)


def test_trajectory_binary_file(tmp_path):
    p = tmp_path / "t.yaml"
    p.write_bytes(bytes(range(256)))
    with pytest.raises(ControllerError, match=r"t\.yaml: binary file"):
        load_trajectory(p)


# -- the loader's accessors on their own ----------------------------------------------------------

def test_accessors_on_parsed_text():
    doc = parse_yaml_text("a:\n  n: 3\n  xs: [1, 2.5]\n  flag: false\n  s: hi\n", "f.yaml")
    a = doc.root().section("a")
    assert a.integer("n", min=0, max=3) == 3
    assert a.numbers("xs", 2) == (1.0, 2.5)
    assert a.boolean("flag") is False
    assert a.string("s") == "hi"
    assert a.choice("s", {"hi": 1, "lo": 2}) == 1
    assert a.number("absent", 0.5) == 0.5
    assert a.section("none", required=False).number("x", 1.0) == 1.0
    with pytest.raises(ConfigError) as ei:
        a.integer("n", max=2)
    assert str(ei.value) == "f.yaml:2: a.n: 3 is outside [-inf, 2]"
    with pytest.raises(ConfigError) as ei:
        a.numbers("xs", 3)
    assert str(ei.value) == "f.yaml:3: a.xs: expected a list of 3 numbers, got [1, 2.5]"
    with pytest.raises(ConfigError, match=r"^f\.yaml:4: a\.flag: expected a number, got a boolean"):
        a.number("flag")


def test_strict_unknown_keys_are_errors():
    top = parse_yaml_text("x: 1\ny: 2\n", "f.yaml").root()
    top.number("x")
    with pytest.raises(ConfigError) as ei:
        top.check_unknown(strict=True)
    assert (str(ei.value), ei.value.line, ei.value.key) == ("f.yaml:2: y: unknown key", 2, "y")


def test_parsed_data_has_no_line():
    with pytest.raises(ConfigError) as ei:
        document({"a": {"b": "x"}}, "robot.yaml").root().section("a").number("b")
    assert str(ei.value) == "robot.yaml: a.b: expected a number, got the string 'x'"
    assert ei.value.line is None


def test_read_yaml_keeps_lines_of_list_items(tmp_path):
    p = tmp_path / "l.yaml"
    p.write_text("items:\n  - {v: 1}\n  - {v: two}\n")
    items = read_yaml(p).root().items("items", 2)
    with pytest.raises(ConfigError, match=r"l\.yaml:3: items\[1\]\.v: expected a number"):
        items[1].number("v")
