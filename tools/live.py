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

What a viewer sees differs from the log in three ways, so that plots have no gaps:

* **Time.** Message times (log time and header stamps) are on the wall clock's epoch: the
  wall time at which the first record reached the publisher plus the record's robot time
  since the first record (``stamp_ns`` differences). A lockstep run, whose stamps start at 0,
  thus shows today's date; a wall-clock run shows its own times, shifted by the constant
  delay of the first record.
* **No NaN in** ``/joint_states`` **and** ``/odom`` (:class:`JointsAndTwist`). Drive positions
  are the measured wheel speeds integrated (trapezoid, robot time) since the live view
  started; steering velocities are the measured steering angles differenced between cycles;
  the twist of ``/odom`` is the odometry estimate differenced between cycles, in
  ``base_link``. An array of ``JointState`` that cannot be filled wholly (the first cycle, a
  missed read) is sent empty, as ``sensor_msgs/JointState`` allows; ``/odom`` starts with
  the second cycle. ``/trajectory`` is the log's message unchanged.
* **Channels.** Only the ``topics`` given are advertised, all at start, and only they are
  sent: a run passes :data:`RUN_TOPICS` plus ``/true_pose`` when the emulator supplies it,
  ``swerve emulate --live`` only ``/true_pose``. ``/swerve/metadata`` and ``/sim_pose`` (the
  open-loop overlay, computed for the log) stay in the log only. (A channel created while a
  client is connected was seen to refuse that client's subscription under load, foxglove-sdk
  0.30; advertising everything at start avoids it.)

foxglove-sdk 0.30 accepts only the ``foxglove.sdk.v1`` WebSocket subprotocol. It refuses any
other client with HTTP 400 and logs "handshake failed" without the protocols offered; the
publisher then logs a warning naming the accepted subprotocol (which one the client offered
cannot be seen through the SDK).

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
from swerve.tools.logs.typestore import log_typestore

log = logging.getLogger(__name__)

#: Default WebSocket port of Foxglove's protocol.
DEFAULT_PORT = 8765
#: Records waiting for the worker before new ones are dropped.
QUEUE_SIZE = 64
#: How often the worker looks for new records, s (it is never woken by the loop).
POLL_S = 0.02
#: Topic with named numbers for plot panels (JSON).
LIVE_TOPIC = "/swerve/live"
#: Topics every run publishes every cycle (``/true_pose`` is added on the emulator).
RUN_TOPICS = ("/swerve/cycle", "/joint_states", "/trajectory", "/odom", "/reference", LIVE_TOPIC)
#: The only WebSocket subprotocol foxglove-sdk 0.30's server accepts.
ACCEPTED_SUBPROTOCOL = "foxglove.sdk.v1"
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


