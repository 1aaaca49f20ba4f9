"""A reply that arrives after its deadline must never be taken as the answer to the next request.

Protocol 2.0 statuses carry no instruction echo, so the bus protects itself by time: after a
failed exchange it lets the line go quiet for ``timeout_margin_s`` before transmitting again.
(A reply later than deadline + margin cannot be told apart; the margin is chosen above the USB
latency timer for that reason.)
"""
import pytest

from swerve.driver.bus import Bus
from swerve.driver.control_table import Reg
from swerve.driver.errors import DxlTimeoutError


def test_late_reply_is_drained_not_misattributed(emu):
    with Bus(emu.port, 1_000_000, default_model="xh430-w210", return_delay_us=500,
             timeout_margin_s=0.05) as bus:
        deadline = bus.timeout_s(11 + 14)             # read request + 1-byte reply
        emu.faults.delay_s = deadline + 0.015          # misses its deadline, lands inside the margin
        with pytest.raises(DxlTimeoutError):
            bus.read(1, Reg.RETURN_DELAY_TIME)         # 250
        emu.faults.delay_s = 0.0
        assert bus.read(1, Reg.OPERATING_MODE) == 3    # also 1 byte: only timing tells them apart
        assert bus.drained_bytes > 0                   # the late 250 was seen and discarded



def test_replies_to_a_failed_try_do_not_answer_the_next_request(emu):
    """One late reply makes the first try fail; the retry is answered; a straggler of that
    exchange then arrives: the next request must not take it as its answer."""
    faults = emu.faults
    with Bus(emu.port, 1_000_000, default_model="xh430-w210", return_delay_us=500,
             timeout_margin_s=0.005, retries=1) as bus:
        late = [bus.timeout_s(11 + 14) + 0.008]      # past the deadline and the 5 ms quiet wait

        class OneLateReply(type(faults)):
            @property
            def delay_s(self):
                return late.pop() if late else 0.0

            @delay_s.setter
            def delay_s(self, value):
                pass

        faults.__class__ = OneLateReply
        try:
            assert bus.read(1, Reg.RETURN_DELAY_TIME) == 250   # needed the retry
            assert bus.read(1, Reg.OPERATING_MODE) == 3         # not the straggling 250
        finally:
            faults.__class__ = OneLateReply.__mro__[1]
