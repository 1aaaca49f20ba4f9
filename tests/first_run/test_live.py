"""Live view over the Foxglove WebSocket protocol: a client sees the run log's channels and
receives messages it can decode; a full queue drops records instead of blocking the caller."""
from __future__ import annotations

import asyncio
import json
import struct
import time

import numpy as np
import pytest

from swerve.driver.errors import ConfigError
from swerve.tools import live
from swerve.tools.logs.bag import TOPICS
from swerve.tools.logs.record import CYCLE_FIELDS, CycleRecord

websockets = pytest.importorskip("websockets")
#: foxglove-sdk >= 0.2x speaks "foxglove.sdk.v1" (the successor of "foxglove.websocket.v1", same
#: operations); the client offers both, as the Foxglove app does.
SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def _record(k: int) -> CycleRecord:
    t = 0.016 * k
    return CycleRecord(t_s=t, stamp_ns=time.time_ns(), cycle=k, period_s=0.016,
                       cmd_drive_radps=np.full(4, 2.0), cmd_steer_rad=np.full(4, 0.1),
                       meas_drive_radps=np.full(4, 1.9), meas_steer_rad=np.full(4, 0.09),
                       meas_current_a=np.zeros(8), est_pose=np.array([t, 0.0, 0.0]),
                       ref_pose=np.array([t + 0.003, 0.004, 0.0]), true_pose=np.array([t, 0.001, 0.0]))


async def _client(url: str, feed, want_topics: set[str], timeout_s: float = 20.0):
    """Connect, check the advertised channels, subscribe to all, collect messages by topic."""
    async with websockets.connect(url, subprotocols=SUBPROTOCOLS) as ws:
        assert ws.subprotocol in SUBPROTOCOLS
        channels: dict[int, dict] = {}
        got: dict[str, list[bytes]] = {}
        subs: dict[int, str] = {}
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
                sub_id, _ns = struct.unpack_from("<IQ", frame, 1)
                got.setdefault(subs[sub_id], []).append(bytes(frame[13:]))
            feed()
        return channels, got


def test_client_sees_the_run_log_topics_and_decodes_them():
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    with live.LivePublisher("127.0.0.1", 0) as pub:
        k = [0]

        def feed():
            for _ in range(3):
                pub.publish(_record(k[0]))
                k[0] += 1

        want = {"/joint_states", "/trajectory", "/odom", "/reference", "/true_pose", "/swerve/cycle",
                live.LIVE_TOPIC}
        channels, got = asyncio.run(_client(pub.url, feed, want))
    by_topic = {c["topic"]: c for c in channels.values()}
    for topic, msgtype in TOPICS.items():
        assert by_topic[topic]["schemaName"] == msgtype
        assert by_topic[topic]["encoding"] == "cdr" and by_topic[topic]["schemaEncoding"] == "ros2msg"
    assert want <= got.keys(), sorted(got)
    js = ts.deserialize_cdr(got["/joint_states"][-1], "sensor_msgs/msg/JointState")
    assert js.name[0] == "front_left_drive" and js.velocity[0] == pytest.approx(1.9)
    cyc = ts.deserialize_cdr(got["/swerve/cycle"][-1], "std_msgs/msg/Float64MultiArray")
    assert len(cyc.data) == sum(n for _, n in CYCLE_FIELDS)
    doc = json.loads(got[live.LIVE_TOPIC][-1])
    assert doc["period_ms"] == pytest.approx(16.0)
    assert doc["error_est_m"] == pytest.approx(0.005)
    assert doc["error_true_m"] == pytest.approx(np.hypot(0.003, 0.003))


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
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    assert proc.returncode == 0
    from rosbags.typesys import Stores, get_typestore

    msg = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(got["/true_pose"][-1], "geometry_msgs/msg/PoseStamped")
    assert msg.pose.position.x == pytest.approx(0.0, abs=1e-6) and msg.pose.orientation.w == pytest.approx(1.0)
