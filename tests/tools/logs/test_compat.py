"""The bag is a standard ROS 2 bag: independent readers open it and decode every topic."""
import numpy as np
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from swerve.tools.logs.bag import TOPICS


def test_independent_mcap_reader_sees_summary_and_standard_schemas(run_bag):
    with next(run_bag.glob("*.mcap")).open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        topics = {c.topic: c for c in summary.channels.values()}
        assert set(topics) == set(TOPICS)
        for topic, ch in topics.items():
            assert ch.message_encoding == "cdr"
            schema = summary.schemas[ch.schema_id]
            assert schema.name == TOPICS[topic] and schema.encoding == "ros2msg"
        counts = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
        assert counts["/joint_states"] == counts["/swerve/cycle"] == 500
        assert counts["/swerve/metadata"] == 1


def test_rosbags_anyreader_deserialises_every_message(run_bag, run_records):
    with AnyReader([run_bag]) as reader:
        assert {c.topic for c in reader.connections} == set(TOPICS)
        msgs = {}
        for conn, stamp, raw in reader.messages():
            msgs.setdefault(conn.topic, []).append((stamp, reader.deserialize(raw, conn.msgtype)))
    js = msgs["/joint_states"][10][1]
    r = run_records[10]
    assert list(js.name[4:]) == ["front_left_steer", "rear_left_steer", "rear_right_steer", "front_right_steer"]
    np.testing.assert_array_equal(js.position[4:], r.meas_steer_rad)
    np.testing.assert_array_equal(js.velocity[:4], r.meas_drive_radps)
    np.testing.assert_array_equal(js.effort, r.meas_current_a)
    assert js.header.stamp.sec * 10**9 + js.header.stamp.nanosec == r.stamp_ns
    traj = msgs["/trajectory"][10][1]
    np.testing.assert_array_equal(traj.points[0].positions[4:], r.cmd_steer_rad)
    np.testing.assert_array_equal(traj.points[0].velocities[:4], r.cmd_drive_radps)
    odom = msgs["/odom"][10][1]
    assert odom.pose.pose.position.x == r.est_pose[0]
    assert np.isclose(2 * np.arctan2(odom.pose.pose.orientation.z, odom.pose.pose.orientation.w), r.est_pose[2])
    assert len(msgs["/true_pose"]) == 500 and "/sim_pose" not in msgs


def test_bag_time_range_is_the_runs(run_bag, run_records):
    with AnyReader([run_bag]) as reader:
        assert reader.start_time == run_records[0].stamp_ns
        assert reader.end_time == run_records[-1].stamp_ns + 1  # rosbags: end is exclusive
