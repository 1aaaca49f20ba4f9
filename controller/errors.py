"""The controller's error class.

:class:`ControllerError` is a :class:`swerve.core.errors.ConfigError`, so the ``swerve`` command
prints it as one line (exit status 2) instead of a traceback.
"""
from __future__ import annotations

from swerve.core.errors import ConfigError


class ControllerError(ConfigError):
    """A trajectory, gain schedule, start state or limit cannot be used as given."""


class SingularityError(ControllerError):
    """The plain chained form was asked to work where it is singular.

    Attributes: ``t_s`` the first time at which it happens (``None`` if not known).
    """

    def __init__(self, message: str, t_s: float | None = None):
        self.t_s = t_s
        super().__init__(message)
