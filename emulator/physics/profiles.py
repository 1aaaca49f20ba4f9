"""Named physics profiles: ``ideal`` (the world obeys the controller's model) and ``realistic``.

``resolve_emulator_config("ideal" | "realistic" | PATH)`` gives the file to load; the CLI's
``--emulator-config`` takes either form. :func:`single_effect` builds the configs that switch one
effect of ``realistic`` on over ``ideal``, for measuring what each does alone.
"""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

from swerve.configs import shipped
from swerve.core.errors import ConfigError

from .params import PhysicsConfig

#: Profile name -> shipped file.
PROFILES = {"ideal": "emulator.yaml", "realistic": "emulator-realistic.yaml"}
#: ``--emulator-config`` help of every command that starts an emulator.
EMULATOR_CONFIG_HELP = ("emulator physics: a profile, 'ideal' (the world obeys the controller's "
                        "model) or 'realistic' (tyre slip, gearbox friction, build tolerances, supply sag, "
                        "firmware faults), or a physics .yaml file")
#: Effects of the realistic profile that can be switched on alone, and the config fields they own.
EFFECTS = {
    "contact": ("contact",),
    "friction": ("drive_friction", "steering_friction"),
    "tolerances": ("tolerances",),
    "supply": ("supply",),
    "protection": ("protection",),
}


def resolve_emulator_config(name_or_path: str | os.PathLike) -> Path:
    """The physics config file for a profile name (``ideal``, ``realistic``) or a path.

    Raises
    ------
    ConfigError
        If it is neither a profile name nor an existing file.
    """
    text = str(name_or_path)
    if text in PROFILES:
        return shipped(PROFILES[text])
    path = Path(text)
    if not path.is_file():
        raise ConfigError(f"emulator config {text!r}: no such file and not a profile "
                          f"({', '.join(PROFILES)})")
    return path


def single_effect(ideal: PhysicsConfig, realistic: PhysicsConfig, effect: str) -> PhysicsConfig:
    """``ideal`` with the fields of one ``effect`` (a key of :data:`EFFECTS`) taken from ``realistic``."""
    try:
        fields = EFFECTS[effect]
    except KeyError:
        raise ConfigError(f"unknown effect {effect!r} (one of {', '.join(EFFECTS)})") from None
    return dataclasses.replace(ideal, **{f: getattr(realistic, f) for f in fields})
