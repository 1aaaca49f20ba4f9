"""Live view over the Foxglove WebSocket protocol: a client sees the run's channels (and only
channels that carry data), receives messages it can decode, with no NaN in /joint_states and
/odom and times on today's date; a full queue drops records instead of blocking the caller.
Every server here binds to 127.0.0.1."""
from __future__ import annotations

import asyncio
import json
import struct
import time

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from swerve.driver.errors import ConfigError
from swerve.tools import live
from swerve.tools.logs.bag import TOPICS
from swerve.tools.logs.record import CYCLE_FIELDS, CycleRecord

websockets = pytest.importorskip("websockets")
websockets_exceptions = pytest.importorskip("websockets.exceptions")     # a submodule, not loaded by the package
#: foxglove-sdk >= 0.2x speaks "foxglove.sdk.v1" (the successor of "foxglove.websocket.v1", same
#: operations); the client offers both, as the Foxglove app does.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


#: Heading of the synthetic odometry (the body drives straight along it at 1 m/s).
HEADING = 0.5
PERIOD_NS = 16_000_000


def _record(k: int) -> CycleRecord:
    """Cycle ``k`` of a lockstep-like run: robot time from 0 in 16 ms steps (stamps near 1970)."""
    t = 0.016 * k
    return CycleRecord(t_s=t, stamp_ns=k * PERIOD_NS, cycle=k, period_s=0.016,
                       cmd_drive_radps=np.full(4, 2.0), cmd_steer_rad=np.full(4, 0.1),
                       meas_drive_radps=np.full(4, 1.9), meas_steer_rad=np.full(4, 0.09 + 0.01 * k),
                       meas_current_a=np.zeros(8),
                       est_pose=np.array([t * math.cos(HEADING), t * math.sin(HEADING), HEADING]),
                       ref_pose=np.array([t * math.cos(HEADING) + 0.003, t * math.sin(HEADING) + 0.004, HEADING]),
                       true_pose=np.array([t, 0.001, 0.0]))


async def _client(url: str, feed, want_topics: set[str], timeout_s: float = 20.0, times: dict | None = None):
    """Connect, check the advertised channels, subscribe to all, collect messages by topic (and
    their log times, ns, into ``times``)."""
    times = {} if times is None else times
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        channels: dict[int, dict] = {}
        got: dict[str, list[bytes]] = {}
        subs: dict[int, str] = {}
        times.clear()
        end = time.monotonic() + timeout_s
        while time.monotonic() < end and not (want_topics <= got.keys()):
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=0.2)
            except asyncio.TimeoutError:
                feed()
                continue
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "advertise":
                    new = []
                    for ch in msg["channels"]:
                        channels[ch["id"]] = ch
                        sub_id = len(subs) + 1
                        subs[sub_id] = ch["topic"]
                        new.append({"id": sub_id, "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": new}))
            elif frame[0] == 0x01:                       # Message Data
                sub_id, ns = struct.unpack_from("<IQ", frame, 1)
                got.setdefault(subs[sub_id], []).append(bytes(frame[13:]))
                times.setdefault(subs[sub_id], []).append(ns)
            feed()
        return channels, got


@pytest.mark.slow
def test_client_sees_the_run_topics_with_clean_contents_and_times():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    times: dict[str, list[int]] = {}
    before_ns = time.time_ns()
    want = {*live.RUN_TOPICS, "/true_pose"}
    with live.LivePublisher("127.0.0.1", 0, topics=sorted(want)) as pub:
        k = [0]

        def feed():
            for _ in range(3):
                pub.publish(_record(k[0]))
                k[0] += 1

        channels, got = asyncio.run(_client(pub.url, feed, want, times=times))
    after_ns = time.time_ns()
    by_topic = {c["topic"]: c for c in channels.values()}
    # only channels that carry data: no /swerve/metadata, no /sim_pose
    assert set(by_topic) == want and got.keys() == want
    for topic in want - {live.LIVE_TOPIC}:
        assert by_topic[topic]["schemaName"] == TOPICS[topic]
        assert by_topic[topic]["encoding"] == "cdr" and by_topic[topic]["schemaEncoding"] == "ros2msg"
    # times: today's date, 16 ms apart as the robot-time stamps are
    span_ns = k[0] * PERIOD_NS
    for topic, ns in times.items():
        assert all(before_ns <= t <= after_ns + span_ns for t in ns), topic
        assert all((b - a) % PERIOD_NS == 0 and b > a for a, b in zip(ns, ns[1:])), topic
    js = [ts.deserialize_cdr(m, "sensor_msgs/msg/JointState") for m in got["/joint_states"]]
    full = [m for m in js if len(m.position) == len(m.velocity) == len(m.effort) == 8]
    assert len(full) >= len(js) - 1 and full                    # only the first may lack velocity
    for a, b in zip(full, full[1:]):
        dt = (b.header.stamp.sec - a.header.stamp.sec) + (b.header.stamp.nanosec - a.header.stamp.nanosec) * 1e-9
        assert np.allclose(b.position[:4] - a.position[:4], 1.9 * dt)    # drive angle: integrated speed
    last = full[-1]
    assert last.name[0] == "front_left_drive" and last.header.stamp.sec * 10 ** 9 + last.header.stamp.nanosec in times["/joint_states"]
    assert np.all(np.isfinite(last.position)) and np.all(np.isfinite(last.velocity))
    assert np.allclose(last.velocity, [1.9] * 4 + [0.01 / 0.016] * 4)
    odom = ts.deserialize_cdr(got["/odom"][-1], "nav_msgs/msg/Odometry")
    tw = odom.twist.twist
    assert (tw.linear.x, tw.linear.y, tw.angular.z) == pytest.approx((1.0, 0.0, 0.0), abs=1e-9)
    assert not any(math.isnan(v) for v in (tw.linear.z, tw.angular.x, tw.angular.y, *odom.twist.covariance))
    cyc = ts.deserialize_cdr(got["/swerve/cycle"][-1], "std_msgs/msg/Float64MultiArray")
    assert len(cyc.data) == sum(n for _, n in CYCLE_FIELDS)
    doc = json.loads(got[live.LIVE_TOPIC][-1])
    assert doc["period_ms"] == pytest.approx(16.0)
    assert doc["error_est_m"] == pytest.approx(0.005)


