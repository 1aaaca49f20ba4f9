"""Sensor noise from a command-line spec (``--noise position=0.5,current=0.003,seed=1``)."""
from __future__ import annotations

import dataclasses
import math
from typing import Mapping

from swerve.core.options import parse_key_values
from swerve.driver.errors import ConfigError
from swerve.emulator.physics.params import SensorParams

#: Keys of the ``noise`` spec and the SensorParams fields they set.
NOISE_KEYS = {"position": "position_noise_std_pulse", "current": "current_noise_std_a",
              "voltage": "voltage_noise_std_v"}


def parse_noise(spec: str | Mapping[str, float] | None, base: SensorParams) -> tuple[SensorParams, int | None]:
    """Sensor noise from ``"position=0.5,current=0.003,voltage=0.05,seed=1"`` or a mapping.

    Keys: ``position`` (pulse), ``current`` (A), ``voltage`` (V) standard deviations, ``seed``;
    unnamed fields keep ``base`` (``configs/emulator.yaml: sensors``). Returns ``(params, seed)``.
    """
    if spec is None:
        return base, None
    if isinstance(spec, str):
        items = dict(parse_key_values(spec, "noise", (*NOISE_KEYS, "seed")))
    else:
        items = dict(spec)
    seed = None
    fields = {}
    for key, value in items.items():
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f"noise {key}={value!r}: not a number") from None
        if key == "seed":
            seed = int(number)
        elif key in NOISE_KEYS:
            if not (math.isfinite(number) and number >= 0):
                raise ConfigError(f"noise {key}={value!r}: expected a standard deviation >= 0")
            fields[NOISE_KEYS[key]] = number
        else:
            raise ConfigError(f"noise: unknown key {key!r} (keys: {', '.join(NOISE_KEYS)}, seed)")
    return dataclasses.replace(base, **fields), seed
