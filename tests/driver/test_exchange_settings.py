"""A bus's exchange settings: checked when built, given to the constructor, applied for a block."""
from __future__ import annotations

import math

import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from swerve.driver.bus import Bus, ExchangeSettings


@settings(deadline=None)
@given(st.integers(0, 10), st.floats(0.0, 10.0))
def test_valid_settings_keep_their_values(retries, margin_s):
    s = ExchangeSettings(retries, margin_s)
    assert (s.retries, s.timeout_margin_s) == (retries, margin_s)


@settings(deadline=None)
@given(st.one_of(st.integers(max_value=-1), st.floats(), st.booleans(), st.text(max_size=3)))
@example(-1)
@example(True)
def test_retries_must_be_a_whole_number_of_at_least_zero(retries):
    with pytest.raises(ValueError, match="retries must be a whole number >= 0"):
        ExchangeSettings(retries=retries)


@settings(deadline=None)
@given(st.one_of(st.floats(max_value=-1e-300), st.just(math.inf), st.just(math.nan)))
def test_the_margin_must_be_finite_and_not_negative(margin_s):
    with pytest.raises(ValueError, match="timeout margin must be a finite time >= 0 s"):
        ExchangeSettings(timeout_margin_s=margin_s)


def test_the_constructor_builds_them_and_a_block_applies_others():
    with Bus("loop://", 1_000_000, retries=2, timeout_margin_s=0.01) as bus:
        own = bus.exchange
        assert own == ExchangeSettings(2, 0.01) and (bus.retries, bus.timeout_margin_s) == (2, 0.01)
        with bus.exchanging(ExchangeSettings(5, 0.5)):
            assert (bus.retries, bus.timeout_margin_s) == (5, 0.5)
            assert bus.timeout_s(10) > 0.5
        assert bus.exchange is own
        with pytest.raises(RuntimeError), bus.exchanging(ExchangeSettings(0, 0.0)):
            raise RuntimeError("the block failed")
        assert bus.exchange is own                   # restored also when the block raises


def test_bad_constructor_values_are_refused():
    with pytest.raises(ValueError, match="retries"):
        Bus("loop://", 1_000_000, retries=-1)
