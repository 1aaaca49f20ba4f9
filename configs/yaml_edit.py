"""Edit one-line values of a YAML file in place, keeping every other byte.

Config files carry comments and aligned columns that a YAML dump would lose, so a tool that
changes a few values (calibration, tuned gains) rewrites only the lines that hold them::

    text = set_value(text, "geometry", "wheel_radius_m", "0.0331", where="robot.yaml")
    gains = get_value(text, "drive", "gains")          # '{velocity_p_gain: 250, ...}'

A value is found under a top-level ``section:`` block as an indented ``key: value`` line whose
value is a plain scalar, a flow list ``[...]`` or a flow mapping ``{...}`` on that one line. A
comment after it keeps its column where the new value leaves room. The caller re-validates the
result with the file's loader; this module only moves text.
"""
from __future__ import annotations

import re

from swerve.core.errors import ConfigError

_VALUE_LINE = (r"^(?P<head>[ \t]+{key}:[ \t]*)(?P<value>\{{[^}}#]*\}}|\[[^\]#]*\]|[^\s#]+)"
               r"(?P<gap>[ \t]*)(?P<tail>#.*)?$")


def block(lines: list[str], section: str, where: str = "config") -> tuple[int, int]:
    """Line range ``[start, end)`` of the top-level ``section:`` block of ``lines``."""
    head = re.compile(rf"^{re.escape(section)}:[ \t]*(#.*)?$")
    start = next((k for k, ln in enumerate(lines) if head.match(ln.rstrip("\r\n"))), None)
    if start is None:
        raise ConfigError(f"{where}: no top-level '{section}:' block", file=where, key=section)
    end = next((k for k in range(start + 1, len(lines)) if re.match(r"^[^\s#]", lines[k])), len(lines))
    return start, end


def _find(lines: list[str], section: str, key: str, where: str) -> tuple[int, re.Match]:
    start, end = block(lines, section, where)
    pattern = re.compile(_VALUE_LINE.format(key=re.escape(key)))
    for k in range(start + 1, end):
        m = pattern.match(lines[k].rstrip("\r\n"))
        if m:
            return k, m
    raise ConfigError(f"{where}: no one-line '{key}:' under '{section}:' to update", file=where,
                      key=f"{section}.{key}")


def get_value(text: str, section: str, key: str, where: str = "config") -> str:
    """The text of ``section.key``'s one-line value (e.g. ``0.033``, ``[1, 1, -1, -1]``, ``{a: 1}``)."""
    _, m = _find(text.splitlines(keepends=True), section, key, where)
    return m["value"]


def set_value(text: str, section: str, key: str, value: str, where: str = "config") -> str:
    """``text`` with the one-line value of ``section.key`` replaced by ``value`` (YAML text).

    Raises :class:`ConfigError` naming ``where`` if the block or a one-line value is missing.
    """
    lines = text.splitlines(keepends=True)
    k, m = _find(lines, section, key, where)
    gap = m["gap"]
    if m["tail"]:
        gap = " " * max(1, len(m["value"]) + len(gap) - len(value))
    body = lines[k].rstrip("\r\n")
    lines[k] = f"{m['head']}{value}{gap}{m['tail'] or ''}{lines[k][len(body):]}"
    return "".join(lines)


__all__ = ["block", "get_value", "set_value"]
