"""The compiled span decoder of Sync/Bulk Read replies reads exactly what Register.decode reads."""
import random

import pytest

from swerve.driver.span_codec import span_decoder as _span_decoder
from swerve.driver.control_table import models


@pytest.mark.parametrize("model", sorted(models()), ids=str)
def test_every_span_decodes_as_register_decode(model):
    table = models()[model]
    rng = random.Random(7)
    top = max(r.address + r.size for r in table)
    spans = [(a, n) for a in range(top) for n in (1, 2, 4, 10, 30)] + [(0, top)]
    for address, length in spans:
        data = rng.randbytes(length)
        expect = {r.name: r.decode(data[r.address - address:r.address - address + r.size])
                  for r in table.within(address, length)}
        assert _span_decoder(table, address, length)(data) == expect, (address, length)


def test_extreme_values_keep_their_sign():
    table = models()["xh430-w210"]
    decode = _span_decoder(table, 126, 10)       # present current (2), velocity (4), position (4)
    got = decode(b"\x00\x80" + b"\xff\xff\xff\xff" + b"\xff\xff\xff\x7f")
    assert got == {"present_current": -32768, "present_velocity": -1, "present_position": 2**31 - 1}
