"""``swerve config init [DIR]``: copy the shipped robot and emulator files where you can edit them.

The default DIR is the user's config folder (``~/.config/swerve``, or ``$XDG_CONFIG_HOME/swerve``),
where every command finds ``robot.yaml`` when neither ``--config`` nor ``$SWERVE_CONFIG`` names
one. An existing file is never overwritten.
"""
from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from swerve.configs import shipped, user_robot_file
from swerve.core.errors import ConfigError


#: The shipped files ``config init`` copies.
FILES = ("robot.yaml", "emulator.yaml")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    init = sub.add_parser("init", help="copy the shipped robot.yaml and emulator.yaml into DIR",
                          description="Copy the shipped robot.yaml and emulator.yaml into DIR; "
                                      "refuses to overwrite an existing file.")
    init.add_argument("dir", nargs="?", default=None, metavar="DIR",
                      help="target folder (default: ~/.config/swerve, where the commands look)")


def run(args: argparse.Namespace) -> int:
    target = Path(args.dir).expanduser() if args.dir else user_robot_file().parent
    existing = [target / name for name in FILES if (target / name).exists()]
    if existing:
        raise ConfigError(f"{' and '.join(map(str, existing))} already "
                          f"exist{'s' if len(existing) == 1 else ''}; not overwriting "
                          "(move it away or choose another DIR)")
    try:
        target.mkdir(parents=True, exist_ok=True)
        for name in FILES:
            shutil.copyfile(shipped(name), target / name)
            print(f"wrote {target / name}")
    except OSError as exc:
        raise ConfigError(f"cannot write into {target}: {exc.strerror}") from None
    return 0
