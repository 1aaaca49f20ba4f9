"""The two errors below every layer: :class:`SwerveError` and :class:`ConfigError`.

They live beside the shipped configs so that the driver, the emulator and the controller can all
raise them without importing each other. The whole hierarchy is described in
:mod:`swerve.driver.errors`, which re-exports both.
"""
from __future__ import annotations


class SwerveError(Exception):
    """Base of every error the project raises on purpose."""


class ConfigError(SwerveError, ValueError):
    """A configuration, data or trajectory file (or argument) is malformed.

    Attributes (``None`` when not known): ``file`` the file's name, ``key`` the dotted key path
    (``geometry.a_m``, ``wheels[2].drive_id``), ``line`` its 1-based line. Errors raised by
    :mod:`swerve.configs.loader` read ``FILE:LINE: KEY: problem``.
    """

    def __init__(self, message: str = "", *, file: str | None = None, key: str | None = None,
                 line: int | None = None):
        super().__init__(message)
        self.file, self.key, self.line = file, key, line
