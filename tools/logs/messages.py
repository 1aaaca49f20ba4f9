"""The ROS 2 messages of one control cycle: what the run log stores and the live view streams.

:class:`CycleMessages` turns a :class:`CycleRecord` into ``(topic, message)`` pairs of
``rosbags`` message objects (types of :data:`swerve.tools.logs.bag.TOPICS`); the bag writer
serialises them into the MCAP, :mod:`swerve.tools.live` onto Foxglove channels, so the two
cannot drift apart. Parts that are the same every cycle are built once.

Every message of a cycle has a fixed shape (the same strings and sequence lengths each cycle);
what changes is its header stamp and its float64 numbers (:meth:`CycleMessages.numbers`).
:class:`CycleSerializer` therefore has ``rosbags`` serialise each topic's message once, finds
where the stamp and each number land in those bytes, and per cycle packs the new ones into a
copy: the bytes ``Typestore.serialize_cdr`` would give, without building message objects.
"""
from __future__ import annotations

import random
import struct
from math import cos, isfinite, sin
from typing import Sequence

import numpy as np

from .record import CYCLE_SIZE, FLAT_SLICES, CycleRecord, flatten

_NAN4 = [float("nan")] * 4
#: Where the numbers of the cycle's messages are in the flat record.
_MEAS_STEER, _MEAS_DRIVE, _MEAS_CURRENT, _CMD_STEER, _CMD_DRIVE, _EST_POSE = (FLAT_SLICES[name] for name in (
    "meas_steer_rad", "meas_drive_radps", "meas_current_a", "cmd_steer_rad", "cmd_drive_radps", "est_pose"))
_POSE_TOPICS = (("/reference", FLAT_SLICES["ref_pose"]), ("/true_pose", FLAT_SLICES["true_pose"]),
                ("/sim_pose", FLAT_SLICES["sim_pose"]))


def _pose_numbers(x: float, y: float, th: float) -> list[float]:
    """The float64 fields of a ``geometry_msgs/Pose`` of a planar pose, in field order:
    position x, y, z, orientation x, y, z, w."""
    return [x, y, 0.0, 0.0, 0.0, sin(th / 2), cos(th / 2)]


def cycle_numbers(rec: CycleRecord) -> list[tuple[str, list[float]]]:
    """``(topic, numbers)`` for one cycle, ``/swerve/cycle`` first: the float64 fields each
    topic's message carries, in field order (what :meth:`CycleMessages.build` takes); a pose
    topic whose pose is not finite (unknown) is left out."""
    flat = flatten(rec)
    out = [("/swerve/cycle", flat),
           ("/joint_states", [*_NAN4, *flat[_MEAS_STEER], *flat[_MEAS_DRIVE], *_NAN4, *flat[_MEAS_CURRENT]]),
           ("/trajectory", [*_NAN4, *flat[_CMD_STEER], *flat[_CMD_DRIVE], *_NAN4]),
           ("/odom", _pose_numbers(*flat[_EST_POSE]))]
    for topic, at in _POSE_TOPICS:
        x, y, th = flat[at]
        if isfinite(x) and isfinite(y) and isfinite(th):
            out.append((topic, _pose_numbers(x, y, th)))
    return out