_finite = st.floats(-50.0, 50.0, allow_nan=False)
_maybe = st.one_of(_finite, st.just(float("nan")))


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 50_000_000), st.lists(_maybe, min_size=4, max_size=4),
                          st.lists(_maybe, min_size=4, max_size=4), st.lists(_maybe, min_size=8, max_size=8),
                          st.lists(_maybe, min_size=3, max_size=3)), min_size=1, max_size=30))
def test_joints_and_twist_never_send_nan_and_arrays_are_whole_or_empty(cycles):
    fill, stamp = live.JointsAndTwist(), 0
    for k, (step_ns, drive, steer, current, pose) in enumerate(cycles):
        stamp += step_ns
        fill.update(CycleRecord(t_s=0.0, stamp_ns=stamp, cycle=k, meas_drive_radps=np.array(drive),
                                meas_steer_rad=np.array(steer), meas_current_a=np.array(current),
                                est_pose=np.array(pose)))
        for arr in (fill.position, fill.velocity, fill.effort):
            assert len(arr) in (0, 8) and all(math.isfinite(v) for v in arr)
        assert fill.twist is None or all(math.isfinite(v) for v in fill.twist)
        if all(map(math.isfinite, steer)):
            assert fill.position[4:] == steer


def test_refused_client_is_logged_with_the_accepted_subprotocol(caplog):
    async def old_client(url):
        with pytest.raises(websockets_exceptions.InvalidStatus, match="400"):
            async with websockets.connect(url, subprotocols=["foxglove.websocket.v1"]):
                pass

    with caplog.at_level("WARNING", logger="swerve.tools.live"), live.LivePublisher("127.0.0.1", 0) as pub:
        asyncio.run(old_client(pub.url))
        deadline = time.monotonic() + 10.0
        while pub.refused_clients == 0 and time.monotonic() < deadline:
            time.sleep(0.02)                  # the SDK logs from its own thread
    assert pub.refused_clients == 1
    assert any(live.ACCEPTED_SUBPROTOCOL in r.getMessage() for r in caplog.records)


def test_publish_never_blocks_and_counts_drops():
    pub = live.LivePublisher("127.0.0.1", 0, queue_size=4)     # not started: nobody drains the queue
    for k in range(10):
        pub.publish(_record(k))
    assert pub.dropped == 6


def test_live_address_parsing():
    assert live.parse_live("8765") == ("127.0.0.1", 8765)
    assert live.parse_live("0.0.0.0:9000") == ("0.0.0.0", 9000)
    with pytest.raises(ConfigError):
        live.parse_live("host:notaport")


def test_shipped_layout_names_topics_the_publisher_serves():
    text = live.layout_path().read_text()
    doc = json.loads(text)
    assert "configById" in doc
    topics = set(TOPICS) | {live.LIVE_TOPIC}
    used = {t for t in topics if f'"{t}' in text}
    assert {"/joint_states", "/reference", "/odom", live.LIVE_TOPIC} <= used


@pytest.mark.slow
def test_emulate_physics_streams_the_true_pose(tmp_path):
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "swerve.tools.cli", "emulate", "--physics", "--live", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        url = None
        for _ in range(20):
            line = proc.stderr.readline()
            if line.startswith("LIVE "):
                url = line.split()[1]
                break
        assert url and url.startswith("ws://127.0.0.1:")
        channels, got = asyncio.run(_client(url, lambda: None, {"/true_pose"}))
        assert {c["topic"] for c in channels.values()} == {"/true_pose"}      # nothing silent advertised
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    assert proc.returncode == 0
    from rosbags.typesys import Stores, get_typestore

    msg = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(got["/true_pose"][-1], "geometry_msgs/msg/PoseStamped")
    assert msg.pose.position.x == pytest.approx(0.0, abs=1e-6) and msg.pose.orientation.w == pytest.approx(1.0)


def test_unknown_live_topics_are_refused():
    with pytest.raises(ConfigError, match="unknown topics /nope"):
        live.LivePublisher("127.0.0.1", 0, topics=("/joint_states", "/nope"))
