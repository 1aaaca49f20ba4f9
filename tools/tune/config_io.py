"""Write tuned gains into ``configs/robot.yaml`` without disturbing the rest of the file.

Only the ``gains: {...}`` line of the ``drive:`` or ``steering:`` block is rewritten (its comment
kept, by :mod:`swerve.configs.yaml_edit`); the result is re-validated with :func:`driver.robot_config.parse_robot_config` before the
file is replaced, so a failure leaves the file untouched.
"""
from __future__ import annotations

from pathlib import Path

import yaml

from swerve.core.atomic import write_text
from swerve.configs.loader import parse_yaml_text
from swerve.configs.yaml_edit import get_value, set_value
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import parse_robot_config


def update_gains_text(text: str, group: str, gains: dict[str, int], where: str = "robot config") -> str:
    """Return ``text`` with ``group.gains`` updated by ``gains`` (other gains kept).

    Raises
    ------
    ConfigError
        If the block or a one-line ``gains: {...}`` mapping is missing, or the result is invalid.
    """
    old_text = get_value(text, group, "gains", where)
    old = yaml.safe_load(old_text) if old_text.startswith("{") else None
    if not isinstance(old, dict):
        raise ConfigError(f"{where}: no one-line 'gains: {{...}}' mapping under '{group}:' to update")
    merged = {**old, **{str(n): int(v) for n, v in gains.items()}}
    new = set_value(text, group, "gains", "{" + ", ".join(f"{n}: {v}" for n, v in merged.items()) + "}",
                    where)
    cfg = parse_robot_config(parse_yaml_text(new, where))
    got = dict(getattr(cfg, group).gains)
    if any(got.get(n) != int(v) for n, v in gains.items()):
        raise ConfigError(f"{where}: gains did not round-trip ({got})")
    return new


def write_gains(path: str | Path, group: str, gains: dict[str, int]) -> None:
    """Update ``group.gains`` in the robot config at ``path`` (atomic replace; a symlink is
    written through, keeping the mode of the file it names; a read-only file is refused)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from exc
    write_text(path, update_gains_text(text, group, gains, str(path)), mkdir=False)

