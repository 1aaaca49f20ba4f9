"""The ``swerve`` command: one sub-module per subcommand in :mod:`tools.commands`.

Each module ``tools/commands/<name>.py`` defines ``NAME``, ``HELP``, ``add_arguments(parser)``
and ``run(args) -> int``. Heavy imports happen inside ``run`` so ``swerve --help`` stays fast.
Errors the user can cause (:class:`swerve.configs.errors.SwerveError`) are printed as one line and
exit with status 2; Ctrl-C exits with 130.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from swerve.configs.errors import SwerveError

#: Subcommands in the order ``swerve --help`` lists them (module names in tools.commands).
COMMANDS = ("emulate", "scan", "doctor", "calibrate", "synth", "sim", "run", "demo", "tune", "plot", "export_csv",
            "config")


def add_config_option(parser: argparse.ArgumentParser) -> None:
    """``--config FILE``: the robot file, the same option in every command that reads one."""
    parser.add_argument("--config", default=None, metavar="FILE",
                        help="robot file (default: $SWERVE_CONFIG, else ~/.config/swerve/robot.yaml, "
                             "else the shipped robot.yaml)")


def _load(name: str):
    """Import ``tools.commands.<name>``; ``None`` only if that module itself does not exist.

    (tests/test_cli.py asserts that every name in COMMANDS is present, so nothing is hidden.)
    """
    full = f"swerve.tools.commands.{name}"
    try:
        return importlib.import_module(full)
    except ModuleNotFoundError as exc:
        if exc.name == full:
            return None
        raise


def build_parser() -> argparse.ArgumentParser:
    """Return the top-level parser with every subcommand registered."""
    parser = argparse.ArgumentParser(
        prog="swerve",
        description="Four-wheel steered robot: Dynamixel driver, servo emulator, LQ tracking.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        mod = _load(name)
        if mod is None:
            continue
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``swerve`` console script."""
    args = build_parser().parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except SwerveError as exc:
        print(f"swerve {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"swerve {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
