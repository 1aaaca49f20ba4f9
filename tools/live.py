"""Live view: the run log's topics, streamed over the Foxglove WebSocket protocol while a run runs.

A :class:`LivePublisher` owns a ``foxglove-sdk`` WebSocket server (its own
:class:`foxglove.Context`) and one worker thread. The control loop only calls
:meth:`LivePublisher.publish` (or :meth:`on_cycle`), which puts the cycle's record into a
bounded queue (a deque the worker polls every 20 ms, so the loop wakes no thread) and returns;
when the queue is full the record is dropped and counted, so a slow or stalled viewer never
delays a cycle. The worker serialises each record into the same ROS 2
messages (CDR, ``ros2msg`` schemas from the rosbags type store) as the run log
(:data:`swerve.tools.logs.bag.TOPICS`) and logs them on the server's channels; with no client
connected it skips the serialisation. One extra JSON topic, ``/swerve/live``, carries named
numbers for plots (tracking errors, loop period, wheel speeds, steering angles).

::

    with LivePublisher("127.0.0.1", 8765) as live:      # ws://127.0.0.1:8765
        loop = TrackingLoop(..., on_cycle=live.on_cycle)

Open it in Foxglove: "Open connection" -> Foxglove WebSocket -> ``ws://HOST:PORT``, then
"Import layout" with :func:`layout_path` (``swerve/tools/foxglove_layout.json``).
"""
from __future__ import annotations

import collections
import ipaddress
import json
import logging
import math
import threading
import time
from importlib import resources
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from swerve.driver.errors import ConfigError
from swerve.tools.logs.bag import DEFAULT_WHEELS, TOPICS, joint_names
from swerve.tools.logs.messages import CycleMessages
from swerve.tools.logs.record import CycleRecord

log = logging.getLogger(__name__)

#: Default WebSocket port of Foxglove's protocol.
DEFAULT_PORT = 8765
#: Records waiting for the worker before new ones are dropped.
QUEUE_SIZE = 64
#: How often the worker looks for new records, s (it is never woken by the loop).
POLL_S = 0.02
#: Topic with named numbers for plot panels (JSON).
LIVE_TOPIC = "/swerve/live"
LIVE_SCHEMA = {
    "type": "object",
    "properties": {
        "t_s": {"type": "number", "description": "trajectory time, s"},
        "cycle": {"type": "integer"},
        "period_ms": {"type": "number", "description": "measured loop period, ms"},
        "overrun": {"type": "boolean"},
        "error_est_m": {"type": "number", "description": "|odometry - reference| position, m"},
        "error_true_m": {"type": "number", "description": "|true pose - reference| position, m (emulator)"},
        "drive_radps": {"type": "array", "items": {"type": "number"}, "description": "measured wheel speeds"},
        "drive_cmd_radps": {"type": "array", "items": {"type": "number"}},
        "steer_rad": {"type": "array", "items": {"type": "number"}, "description": "measured steering"},
        "steer_cmd_rad": {"type": "array", "items": {"type": "number"}},
        "dropped": {"type": "integer", "description": "records the live view dropped so far"},
    },
}


def parse_live(text: str) -> tuple[str, int]:
    """``"8765"`` -> ``("127.0.0.1", 8765)``; ``"0.0.0.0:8765"`` -> ``("0.0.0.0", 8765)``."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]") if sep else "127.0.0.1"
    try:
        port_i = int(port)
    except ValueError:
        raise ConfigError(f"--live {text!r}: expected [HOST:]PORT, e.g. 8765 or 0.0.0.0:8765") from None
    if not 0 <= port_i <= 65535 or not host:
        raise ConfigError(f"--live {text!r}: expected [HOST:]PORT with a port in 0-65535")
    return host, port_i


def is_loopback(host: str) -> bool:
    """Whether ``host`` (an address or ``localhost``) is reachable from this machine only."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:          # a host name: it may resolve to any interface
        return False


def layout_path() -> Path:
    """The shipped Foxglove layout (3D path, errors, wheel speeds, steering, loop timing)."""
    return Path(str(resources.files("swerve.tools").joinpath("foxglove_layout.json")))


def _finite(v) -> float | None:
    v = float(v)
    return v if math.isfinite(v) else None


def live_numbers(rec: CycleRecord, dropped: int = 0) -> dict:
    """The ``/swerve/live`` document of one record (NaN becomes null)."""
    def dist(a, b):
        d = math.hypot(float(a[0]) - float(b[0]), float(a[1]) - float(b[1]))
        return d if math.isfinite(d) else None

    def arr(x):
        return [_finite(v) for v in np.asarray(x, dtype=float)]

    return {"t_s": _finite(rec.t_s), "cycle": int(rec.cycle),
            "period_ms": None if not math.isfinite(rec.period_s) else rec.period_s * 1e3,
            "overrun": bool(int(rec.flags) & 1),
            "error_est_m": dist(rec.est_pose, rec.ref_pose), "error_true_m": dist(rec.true_pose, rec.ref_pose),
            "drive_radps": arr(rec.meas_drive_radps), "drive_cmd_radps": arr(rec.cmd_drive_radps),
            "steer_rad": arr(rec.meas_steer_rad), "steer_cmd_rad": arr(rec.cmd_steer_rad),
            "dropped": int(dropped)}


