"""The one way errors leave ``swerve``: one line per error, a traceback file for a bug, no warning noise."""
import argparse
import logging
import warnings

import pytest

from swerve.core.errors import ConfigError
from swerve.tools import argtypes, cli


@pytest.fixture
def command(monkeypatch):
    """Replace ``swerve sim``'s body with the function the test sets."""
    from swerve.tools.commands import sim

    holder = {}
    monkeypatch.setattr(sim, "run", lambda args: holder["fn"](args))
    return holder


def test_a_bug_is_one_line_naming_it_and_the_traceback_file(command, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path))

    def broken(args):
        return {}["missing key"]

    command["fn"] = broken
    assert cli.main(["sim", "--trajectory", "line"]) == cli.EXIT_BUG
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "internal error" in err[0] and "KeyError at test_cli_boundary.py" in err[0] and "in broken" in err[0]
    saved = list((tmp_path / "swerve").glob("crash-*.txt"))
    assert len(saved) == 1 and str(saved[0]) in err[0]
    text = saved[0].read_text()
    assert "Traceback" in text and "missing key" in text and "sim --trajectory line" in text


def test_verbose_shows_the_traceback_instead(command, capsys):
    command["fn"] = lambda args: 1 / 0
    assert cli.main(["-v", "sim", "--trajectory", "line"]) == cli.EXIT_BUG
    err = capsys.readouterr().err
    assert "Traceback" in err and "ZeroDivisionError" in err


def test_a_multi_line_error_is_printed_on_one_line(command, capsys):
    def fail(args):
        raise ConfigError("first\nsecond")

    command["fn"] = fail
    assert cli.main(["sim", "--trajectory", "line"]) == 2
    assert capsys.readouterr().err == "swerve sim: error: first second\n"


def test_warnings_are_hidden_and_logged_errors_not_repeated(command, capsys):
    def noisy(args):
        warnings.warn("numpy says something", RuntimeWarning)
        logging.getLogger("swerve.tools.run.loop").error("the robot stopped")
        logging.getLogger("swerve.driver.transport").warning("latency timer is 16 ms")
        logging.getLogger("swerve.driver.transport").warning("latency timer is 16 ms")
        raise ConfigError("the robot stopped")

    command["fn"] = noisy
    assert cli.main(["sim", "--trajectory", "line"]) == 2
    assert capsys.readouterr().err.splitlines() == ["swerve sim: warning: latency timer is 16 ms",
                                                     "swerve sim: error: the robot stopped"]


def test_an_os_error_is_one_line_with_the_file(command, capsys):
    def fail(args):
        open("/proc/no/such/file")

    command["fn"] = fail
    assert cli.main(["sim", "--trajectory", "line"]) == 1
    assert capsys.readouterr().err == "swerve sim: error: /proc/no/such/file: No such file or directory\n"


def test_a_bad_option_is_one_line(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["run", "--trajectory", "line", "--time-scale", "nan"])
    assert info.value.code == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "--time-scale" in err[0] and "'nan'" in err[0]


@pytest.mark.parametrize("text", ["nan", "inf", "-inf", "-1", "0", "2", "x", ""])
def test_finite_float_rejects_what_is_outside_its_range(text):
    with pytest.raises(argparse.ArgumentTypeError):
        argtypes.finite_float(0.0, 1.0, lo_open=True)(text)


def test_finite_float_and_int_range_accept_their_range():
    assert argtypes.finite_float(0.0, 1.0, lo_open=True)("1") == 1.0
    assert argtypes.finite_float(0.0, allow_inf=True)("inf") == float("inf")
    assert argtypes.servo_id("252") == 252
    with pytest.raises(argparse.ArgumentTypeError):
        argtypes.servo_id("253")
