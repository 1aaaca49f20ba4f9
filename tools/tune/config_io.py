"""Write tuned gains into ``configs/robot.yaml`` without disturbing the rest of the file.

Only the ``gains: {...}`` line of the ``drive:`` or ``steering:`` block is rewritten (its comment
kept); the result is re-validated with :func:`driver.robot_config.parse_robot_config` before the
file is replaced, so a failure leaves the file untouched.
"""
from __future__ import annotations

import re
from pathlib import Path

import yaml

from swerve.configs.atomic import write_text
from swerve.configs.loader import parse_yaml_text
from swerve.driver.errors import ConfigError
from swerve.driver.robot_config import parse_robot_config

_GAINS = re.compile(r"^(?P<indent>[ \t]+)gains:[ \t]*\{(?P<body>[^}]*)\}(?P<tail>.*)$")


def _block(lines: list[str], group: str) -> tuple[int, int]:
    """Line range ``[start, end)`` of the top-level ``group:`` block."""
    start = next((k for k, ln in enumerate(lines) if re.match(rf"^{group}:\s*(#.*)?$", ln)), None)
    if start is None:
        raise ConfigError(f"no top-level '{group}:' block")
    end = next((k for k in range(start + 1, len(lines)) if re.match(r"^[^\s#]", lines[k])), len(lines))
    return start, end


def update_gains_text(text: str, group: str, gains: dict[str, int], where: str = "robot config") -> str:
    """Return ``text`` with ``group.gains`` updated by ``gains`` (other gains kept).

    Raises
    ------
    ConfigError
        If the block or a one-line ``gains: {...}`` mapping is missing, or the result is invalid.
    """
    lines = text.splitlines(keepends=True)
    start, end = _block(lines, group)
    for k in range(start + 1, end):
        m = _GAINS.match(lines[k].rstrip("\n"))
        if m:
            old = yaml.safe_load("{" + m["body"] + "}") or {}
            merged = {**old, **{str(n): int(v) for n, v in gains.items()}}
            body = ", ".join(f"{n}: {v}" for n, v in merged.items())
            nl = "\n" if lines[k].endswith("\n") else ""
            lines[k] = f"{m['indent']}gains: {{{body}}}{m['tail']}{nl}"
            break
    else:
        raise ConfigError(f"{where}: no one-line 'gains: {{...}}' mapping under '{group}:' to update")
    new = "".join(lines)
    cfg = parse_robot_config(parse_yaml_text(new, where))
    got = dict(getattr(cfg, group).gains)
    if any(got.get(n) != int(v) for n, v in gains.items()):
        raise ConfigError(f"{where}: gains did not round-trip ({got})")
    return new


def write_gains(path: str | Path, group: str, gains: dict[str, int]) -> None:
    """Update ``group.gains`` in the robot config at ``path`` (atomic replace)."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read ({exc.strerror})") from exc
    write_text_atomic(path, update_gains_text(text, group, gains, str(path)))


def write_text_atomic(path: Path, text: str) -> None:
    """Replace the file at ``path`` by ``text`` atomically, keeping its mode (see
    :func:`swerve.configs.atomic.atomic_write`): a reader sees the old or the new file, never half."""
    write_text(path, text, mkdir=False)
