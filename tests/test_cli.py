"""The swerve command: every planned subcommand is registered and user errors are one line."""
import subprocess
import sys

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
