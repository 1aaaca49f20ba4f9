"""The bag's CDR bytes come from templates: they must equal rosbags' serialisation of the
cycle's messages byte for byte, whatever the numbers."""
import numpy as np
import pytest

from swerve.tools.logs import CycleRecord
from swerve.tools.logs.bag import TOPICS, _typestore, joint_names
from swerve.tools.logs.messages import CycleMessages, CycleSerializer
from . import synthetic


@pytest.fixture(scope="module")
def builders():
    ts = _typestore()
    msgs = CycleMessages(ts, joint_names())
    return ts, msgs, CycleSerializer(msgs)


def _odd_records():
    """Records with unknown poses, signed zeros, NaN payloads, infinities and extreme stamps."""
    yield CycleRecord(t_s=0.0, stamp_ns=0, cycle=0)
    neg_nan = -np.float64("nan")
    yield CycleRecord(t_s=-0.0, stamp_ns=2**31 * 1_000_000_000 - 1, cycle=2**40, period_s=np.inf,
                      cmd_drive_radps=[neg_nan, -0.0, 1e308, -5e-324], meas_current_a=np.arange(8.0),
                      est_pose=[np.nan, 0.0, 0.0], ref_pose=[1.0, -2.0, np.pi], true_pose=[0.0, np.inf, 0.0],
                      sim_pose=[3.0, 4.0, -7.0], flags=3)


@pytest.mark.parametrize("source", ["synthetic", "odd"])
def test_bytes_equal_rosbags_serialisation(builders, source):
    ts, msgs, cdr = builders
    recs = synthetic.records(50, seed=3) if source == "synthetic" else list(_odd_records())
    for rec in recs:
        fast = cdr.serialize(rec)
        slow = msgs.messages(rec)
        assert [t for t, _ in fast] == [t for t, _ in slow]
        for (topic, data), (_, msg) in zip(fast, slow):
            assert cdr.typename(topic) == TOPICS[topic] == msg.__msgtype__
            assert bytes(data) == bytes(ts.serialize_cdr(msg, msg.__msgtype__)), topic


def test_wrong_count_of_numbers_is_refused(builders):
    _, _, cdr = builders
    with pytest.raises(ValueError, match="numbers, expected 7"):
        cdr._templates["/odom"].fill(0, 0, [0.0] * 6)
