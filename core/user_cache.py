"""The user's cache folder of swerve: results worth keeping between runs, safe to delete."""
from __future__ import annotations

import os
from pathlib import Path


def user_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/swerve`` (``~/.cache/swerve`` when the variable is unset or empty), read
    at each call (XDG Base Directory Specification, ``$XDG_CACHE_HOME``:
    https://specifications.freedesktop.org/basedir-spec/latest/)."""
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "swerve"