class LivePublisher:
    """A Foxglove WebSocket server on ``host:port`` fed from a bounded queue (see module doc).

    ``port`` 0 picks a free port (:attr:`port` tells which). ``wheels``: wheel names in
    robot-file order (joint names derive from them). Counters: :attr:`published` records,
    :attr:`dropped` records (queue full), :attr:`errors` (serialisation failures, logged).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *,
                 wheels: Sequence[str] = DEFAULT_WHEELS, queue_size: int = QUEUE_SIZE,
                 name: str = "swerve"):
        self.host, self.requested_port, self.name = host, int(port), name
        self._wheels = list(wheels)
        self._items: collections.deque = collections.deque()
        self._queue_size = int(queue_size)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._server = None
        self._channels: dict = {}
        self.published = 0
        self.dropped = 0
        self.errors = 0

    # --- lifecycle ----------------------------------------------------------------------------
    def start(self) -> "LivePublisher":
        import foxglove
        from rosbags.typesys import Stores, get_typestore

        self._ts = get_typestore(Stores.ROS2_JAZZY)
        self._msgs = CycleMessages(self._ts, joint_names(self._wheels))
        self._ctx = foxglove.Context()
        try:
            self._server = foxglove.start_server(name=self.name, host=self.host, port=self.requested_port,
                                                 context=self._ctx)
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types
            raise ConfigError(f"cannot start the live view on {self.host}:{self.requested_port}: {exc}") from None
        if not is_loopback(self.host):
            log.warning("the live view %s is reachable from other machines: anyone who can reach this "
                        "host can watch the robot's state (no authentication; read-only)", self.url)
        for topic, msgtype in TOPICS.items():
            msgdef, _ = self._ts.generate_msgdef(msgtype, ros_version=2)
            self._channels[topic] = foxglove.Channel(
                topic, schema=foxglove.Schema(name=msgtype, encoding="ros2msg", data=msgdef.encode()),
                message_encoding="cdr", context=self._ctx)
        self._channels[LIVE_TOPIC] = foxglove.Channel(
            LIVE_TOPIC, schema=foxglove.Schema(name="swerve.Live", encoding="jsonschema",
                                               data=json.dumps(LIVE_SCHEMA).encode()),
            message_encoding="json", context=self._ctx)
        self._msgs.messages(CycleRecord(t_s=0.0, stamp_ns=0, cycle=0))   # build serialisers now
        self._thread = threading.Thread(target=self._work, name="swerve-live", daemon=True)
        self._thread.start()
        return self

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return self._server.port if self._server is not None else self.requested_port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def close(self) -> None:
        """Stop the worker (pending records are dropped) and the server. Idempotent."""
        if self._thread is not None:
            self._stop.set()
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._server is not None:
            self._server.stop()
            self._server = None

    def __enter__(self) -> "LivePublisher":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # --- the loop's side ----------------------------------------------------------------------
    def publish(self, rec: CycleRecord | dict) -> None:
        """Queue one record (or its fields) for the viewers; never blocks and wakes no thread
        (the worker polls), and a full queue drops the record."""
        if len(self._items) >= self._queue_size:
            self.dropped += 1
        else:
            self._items.append(rec)

    def on_cycle(self, fields: dict) -> None:
        """The loop's ``on_cycle`` callback: the fields of a :class:`CycleRecord` (the record
        is built by the worker; the caller must not change the arrays afterwards)."""
        self.publish(fields)

    def pose(self, topic: str, stamp_ns: int, pose: Sequence[float]) -> None:
        """Publish one ``PoseStamped`` (e.g. the emulator's ``/true_pose``); from any thread."""
        self.publish(_PoseItem(topic, int(stamp_ns), tuple(float(v) for v in pose)))

    # --- the worker's side --------------------------------------------------------------------
    def _has_clients(self) -> bool:
        return any(ch.has_sinks() for ch in self._channels.values())

    def _work(self) -> None:
        while not self._stop.wait(POLL_S):
            while self._items:
                self._send_one(self._items.popleft())

    def _send_one(self, item) -> None:
        if not self._has_clients():
            return
        try:
            if isinstance(item, _PoseItem):
                self._send_pose(item)
            elif isinstance(item, dict):
                self._send(CycleRecord(**item))
            else:
                self._send(item)
            self.published += 1
        except Exception:  # noqa: BLE001 - a bad record must not end the live view
            self.errors += 1
            log.exception("live view: could not publish a record")

    def _send(self, rec: CycleRecord) -> None:
        ns = int(rec.stamp_ns)
        for topic, msg in self._msgs.messages(rec):
            self._channels[topic].log(bytes(self._ts.serialize_cdr(msg, msg.__msgtype__)), log_time=ns)
        self._channels[LIVE_TOPIC].log(json.dumps(live_numbers(rec, self.dropped)).encode(), log_time=ns)

    def _send_pose(self, item: "_PoseItem") -> None:
        msg = self._msgs.pose_stamped(self._msgs.header(item.stamp_ns), item.pose)
        self._channels[item.topic].log(bytes(self._ts.serialize_cdr(msg, msg.__msgtype__)), log_time=item.stamp_ns)


class _PoseItem:
    __slots__ = ("topic", "stamp_ns", "pose")

    def __init__(self, topic: str, stamp_ns: int, pose: tuple[float, float, float]):
        self.topic, self.stamp_ns, self.pose = topic, stamp_ns, pose


class PosePump:
    """A thread that publishes ``pose()`` (e.g. an emulator's true pose) on ``/true_pose`` at
    ``rate_hz`` wall Hz, for ``swerve emulate --physics --live``."""

    def __init__(self, live: LivePublisher, pose: Callable[[], Sequence[float]], rate_hz: float = 30.0):
        self.live, self.pose, self.period_s = live, pose, 1.0 / rate_hz
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="swerve-live-pose", daemon=True)

    def start(self) -> "PosePump":
        self._thread.start()
        return self

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self.live.pose("/true_pose", time.time_ns(), self.pose())

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