class CycleMessages:
    """Message builder for one typestore (``rosbags.typesys`` store) and joint names (8)."""

    def __init__(self, typestore, joints: Sequence[str]):
        self._ts = typestore
        self._joints = list(joints)
        T = typestore.types
        self._layout = T["std_msgs/msg/MultiArrayLayout"](
            dim=[T["std_msgs/msg/MultiArrayDimension"](label="cycle_record_v1", size=CYCLE_SIZE,
                                                       stride=CYCLE_SIZE)],
            data_offset=0)
        nan3 = T["geometry_msgs/msg/Vector3"](x=np.nan, y=np.nan, z=np.nan)
        self._no_twist = T["geometry_msgs/msg/TwistWithCovariance"](
            twist=T["geometry_msgs/msg/Twist"](linear=nan3, angular=nan3), covariance=np.zeros(36))
        self._zero_duration = T["builtin_interfaces/msg/Duration"](sec=0, nanosec=0)
        self._empty = np.empty(0)
        self._covariance = np.zeros(36)
        # the message classes, looked up once
        self._Float64MultiArray = T["std_msgs/msg/Float64MultiArray"]
        self._Header, self._Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
        self._JointState = T["sensor_msgs/msg/JointState"]
        self._JointTrajectory = T["trajectory_msgs/msg/JointTrajectory"]
        self._JointTrajectoryPoint = T["trajectory_msgs/msg/JointTrajectoryPoint"]
        self._Odometry = T["nav_msgs/msg/Odometry"]
        self._PoseWithCovariance = T["geometry_msgs/msg/PoseWithCovariance"]
        self._PoseStamped, self._Pose = T["geometry_msgs/msg/PoseStamped"], T["geometry_msgs/msg/Pose"]
        self._Point, self._Quaternion = T["geometry_msgs/msg/Point"], T["geometry_msgs/msg/Quaternion"]

    def header(self, stamp_ns: int):
        """``std_msgs/Header`` at ``stamp_ns`` in the ``odom`` frame."""
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        return self._Header(stamp=self._Time(sec=sec, nanosec=nanosec), frame_id="odom")

    def numbers(self, rec: CycleRecord) -> list[tuple[str, list[float]]]:
        """:func:`cycle_numbers` of ``rec``."""
        return cycle_numbers(rec)

    def build(self, topic: str, header, numbers: Sequence[float]):
        """The message of ``topic`` with ``numbers`` (as :meth:`numbers` gives them) under
        ``header`` (unused by ``/swerve/cycle``)."""
        if topic == "/swerve/cycle":
            return self._Float64MultiArray(layout=self._layout, data=np.array(numbers, dtype=np.float64))
        if topic == "/joint_states":
            return self._JointState(header=header, name=self._joints,
                                    position=np.array(numbers[0:8]), velocity=np.array(numbers[8:16]),
                                    effort=np.array(numbers[16:24]))
        if topic == "/trajectory":
            point = self._JointTrajectoryPoint(
                positions=np.array(numbers[0:8]), velocities=np.array(numbers[8:16]),
                accelerations=self._empty, effort=self._empty, time_from_start=self._zero_duration)
            return self._JointTrajectory(header=header, joint_names=self._joints, points=[point])
        if topic == "/odom":
            return self._Odometry(
                header=header, child_frame_id="base_link",
                pose=self._PoseWithCovariance(pose=self._pose_msg(numbers), covariance=self._covariance),
                twist=self._no_twist)
        return self._PoseStamped(header=header, pose=self._pose_msg(numbers))

    def messages(self, rec: CycleRecord) -> list:
        """``(topic, message)`` for one cycle, ``/swerve/cycle`` first; a pose topic whose pose
        is not finite (unknown) is left out."""
        header = self.header(rec.stamp_ns)
        return [(topic, self.build(topic, header, v)) for topic, v in self.numbers(rec)]

    def pose(self, pose):
        """``geometry_msgs/Pose`` of a planar pose ``(x_m, y_m, theta_rad)``."""
        x, y, th = map(float, pose)
        return self._pose_msg(_pose_numbers(x, y, th))

    def _pose_msg(self, v: Sequence[float]):
        return self._Pose(position=self._Point(x=v[0], y=v[1], z=v[2]),
                          orientation=self._Quaternion(x=v[3], y=v[4], z=v[5], w=v[6]))

    def pose_stamped(self, header, pose):
        """``geometry_msgs/PoseStamped`` of a planar pose under ``header``."""
        return self._PoseStamped(header=header, pose=self.pose(pose))


