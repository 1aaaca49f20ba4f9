"""The two errors below every layer: :class:`SwerveError` and :class:`ConfigError`.

They live beside the shipped configs so that the driver, the emulator and the controller can all
raise them without importing each other. The whole hierarchy is described in
:mod:`swerve.driver.errors`, which re-exports both.
"""
from __future__ import annotations


class SwerveError(Exception):
    """Base of every error the project raises on purpose."""


class ConfigError(SwerveError, ValueError):
    """A configuration, data or trajectory file (or argument) is malformed."""
