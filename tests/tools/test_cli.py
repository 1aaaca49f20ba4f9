"""The swerve command: every planned subcommand is registered and user errors are one line."""
import subprocess
import sys

import pytest

from swerve.tools import cli


def test_every_subcommand_is_registered():
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    expected = {n.replace("_", "-") for n in cli.COMMANDS}
    assert expected <= set(sub.choices)


def test_help_runs_as_a_console_script():
    out = subprocess.run([sys.executable, "-m", "swerve.tools.cli", "--help"], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0
    for name in ("emulate", "scan", "synth", "sim", "run", "demo", "tune"):
        assert name in out.stdout


def _options(name: str) -> set[str]:
    parser = cli.build_parser()
    sub = next(a for a in parser._actions if a.dest == "command").choices[name]
    return {s for a in sub._actions for s in a.option_strings}


def test_every_command_that_reads_the_robot_file_calls_it_config():
    for name in ("synth", "sim", "run", "demo", "tune", "emulate"):
        opts = _options(name)
        assert "--config" in opts, name
        assert not opts & {"--robot", "--robot-config"}, name


def test_config_init_copies_the_shipped_files_and_refuses_to_overwrite(tmp_path, capsys):
    from swerve.configs import shipped

    target = tmp_path / "cfg"
    assert cli.main(["config", "init", str(target)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == [f"wrote {target / 'robot.yaml'}", f"wrote {target / 'emulator.yaml'}"]
    for name in ("robot.yaml", "emulator.yaml"):
        assert (target / name).read_bytes() == shipped(name).read_bytes()
    (target / "robot.yaml").write_text("edited\n")
    assert cli.main(["config", "init", str(target)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "already exist" in err and "robot.yaml" in err
    assert (target / "robot.yaml").read_text() == "edited\n"


def test_config_init_defaults_to_the_folder_the_commands_search(tmp_path, monkeypatch, capsys):
    from swerve.configs import locate_robot_file

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path))
    monkeypatch.delenv("SWERVE_CONFIG", raising=False)
    assert locate_robot_file(None).source == "shipped"
    assert cli.main(["config", "init"]) == 0
    choice = locate_robot_file(None)
    assert choice.source == "user" and choice.path == tmp_path / "swerve" / "robot.yaml"
    assert choice.path.is_file()


def test_sim_records_which_robot_file_it_used(tmp_path, monkeypatch, capsys):
    import json
    import shutil

    from swerve.configs import shipped

    robot = tmp_path / "my-robot.yaml"
    shutil.copy(shipped("robot.yaml"), robot)
    monkeypatch.setenv("SWERVE_CONFIG", str(robot))
    assert cli.main(["sim", "--trajectory", "line", "--json", "--quiet"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["config"] == str(robot) and out["config_source"] == "$SWERVE_CONFIG"
    other = tmp_path / "other.yaml"
    shutil.copy(robot, other)
    assert cli.main(["sim", "--trajectory", "line", "--json", "--quiet", "--config", str(other)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["config"] == str(other) and out["config_source"] == "--config"


def test_a_missing_robot_file_is_a_one_line_error(tmp_path, capsys):
    assert cli.main(["synth", "--trajectory", "line", "--config", str(tmp_path / "nope.yaml")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "nope.yaml" in err


def _modules_after(code: str) -> set[str]:
    """Top-level names of the modules a fresh interpreter holds after running ``code``."""
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys; print(' '.join(sys.modules))"],
                         capture_output=True, text=True, timeout=120, check=True)
    return set(out.stdout.split())


def test_help_imports_no_command_module():
    loaded = _modules_after("from swerve.tools import cli; cli.build_parser(())")
    assert not {m for m in loaded if m.startswith("swerve.tools.commands.")}


def test_the_cli_module_spawns_the_emulator_before_it_loads_numpy_or_the_robot_files_reader():
    """``swerve run --emulate`` starts the emulator's child right after importing ``cli``: what
    ``cli`` imports delays the child, which is the start-up's longer path."""
    loaded = _modules_after("from swerve.tools import cli")
    assert not {"numpy", "yaml", "serial", "swerve.driver.robot_config", "swerve.driver.control_table"} & loaded


#: Heavy packages that ``swerve run --emulate --lockstep`` does not use in its own process (the log
#: writer's rosbags comes later, while the emulator child starts).
NOT_ON_THE_RUN_PATH = ("scipy", "numba", "matplotlib", "rosbags", "ray", "foxglove", "websockets", "mpmath")


def test_the_run_command_loads_only_what_it_uses():
    loaded = _modules_after("from swerve.tools import cli; cli.build_parser(('run',))")
    assert "swerve.tools.commands.run" in loaded
    assert not {m for m in loaded if m.startswith("swerve.tools.commands.") and
                m not in ("swerve.tools.commands.run", "swerve.tools.commands.sim")}
    assert not {m.split(".")[0] for m in loaded} & set(NOT_ON_THE_RUN_PATH)
    # the parent launches the emulator child and describes it (its timing and body): it loads
    # neither the bus server nor the physics
    assert not {m for m in loaded if m.startswith("swerve.emulator.") and
                m not in ("swerve.emulator.process", "swerve.emulator.spawn", "swerve.emulator.channel", "swerve.emulator.timing", "swerve.emulator.clock",
                          "swerve.emulator.lockstep_socket", "swerve.emulator.body_settings",
                          "swerve.emulator.physics", "swerve.emulator.physics.params",
                          "swerve.emulator.physics.profiles")}


def test_the_chosen_command_is_the_first_word_that_is_no_option():
    assert cli.chosen_command(["-v", "run", "--trajectory", "line"]) == "run"
    assert cli.chosen_command(["--help"]) is None
    assert cli.chosen_command(["export-csv", "LOG"]) == "export-csv"


def test_the_emulating_options_are_options_of_their_commands():
    for name, option in cli.EMULATING_OPTION.items():
        assert option in _options(name)


def test_only_a_command_line_that_emulates_starts_an_emulator_child_ahead():
    assert cli.starts_emulator(["run", "--trajectory", "line", "--emulate", "--lockstep"])
    assert cli.starts_emulator(["-v", "run", "--emulate"])
    assert not cli.starts_emulator(["run", "--trajectory", "line", "--port", "/dev/ttyUSB0"])
    assert not cli.starts_emulator(["sim", "--emulate"])         # not an option of sim: no child
    assert not cli.starts_emulator([])


#: A bad option of each command whose work is a module apart (:data:`cli.WORK_MODULES`).
BAD_OPTION = {
    "emulate": ["emulate", "--time-scale", "nan"],
    "doctor": ["doctor", "--emulate", "--cycles", "0"],
    "calibrate": ["calibrate", "--emulate", "--speed", "0"],
    "campaign": ["campaign", "run", "smoke", "--out", "x", "--workers", "0"],
    "tune": ["tune", "--emulate", "--seed", "-3"],
    "plot": ["plot", "LOG"],
}


def test_every_work_module_has_a_bad_option_case():
    assert set(BAD_OPTION) == set(cli.WORK_MODULES)


@pytest.mark.parametrize("name", sorted(BAD_OPTION))
def test_a_bad_option_is_refused_before_the_work_is_imported(name):
    code = ("from swerve.tools import cli\n"
            f"try:\n    cli.main({BAD_OPTION[name]!r})\n"
            "except SystemExit as exc:\n    assert exc.code == 2, exc.code\n"
            "else:\n    raise AssertionError('no exit')")
    loaded = _modules_after(code)
    assert cli.command_module(name).__name__ in loaded
    assert cli.WORK_MODULES[name] not in loaded
    assert not {m.split(".")[0] for m in loaded} & {"scipy", "numba", "matplotlib"}


def test_every_work_module_has_the_run_of_its_command():
    for name, module in cli.WORK_MODULES.items():
        assert name in cli.COMMANDS
        assert callable(cli.work_module(name).run), module
        assert not hasattr(cli.command_module(name), "run"), name