class CdrTemplate:
    """The CDR bytes of one topic's message and where its header stamp (``stamp_at``, None for
    none) and its float64 numbers land: ``runs`` of ``(offset, first, end)``, numbers
    ``first..end-1`` packed contiguously from ``offset`` in the byte ``order`` (``<``, ``>``).
    :meth:`probe` finds them by serialising probes with rosbags; :meth:`fill` packs new ones into
    a copy."""

    def __init__(self, typename: str, raw: bytes, order: str, stamp_at: int | None,
                 runs: Sequence[tuple[int, int, int]]):
        count = runs[-1][2] if runs else 0
        spans = [(stamp_at, 8)] if stamp_at is not None else []
        spans += [(at, 8 * (end - first)) for at, first, end in runs]
        if (order not in "<>" or len(order) != 1 or any(at < 0 or at + n > len(raw) for at, n in spans)
                or [first for _, first, _ in runs] != [0] + [end for _, _, end in runs[:-1]]
                or any(end <= first for _, first, end in runs)):
            raise ValueError(f"{typename}: not a CDR template (runs {list(runs)}, stamp {stamp_at}, "
                             f"{len(raw)} bytes)")
        self.typename, self.count = typename, count
        self._raw, self._order, self._stamp_at = bytes(raw), order, stamp_at
        self._layout = tuple((int(at), int(first), int(end)) for at, first, end in runs)
        self._runs = tuple((struct.Struct(f"{order}{end - first}d").pack_into, at, first, end)
                           for at, first, end in self._layout)
        self._stamp = struct.Struct(order + "iI").pack_into

    @classmethod
    def probe(cls, msgs: CycleMessages, topic: str, count: int) -> "CdrTemplate":
        """The template of ``topic``'s message with ``count`` numbers, from rosbags'
        serialisation of two probes (raises ``RuntimeError`` if its bytes are not a fixed
        layout)."""
        rng = random.Random(count)
        # probe values whose 8-byte patterns occur once in the bytes (checked below)
        probe = [rng.uniform(1.0, 2.0) * 10 ** rng.randint(-30, 30) for _ in range(count)]
        sec, nanosec = 0x1234_5678, 0x2345_6789
        msg = msgs.build(topic, msgs.header(sec * 1_000_000_000 + nanosec), probe)
        typename = msg.__msgtype__
        raw = bytes(msgs._ts.serialize_cdr(msg, typename))
        order = "<" if raw[1] else ">"     # the CDR encapsulation says the byte order
        stamp_at = None
        if topic != "/swerve/cycle":
            stamp_at = _find_once(raw, struct.pack(order + "iI", sec, nanosec), topic, "stamp")
        offsets = [_find_once(raw, struct.pack(order + "d", v), topic, f"number {k}")
                   for k, v in enumerate(probe)]
        runs, k = [], 0                    # (offset, first, end) of numbers contiguous in the bytes
        while k < count:
            end = k + 1
            while end < count and offsets[end] == offsets[end - 1] + 8:
                end += 1
            runs.append((offsets[k], k, end))
            k = end
        template = cls(typename, raw, order, stamp_at, runs)
        other = [rng.uniform(-1.0, 1.0) for _ in range(count)]
        check = bytes(msgs._ts.serialize_cdr(msgs.build(topic, msgs.header(7), other), typename))
        if template.fill(sec, nanosec, probe) != raw or template.fill(0, 7, other) != check:
            raise RuntimeError(f"{topic}: the CDR bytes of {typename} do not have a fixed layout")
        return template

    def as_data(self) -> dict:
        """The template as JSON-able data (:meth:`from_data` reads it back)."""
        return {"type": self.typename, "raw": self._raw.hex(), "order": self._order,
                "stamp_at": self._stamp_at, "runs": [list(r) for r in self._layout]}

    @classmethod
    def from_data(cls, data: dict) -> "CdrTemplate":
        """The template :meth:`as_data` gave; ``ValueError`` (or ``KeyError``, ``TypeError``) if
        ``data`` is not one."""
        stamp_at = data["stamp_at"]
        if not (stamp_at is None or type(stamp_at) is int) or not isinstance(data["type"], str):
            raise ValueError("not a CDR template")
        runs = [tuple(r) for r in data["runs"]]
        if not all(len(r) == 3 and all(type(v) is int for v in r) for r in runs):
            raise ValueError("not a CDR template")
        return cls(data["type"], bytes.fromhex(data["raw"]), str(data["order"]), stamp_at, runs)

    def fill(self, sec: int, nanosec: int, numbers: Sequence[float]) -> bytearray:
        """The message's bytes with the stamp ``sec``/``nanosec`` and ``numbers`` (:attr:`count`)."""
        if len(numbers) != self.count:
            raise ValueError(f"{self.typename}: {len(numbers)} numbers, expected {self.count}")
        buf = bytearray(self._raw)
        if self._stamp_at is not None:
            self._stamp(buf, self._stamp_at, sec, nanosec)
        for pack_into, at, first, end in self._runs:
            pack_into(buf, at, *numbers[first:end])
        return buf