def _wrap(angle: float) -> float:
    """``angle`` wrapped into [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


class JointsAndTwist:
    """Fills what a :class:`CycleRecord` leaves out of ``/joint_states`` and ``/odom`` from the
    records before it (see the module doc); feed every record in order to :meth:`update`.

    Attributes after an update: ``position``, ``velocity``, ``effort`` (8 each in joint order,
    4 drive then 4 steer, or ``[]`` where unknown) and ``twist`` (``(vx_mps, vy_mps, wz_radps)``
    in ``base_link``, or ``None`` before two finite odometry poses).
    """

    def __init__(self):
        self._stamp_ns: int | None = None
        self._drive_rad = [0.0] * 4
        self._drive_radps: list[float] | None = None
        self._steer_rad: list[float] | None = None
        self._pose: tuple[float, float, float] | None = None
        self.position: list[float] = []
        self.velocity: list[float] = []
        self.effort: list[float] = []
        self.twist: tuple[float, float, float] | None = None

    def update(self, rec: CycleRecord) -> None:
        dt = None if self._stamp_ns is None else (int(rec.stamp_ns) - self._stamp_ns) * 1e-9
        if dt is not None and dt <= 0.0:
            dt = None
        self._stamp_ns = int(rec.stamp_ns)
        drive = [float(v) for v in rec.meas_drive_radps]
        steer = [float(v) for v in rec.meas_steer_rad]
        drive_ok, steer_ok = all(map(math.isfinite, drive)), all(map(math.isfinite, steer))
        if drive_ok and dt is not None and self._drive_radps is not None:
            self._drive_rad = [p + 0.5 * (a + b) * dt for p, a, b in zip(self._drive_rad, self._drive_radps, drive)]
        steer_radps = None
        if steer_ok and dt is not None and self._steer_rad is not None:
            steer_radps = [(b - a) / dt for a, b in zip(self._steer_rad, steer)]
        self.position = [*self._drive_rad, *steer] if steer_ok else []
        self.velocity = [*drive, *steer_radps] if drive_ok and steer_radps is not None else []
        current = [float(v) for v in rec.meas_current_a]
        self.effort = current if all(map(math.isfinite, current)) else []
        if drive_ok:
            self._drive_radps = drive
        if steer_ok:
            self._steer_rad = steer
        x, y, th = (float(v) for v in rec.est_pose)
        pose_ok = math.isfinite(x) and math.isfinite(y) and math.isfinite(th)
        self.twist = None
        if pose_ok and dt is not None and self._pose is not None:
            x0, y0, th0 = self._pose
            mid = th0 + 0.5 * _wrap(th - th0)
            dx, dy = (x - x0) / dt, (y - y0) / dt
            self.twist = (math.cos(mid) * dx + math.sin(mid) * dy, -math.sin(mid) * dx + math.cos(mid) * dy,
                          _wrap(th - th0) / dt)
        self._pose = (x, y, th) if pose_ok else None


class _RefusedClientLog(logging.Handler):
    """Turns foxglove-sdk's "handshake failed" error into a warning that names the subprotocol
    the server accepts (the SDK does not report what the client offered)."""

    def __init__(self, url: str):
        super().__init__(logging.ERROR)
        self.url = url
        self.refused = 0

    def emit(self, record: logging.LogRecord) -> None:
        text = record.getMessage()
        if "handshake failed" in text:
            self.refused += 1
            log.warning("live view %s: %s. foxglove-sdk accepts only the WebSocket subprotocol %r; "
                        "a client offering only 'foxglove.websocket.v1' (older Foxglove and Lichtblick "
                        "releases, @foxglove/ws-protocol 0.8) is refused with HTTP 400. The SDK does not "
                        "show which subprotocol the client offered.", self.url, text, ACCEPTED_SUBPROTOCOL)


class LivePublisher:
    """A Foxglove WebSocket server on ``host:port`` fed from a bounded queue (see module doc).

    ``port`` 0 picks a free port (:attr:`port` tells which). ``wheels``: wheel names in
    robot-file order (joint names derive from them). ``topics``: the channels advertised at
    start (a run's topics by default; ``swerve emulate --live`` gives ``("/true_pose",)``).
    Counters: :attr:`published` records, :attr:`dropped` records (queue full), :attr:`errors`
    (serialisation failures, logged), :attr:`refused_clients` (failed handshakes).
    """

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, *,
                 wheels: Sequence[str] = DEFAULT_WHEELS, queue_size: int = QUEUE_SIZE,
                 name: str = "swerve", topics: Sequence[str] = RUN_TOPICS):
        unknown = sorted(set(topics) - set(TOPICS) - {LIVE_TOPIC})
        if unknown:
            raise ConfigError(f"live view: unknown topics {', '.join(unknown)}")
        self.host, self.requested_port, self.name = host, int(port), name
        self._wheels = list(wheels)
        self._topics = tuple(topics)
        self._fill = JointsAndTwist()
        self._wall_offset_ns: int | None = None
        self._refusals: _RefusedClientLog | None = None
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

        self._ts = log_typestore()
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
        self._refusals = _RefusedClientLog(self.url)
        logging.getLogger("foxglove.websocket.server").addHandler(self._refusals)
        T = self._ts.types
        self._JointState, self._Odometry = T["sensor_msgs/msg/JointState"], T["nav_msgs/msg/Odometry"]
        self._Twist, self._Vector3 = T["geometry_msgs/msg/Twist"], T["geometry_msgs/msg/Vector3"]
        self._TwistWithCovariance = T["geometry_msgs/msg/TwistWithCovariance"]
        self._joints = joint_names(self._wheels)
        for topic in self._topics:
            self._advertise(topic)
        self._msgs.messages(CycleRecord(t_s=0.0, stamp_ns=0, cycle=0))   # build serialisers now
        self._thread = threading.Thread(target=self._work, name="swerve-live", daemon=True)
        self._thread.start()
        return self

    def _advertise(self, topic: str) -> None:
        """Create (and so advertise) the channel of ``topic``."""
        import foxglove

        if topic == LIVE_TOPIC:
            schema = foxglove.Schema(name="swerve.Live", encoding="jsonschema", data=json.dumps(LIVE_SCHEMA).encode())
            channel = foxglove.Channel(topic, schema=schema, message_encoding="json", context=self._ctx)
        else:
            msgdef, _ = self._ts.generate_msgdef(TOPICS[topic], ros_version=2)
            schema = foxglove.Schema(name=TOPICS[topic], encoding="ros2msg", data=msgdef.encode())
            channel = foxglove.Channel(topic, schema=schema, message_encoding="cdr", context=self._ctx)
        self._channels[topic] = channel

    @property
    def refused_clients(self) -> int:
        """Clients whose WebSocket handshake the server refused."""
        return self._refusals.refused if self._refusals is not None else 0

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
        if self._refusals is not None:
            logging.getLogger("foxglove.websocket.server").removeHandler(self._refusals)

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
        try:
            if isinstance(item, dict):
                item = CycleRecord(**item)
            if isinstance(item, CycleRecord):
                self._fill.update(item)     # every record, so integrals and differences stay whole
            if not self._has_clients():
                return
            if isinstance(item, _PoseItem):
                self._send_pose(item)
            else:
                self._send(item)
            self.published += 1
        except Exception:  # noqa: BLE001 - a bad record must not end the live view
            self.errors += 1
            log.exception("live view: could not publish a record")

    def wall_ns(self, stamp_ns: int) -> int:
        """Message time of a record stamped ``stamp_ns``: the wall time the first record arrived
        plus the robot time since it (module doc)."""
        if self._wall_offset_ns is None:
            self._wall_offset_ns = time.time_ns() - int(stamp_ns)
        return int(stamp_ns) + self._wall_offset_ns

    def _log(self, topic: str, msg, ns: int) -> None:
        self._channels[topic].log(bytes(self._ts.serialize_cdr(msg, msg.__msgtype__)), log_time=ns)

    def _send(self, rec: CycleRecord) -> None:
        ns = self.wall_ns(rec.stamp_ns)
        header = self._msgs.header(ns)
        fill = self._fill
        for topic, numbers in self._msgs.numbers(rec):
            if topic not in self._channels:
                continue
            if topic == "/joint_states":
                msg = self._JointState(header=header, name=self._joints, position=np.array(fill.position),
                                       velocity=np.array(fill.velocity), effort=np.array(fill.effort))
            elif topic == "/odom":
                if fill.twist is None:
                    continue
                vx, vy, wz = fill.twist
                twist = self._Twist(linear=self._Vector3(x=vx, y=vy, z=0.0),
                                    angular=self._Vector3(x=0.0, y=0.0, z=wz))
                odom = self._msgs.build(topic, header, numbers)
                msg = self._Odometry(header=header, child_frame_id=odom.child_frame_id, pose=odom.pose,
                                     twist=self._TwistWithCovariance(twist=twist, covariance=np.zeros(36)))
            else:
                msg = self._msgs.build(topic, header, numbers)
            self._log(topic, msg, ns)
        if LIVE_TOPIC in self._channels:
            self._channels[LIVE_TOPIC].log(json.dumps(live_numbers(rec, self.dropped)).encode(), log_time=ns)

    def _send_pose(self, item: "_PoseItem") -> None:
        if item.topic not in self._channels:
            return
        ns = self.wall_ns(item.stamp_ns)
        self._log(item.topic, self._msgs.pose_stamped(self._msgs.header(ns), item.pose), ns)


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
