"""Draws of a campaign's robots: a pure function of (campaign, seed, sample).

Robot ``sample`` gets its own :class:`numpy.random.Generator` (PCG64) seeded with
``SeedSequence(seed, spawn_key=(sample,))``, and the parameters are drawn from it in file
order. Nothing depends on the engine, the worker, the order scenarios run in or how many
ran before: the same sample is the same robot everywhere.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .spec import WHEELS, Campaign, Parameter

#: Spawn-key tags of the streams of one sample: its physics values, its fault generator's seed.
_PARAMS, _FAULTS = 0, 1
#: Redraws of a truncated normal before giving up (the loader keeps >= 1 % of it inside the bounds).
NORMAL_REDRAWS_MAX = 10_000


@dataclass(frozen=True)
class Robot:
    """One drawn robot: ``values`` by parameter key (a scalar, or a tuple of :data:`WHEELS`),
    and ``fault_seed`` for the emulator's fault generator."""

    sample: int
    values: dict
    fault_seed: int

    def columns(self, params: tuple[Parameter, ...]) -> dict:
        """``{column: value}`` in the order of the results table."""
        out = {}
        for p in params:
            v = self.values[p.key]
            out.update(zip(p.columns, v if p.wheels is not None else (v,)))
        return out


def _generator(seed: int, sample: int, stream: int) -> np.random.Generator:
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(seed, spawn_key=(sample, stream))))


def _one(p: Parameter, rng: np.random.Generator):
    d = p.dist
    if d.kind == "choice":
        return d.values[int(rng.integers(len(d.values)))]
    if d.kind == "uniform":
        x = float(rng.uniform(d.low, d.high))
    else:
        for _ in range(NORMAL_REDRAWS_MAX):
            x = float(rng.normal(d.mean, d.std))
            if d.low <= x <= d.high:
                break
        else:                   # not reached for a distribution the loader accepted
            x = float(d.mean)
    return int(round(x)) if p.integer else x


def draw_robot(campaign: Campaign, sample: int) -> Robot:
    """The robot of ``sample`` (0-based) of ``campaign``."""
    rng = _generator(campaign.seed, sample, _PARAMS)
    values = {}
    for p in campaign.parameters:
        if p.wheels == "each":
            values[p.key] = tuple(_one(p, rng) for _ in range(WHEELS))
        elif p.wheels == "same":
            values[p.key] = (_one(p, rng),) * WHEELS
        else:
            values[p.key] = _one(p, rng)
    fault_seed = int(_generator(campaign.seed, sample, _FAULTS).integers(2**31))
    return Robot(sample, values, fault_seed)


__all__ = ["Robot", "draw_robot"]
