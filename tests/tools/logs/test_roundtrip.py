"""A synthetic run written as a bag reads back losslessly."""
import numpy as np
import pytest

from swerve.tools.logs import CYCLE_FIELDS, CycleRecord, RunLogWriter, read_log
from swerve.tools.logs.record import CYCLE_SIZE, pack, unpack
from . import synthetic


def test_every_field_reads_back_exactly(run_bag, run_records):
    log = read_log(run_bag)
    assert log.clean and log.recovery_note == ""
    assert len(log) == len(run_records)
    for name, _ in CYCLE_FIELDS + (("stamp_ns", 1),):
        expected = np.array([np.asarray(getattr(r, name)) for r in run_records])
        np.testing.assert_array_equal(log.fields[name], expected, err_msg=name)
    assert log.stamp_ns.dtype == np.int64 and log.cycle.dtype == np.int64


def test_record_roundtrip_and_metadata(run_bag, run_records):
    log = read_log(run_bag)
    r = log.record(123)
    for name, _ in CYCLE_FIELDS:
        np.testing.assert_array_equal(getattr(r, name), getattr(run_records[123], name))
    assert r.stamp_ns == run_records[123].stamp_ns
    for k, v in synthetic.META.items():
        assert log.metadata[k] == v
    assert log.metadata["joint_names"][0] == "front_left_drive"


def test_reads_the_mcap_file_directly(run_bag):
    assert len(read_log(next(run_bag.glob("*.mcap")))) == 500


def test_unknown_values_stay_nan(tmp_path):
    recs = synthetic.records(5, true_pose=False)
    synthetic.write(tmp_path / "hw", recs)
    log = read_log(tmp_path / "hw")
    assert np.isnan(log.true_pose).all() and np.isnan(log.sim_pose).all()
    bare = CycleRecord(t_s=0.0, stamp_ns=1, cycle=0)
    assert np.isnan(pack(bare)[1:]).sum() == CYCLE_SIZE - 3  # all but t_s, cycle, flags


def test_pack_unpack_inverse():
    r = synthetic.records(1)[0]
    back = unpack(pack(r)[None, :])
    for name, _ in CYCLE_FIELDS:
        np.testing.assert_array_equal(back[name][0], getattr(r, name))


def test_wrong_shape_is_refused():
    with pytest.raises(ValueError, match=r"cmd_steer_rad must have shape \(4,\)"):
        CycleRecord(t_s=0.0, stamp_ns=0, cycle=0, cmd_steer_rad=[0.1, 0.2])


def test_existing_path_is_not_overwritten(run_bag):
    from swerve.driver.errors import ConfigError

    with pytest.raises(ConfigError, match="exists already"):
        RunLogWriter(run_bag, {})
