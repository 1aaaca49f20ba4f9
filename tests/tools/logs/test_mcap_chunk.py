"""The run log's chunks are packed by ``ChunkWriter``: the file must be the one rosbags' own
``Writer.write`` and ``McapWriter.close_chunk`` make of the same messages, byte for byte, for any
records, stamps and flush interval; and ``metadata.yaml`` (counts, time range) must match too."""
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from rosbags.rosbag2 import StoragePlugin, Writer

from swerve.tools.logs import CycleRecord, RunLogWriter, read_log
from swerve.tools.logs.bag import TOPICS, _typestore, joint_names
from swerve.tools.logs.mcap_chunk import CHUNK_LIMIT, ChunkWriter
from swerve.tools.logs.messages import CycleMessages, CycleSerializer
from . import synthetic

TS = _typestore()
CDR = CycleSerializer(CycleMessages(TS, joint_names()))


def _rosbags_log(path: Path, metadata_json: str, records, flush_every: int) -> None:
    """The log as rosbags writes it message by message, closing its chunk every ``flush_every`` cycles."""
    bag = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
    bag.open()
    conns = {topic: bag.add_connection(topic, msgtype, typestore=TS) for topic, msgtype in TOPICS.items()}
    bag.storage.close_chunk()
    bag.set_custom_data("swerve_metadata", metadata_json)
    for k, rec in enumerate(records):
        ns = int(rec.stamp_ns)
        if k == 0:
            meta = TS.types["std_msgs/msg/String"](data=metadata_json)
            bag.write(conns["/swerve/metadata"], ns, TS.serialize_cdr(meta, meta.__msgtype__))
        for topic, data in CDR.serialize(rec):
            bag.write(conns[topic], ns, data)
        if (k + 1) % flush_every == 0:
            bag.storage.close_chunk()
    bag.close()


def _assert_same_files(ours: Path, theirs: Path) -> None:
    """Two bags of the same name (the MCAP's rosbag2 metadata record names the file)."""
    assert (ours / "metadata.yaml").read_text() == (theirs / "metadata.yaml").read_text()
    assert (ours / "log.mcap").read_bytes() == (theirs / "log.mcap").read_bytes()


def _check(records, flush_every: int) -> None:
    with tempfile.TemporaryDirectory() as d:
        ours, theirs = Path(d, "ours", "log"), Path(d, "theirs", "log")
        with RunLogWriter(ours, synthetic.META, flush_every=flush_every) as w:
            for rec in records:
                w.write(rec)
            metadata_json = json.dumps(w.metadata, allow_nan=True, default=str)
        _rosbags_log(theirs, metadata_json, records, flush_every)
        _assert_same_files(ours, theirs)


@pytest.mark.parametrize("flush_every", [1, 3, 64])
def test_log_is_rosbags_bytes(flush_every):
    _check(synthetic.records(200, seed=5), flush_every)


finite = st.floats(-1e6, 1e6, allow_nan=False)
pose = st.one_of(st.tuples(finite, finite, finite), st.just((np.nan, 0.0, 0.0)))


@st.composite
def runs(draw):
    n = draw(st.integers(1, 12))
    stamps = draw(st.lists(st.integers(0, 2**31 * 10**9 - 1), min_size=n, max_size=n))
    return [CycleRecord(t_s=0.016 * k, stamp_ns=stamps[k], cycle=k, period_s=draw(finite),
                        cmd_drive_radps=np.full(4, draw(finite)), est_pose=draw(pose), ref_pose=draw(pose),
                        true_pose=draw(pose), sim_pose=draw(pose), flags=draw(st.integers(0, 3)))
            for k in range(n)]


@settings(max_examples=40, deadline=None)
@given(runs(), st.integers(1, 5))
@example([CycleRecord(t_s=0.0, stamp_ns=5, cycle=0), CycleRecord(t_s=0.016, stamp_ns=3, cycle=1)], 2)
def test_any_records_stamps_and_flush_interval(records, flush_every):
    """Unknown poses drop their topics, so chunks differ in their channels; stamps may go back."""
    _check(records, flush_every)


def test_chunk_over_the_limit_is_closed_where_rosbags_closes_it(tmp_path):
    """rosbags closes its pending chunk once the records pass 1 MiB; so does the chunk writer."""
    big = bytes(range(256)) * 1000
    files = []
    for name, ours in (("ours", True), ("theirs", False)):
        bag = Writer(tmp_path / name / "log", version=9, storage_plugin=StoragePlugin.MCAP)
        bag.open()
        conn = bag.add_connection("/big", "std_msgs/msg/String", typestore=TS)
        bag.storage.close_chunk()
        chunks = ChunkWriter(bag) if ours else None
        for k in range(2 * CHUNK_LIMIT // len(big) + 3):
            if ours:
                chunks.add(conn.id, 1000 + k, big)
            else:
                bag.write(conn, 1000 + k, big)
        assert len(bag.storage.chunks) == 3        # the schema's chunk, then two full ones
        if ours:
            chunks.flush()                         # the rest, as rosbags' close does
        bag.close()
        files.append(tmp_path / name / "log")
    _assert_same_files(*files)


def test_an_open_rosbags_chunk_is_refused(tmp_path):
    bag = Writer(tmp_path / "b", version=9, storage_plugin=StoragePlugin.MCAP)
    bag.open()
    bag.add_connection("/x", "std_msgs/msg/String", typestore=TS)
    with pytest.raises(RuntimeError, match="pending chunk must be closed"):
        ChunkWriter(bag)
    bag.close()


def test_killed_mid_chunk_reads_back_the_flushed_cycles(tmp_path):
    """What reached the file before a crash is whole chunks: the reader recovers them all."""
    recs = synthetic.records(10)
    w = RunLogWriter(tmp_path / "log", synthetic.META, flush_every=4)
    w.open()
    for r in recs:
        w.write(r)
    log = read_log(tmp_path / "log")              # never closed: 8 cycles flushed, 2 pending
    assert not log.clean and len(log) == 8
    np.testing.assert_array_equal(log.t_s, [r.t_s for r in recs[:8]])
    w.close()
    assert len(read_log(tmp_path / "log")) == 10
