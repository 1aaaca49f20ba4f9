"""argparse ``type=`` converters: every number the ``swerve`` command takes is checked where it enters.

Each factory returns a converter that raises :class:`argparse.ArgumentTypeError` with a message
like ``must be a finite number > 0, got 'nan'``; argparse adds the option's name, and the
``swerve`` parser prints it as one line.
"""
from __future__ import annotations

import argparse
import math


def _bounds_text(lo, hi, lo_open: bool, hi_open: bool) -> str:
    parts = []
    if lo is not None:
        parts.append(f"{'>' if lo_open else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"{'<' if hi_open else '<='} {hi:g}")
    return " and ".join(parts)


def finite_float(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
                 hi_open: bool = False, allow_inf: bool = False):
    """Converter to a float that is finite (``inf`` too with ``allow_inf``) and in ``[lo, hi]``.

    ``lo_open`` / ``hi_open`` exclude the bound itself.
    """
    what = "a number" if allow_inf else "a finite number"
    bounds = _bounds_text(lo, hi, lo_open, hi_open)
    want = f"{what} {bounds}".strip()

    def convert(text: str) -> float:
        try:
            v = float(text)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}") from None
        bad = math.isnan(v) or (math.isinf(v) and not allow_inf)
        if lo is not None and (v < lo or (lo_open and v == lo)):
            bad = True
        if hi is not None and (v > hi or (hi_open and v == hi)):
            bad = True
        if bad:
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}")
        return v

    convert.__name__ = "number"            # argparse names the type in its messages
    return convert


def int_range(lo: int | None = None, hi: int | None = None):
    """Converter to an integer in ``[lo, hi]`` (either bound may be ``None``)."""
    want = f"an integer {_bounds_text(lo, hi, False, False)}".strip()

    def convert(text: str) -> int:
        try:
            v = int(text, 10)
        except (TypeError, ValueError):
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}") from None
        if (lo is not None and v < lo) or (hi is not None and v > hi):
            raise argparse.ArgumentTypeError(f"must be {want}, got {text!r}")
        return v

    convert.__name__ = "integer"
    return convert


#: A finite number > 0 (time scales, rates, step sizes).
positive_float = finite_float(0.0, lo_open=True)
#: A finite number >= 0 (margins, tolerances).
nonnegative_float = finite_float(0.0)
#: A servo ID, 0..252 (Protocol 2.0: 253 is reserved, 254 broadcast).
servo_id = int_range(0, 252)
#: A baud rate in bps, positive and at most the X series' fastest (4.5 Mbps).
baud_rate = int_range(1, 4_500_000)


__all__ = ["baud_rate", "finite_float", "int_range", "nonnegative_float", "positive_float", "servo_id"]