class StringCdr:
    """The CDR bytes of a ``std_msgs/String``: the encapsulation ``head`` (4 bytes), then the
    text as a CDR string (a uint32 length counting the NUL, the UTF-8 bytes, a NUL) in the byte
    ``order``. :meth:`probe` takes head and order from rosbags' bytes of two probes and checks
    that layout against them."""

    TYPE = "std_msgs/msg/String"
    _PROBES = ("", "swerve \u2713 run log")

    def __init__(self, head: bytes, order: str):
        if len(head) != 4 or order not in ("<", ">"):
            raise ValueError(f"not a CDR string layout (head {head.hex()}, order {order!r})")
        self.head, self.order = bytes(head), order

    def encode(self, text: str) -> bytes:
        """The bytes ``Typestore.serialize_cdr`` gives for ``String(data=text)``."""
        data = text.encode("utf-8")
        return self.head + struct.pack(self.order + "I", len(data) + 1) + data + b"\0"

    @classmethod
    def probe(cls, typestore) -> "StringCdr":
        """The layout of ``typestore``'s String (``RuntimeError`` if its bytes differ from it)."""
        string = typestore.types[cls.TYPE]
        raws = [bytes(typestore.serialize_cdr(string(data=text), cls.TYPE)) for text in cls._PROBES]
        layout = cls(raws[0][:4], "<" if raws[0][1] else ">")
        if [layout.encode(text) for text in cls._PROBES] != raws:
            raise RuntimeError(f"the CDR bytes of {cls.TYPE} are not a length, the text and a NUL")
        return layout


def _find_once(raw: bytes, needle: bytes, topic: str, what: str) -> int:
    at = raw.find(needle)
    if at < 0 or raw.find(needle, at + 1) >= 0:
        raise RuntimeError(f"{topic}: cannot place the {what} in its CDR bytes")
    return at


class CycleSerializer:
    """``(topic, CDR bytes)`` of one cycle: what ``typestore.serialize_cdr`` makes of each message
    of :meth:`CycleMessages.messages`, byte for byte, at a fraction of the cost (module docstring).

    ``CycleSerializer(msgs)`` probes every topic's template with rosbags (raises
    ``RuntimeError`` if a message's bytes are not a fixed template, checked against two probes
    per topic); :meth:`from_templates` takes templates found before."""

    def __init__(self, msgs: CycleMessages):
        z = np.zeros(3)
        full = CycleRecord(t_s=0.0, stamp_ns=0, cycle=0, ref_pose=z, true_pose=z, sim_pose=z)
        self._templates = {topic: CdrTemplate.probe(msgs, topic, len(v)) for topic, v in msgs.numbers(full)}

    @classmethod
    def from_templates(cls, templates: dict[str, CdrTemplate]) -> "CycleSerializer":
        """The serializer of these templates (topic -> :class:`CdrTemplate`, one per topic a cycle
        can carry, each with as many numbers as :func:`cycle_numbers` gives it)."""
        z = np.zeros(3)
        full = CycleRecord(t_s=0.0, stamp_ns=0, cycle=0, ref_pose=z, true_pose=z, sim_pose=z)
        counts = {topic: len(v) for topic, v in cycle_numbers(full)}
        if counts != {topic: t.count for topic, t in templates.items()}:
            raise ValueError("the templates do not match the cycle's topics and numbers")
        serializer = cls.__new__(cls)
        serializer._templates = dict(templates)
        return serializer

    @property
    def templates(self) -> dict[str, CdrTemplate]:
        """topic -> its :class:`CdrTemplate`."""
        return dict(self._templates)

    def typename(self, topic: str) -> str:
        """The ROS 2 message type of ``topic``."""
        return self._templates[topic].typename

    def serialize(self, rec: CycleRecord) -> list[tuple[str, bytearray]]:
        """``(topic, CDR bytes)`` for one cycle, in the order of :meth:`CycleMessages.messages`."""
        sec, nanosec = divmod(int(rec.stamp_ns), 1_000_000_000)
        templates = self._templates
        return [(topic, templates[topic].fill(sec, nanosec, v)) for topic, v in cycle_numbers(rec)]
