"""Parsers of the compact option texts: ID lists (``1-8``, ``1,3,5``) and ``key=value`` lists.

They live below every layer so that the ``swerve`` command, the emulator and the driver can
share them. Every malformed text raises :class:`~swerve.core.errors.ConfigError` naming the
option, e.g. ``--ids '5-x': bad ID range, expected e.g. 1-8 or 1,3,5``.
"""
from __future__ import annotations

from swerve.core.errors import ConfigError


def parse_id_range(text: str, option: str = "--ids", *, max_id: int) -> range:
    """``"3-6"`` -> ``range(3, 7)``; ``"5"`` -> ``range(5, 6)``; IDs must lie in ``0..max_id``."""
    lo, sep, hi = text.strip().partition("-")
    try:
        lo_i = int(lo)
        hi_i = int(hi) if sep else lo_i
    except ValueError:
        raise ConfigError(f"{option} {text!r}: bad ID range, expected e.g. 1-8 or 1,3,5") from None
    if lo_i > hi_i:
        raise ConfigError(f"{option} {text!r}: ID range is empty (first ID above last)")
    if not 0 <= lo_i <= hi_i <= max_id:
        raise ConfigError(f"{option} {text!r}: ID range must lie within 0-{max_id}")
    return range(lo_i, hi_i + 1)


def parse_ids(text: str, option: str = "--ids", *, max_id: int) -> list[int]:
    """``"1-4,7"`` -> ``[1, 2, 3, 4, 7]`` (order kept); a repeated ID is an error."""
    ids: list[int] = []
    for part in text.split(","):
        if part.strip():
            ids.extend(parse_id_range(part, option, max_id=max_id))
    if not ids:
        raise ConfigError(f"{option} {text!r} names no servo")
    dup = sorted({i for i in ids if ids.count(i) > 1})
    if dup:
        raise ConfigError(f"{option} {text!r}: ID {', '.join(map(str, dup))} given twice")
    return ids


def parse_key_values(text: str, option: str, keys: tuple[str, ...] | None = None) -> list[tuple[str, str]]:
    """``"drop=0.1, seed=3"`` -> ``[("drop", "0.1"), ("seed", "3")]``.

    Keys are stripped and lower-cased, values stripped; order and repeats are kept. With
    ``keys`` given, any other key is an error that lists them.
    """
    pairs: list[tuple[str, str]] = []
    for item in text.split(","):
        if not item.strip():
            continue
        key, sep, value = item.partition("=")
        key = key.strip().lower()
        if not sep or not key:
            raise ConfigError(f"{option} item {item.strip()!r} is not key=value")
        if keys is not None and key not in keys:
            raise ConfigError(f"{option}: unknown key {key!r} (keys: {', '.join(keys)})")
        pairs.append((key, value.strip()))
    return pairs


__all__ = ["parse_id_range", "parse_ids", "parse_key_values"]
