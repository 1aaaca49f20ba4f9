"""The shared option-text parsers: ID lists and key=value lists."""
from __future__ import annotations

import pytest

from swerve.core.errors import ConfigError
from swerve.core.options import parse_id_range, parse_ids, parse_key_values


def test_ids_and_ranges():
    assert parse_ids("1-4,7", max_id=252) == [1, 2, 3, 4, 7]
    assert parse_ids(" 8 , 1-2 ,", max_id=252) == [8, 1, 2]
    assert parse_id_range("0-252", max_id=252) == range(0, 253)
    assert parse_id_range("5", max_id=252) == range(5, 6)


@pytest.mark.parametrize("text, match", [
    ("1-x", r"^--ids '1-x': bad ID range, expected e.g. 1-8 or 1,3,5$"),
    ("5-2", r"^--ids '5-2': ID range is empty"),
    ("0-300", r"^--ids '0-300': ID range must lie within 0-252$"),
    ("-1", r"bad ID range"),
    (",", r"^--ids ',' names no servo$"),
    ("1-3,2", r"^--ids '1-3,2': ID 2 given twice$"),
])
def test_bad_ids(text, match):
    with pytest.raises(ConfigError, match=match):
        parse_ids(text, max_id=252)


def test_key_values_keep_order_and_repeats():
    assert parse_key_values(" Drop=0.1, hwerror=1:overload,hwerror=2:overload,", "--faults") == [
        ("drop", "0.1"), ("hwerror", "1:overload"), ("hwerror", "2:overload")]
    assert parse_key_values("", "--faults") == []


@pytest.mark.parametrize("text, match", [
    ("drop", r"^--faults item 'drop' is not key=value$"),
    ("=3", r"^--faults item '=3' is not key=value$"),
    ("drop=1,speed=2", r"^--faults: unknown key 'speed' \(keys: drop, seed\)$"),
])
def test_bad_key_values(text, match):
    with pytest.raises(ConfigError, match=match):
        parse_key_values(text, "--faults", ("drop", "seed"))
