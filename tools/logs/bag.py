"""Run logs as ROS 2 bags (MCAP storage): :class:`RunLogWriter`, :func:`read_log`, :func:`repair_log`.

Writing goes through ``rosbags.rosbag2.Writer`` (header, schemas, channels, summary and
``metadata.yaml``), the cycles' messages through :class:`~swerve.tools.logs.mcap_chunk.ChunkWriter`
(the same bytes, packed with ``struct``); reading walks the MCAP record by record
(:func:`swerve.tools.logs.mcap_scan.scan`, with the ``mcap`` package), which tolerates a file
whose summary and footer were never written (a crash or SIGKILL). Topics, types and the
crash-recovery rules are described in ``tools/logs/README.md``.
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import numpy as np

from swerve.core.atomic import OutputError
from swerve.driver.errors import ConfigError

from .mcap_chunk import ChunkWriter
from .messages import CdrTemplate, CycleMessages, CycleSerializer, StringCdr
from .record import CYCLE_FIELDS, LAYOUT_VERSION, CycleRecord, unpack

#: Value of ``metadata["format"]`` that marks a swerve run log.
FORMAT = "swerve-runlog"
#: Wheel order of ``configs/robot.yaml``; joints are ``<wheel>_drive`` (IDs 1-4), ``<wheel>_steer`` (5-8).
DEFAULT_WHEELS = ("front_left", "rear_left", "rear_right", "front_right")

#: topic -> ROS 2 message type.
TOPICS = {
    "/swerve/metadata": "std_msgs/msg/String",
    "/swerve/cycle": "std_msgs/msg/Float64MultiArray",
    "/joint_states": "sensor_msgs/msg/JointState",
    "/trajectory": "trajectory_msgs/msg/JointTrajectory",
    "/odom": "nav_msgs/msg/Odometry",
    "/reference": "geometry_msgs/msg/PoseStamped",
    "/true_pose": "geometry_msgs/msg/PoseStamped",
    "/sim_pose": "geometry_msgs/msg/PoseStamped",
}


def _typestore():
    """The log's type store (:func:`swerve.tools.logs.typestore.log_typestore`), imported when
    first needed: commands that never touch a log do not load rosbags."""
    from .typestore import log_typestore

    return log_typestore()


def joint_names(wheels: Sequence[str] = DEFAULT_WHEELS) -> list[str]:
    """The 8 joint names in servo-ID order: 4 ``*_drive`` then 4 ``*_steer``."""
    return [f"{w}_drive" for w in wheels] + [f"{w}_steer" for w in wheels]


@dataclass(frozen=True)
class LogLayouts:
    """What a writer takes from rosbags' type system, for one set of joint names: the cycle's
    CDR templates (``serializer``), each topic type's MCAP schema ``(message definition,
    RIHS01 hash)`` (``schemas``) and the metadata string's layout (``string``).
    :func:`probe_layouts` finds them with the log's type store;
    :class:`~swerve.tools.logs.layout_cache.LayoutCache` keeps them on disk."""

    serializer: CycleSerializer
    schemas: dict[str, tuple[str, str]]
    string: StringCdr

    def as_data(self) -> dict:
        """JSON-able data (:meth:`from_data` reads it back)."""
        return {"templates": {topic: t.as_data() for topic, t in self.serializer.templates.items()},
                "schemas": {name: list(s) for name, s in self.schemas.items()},
                "string": {"head": self.string.head.hex(), "order": self.string.order}}

    @classmethod
    def from_data(cls, data: dict) -> "LogLayouts":
        """The layouts :meth:`as_data` gave; ``ValueError`` (or ``KeyError``, ``TypeError``) if
        ``data`` does not hold every topic's template and type's schema."""
        schemas = {name: (str(s[0]), str(s[1])) for name, s in data["schemas"].items()
                   if isinstance(s, list) and len(s) == 2 and all(isinstance(v, str) for v in s)}
        if set(schemas) != set(TOPICS.values()):
            raise ValueError("the schemas are not those of the log's topics")
        templates = {topic: CdrTemplate.from_data(t) for topic, t in data["templates"].items()}
        if any(TOPICS.get(topic) != t.typename for topic, t in templates.items()):
            raise ValueError("a template is not of its topic's type")
        string = data["string"]
        return cls(CycleSerializer.from_templates(templates), schemas,
                   StringCdr(bytes.fromhex(string["head"]), str(string["order"])))


def probe_layouts(wheels: Sequence[str] = DEFAULT_WHEELS) -> LogLayouts:
    """The :class:`LogLayouts` of the log's type store (:func:`_typestore`) for ``wheels``:
    rosbags serialises probes of every topic (~35 ms) and gives the schemas."""
    ts = _typestore()
    schemas = {name: (ts.generate_msgdef(name, ros_version=2)[0], ts.hash_rihs01(name))
               for name in dict.fromkeys(TOPICS.values())}
    return LogLayouts(CycleSerializer(CycleMessages(ts, joint_names(wheels))), schemas, StringCdr.probe(ts))


class RunLogWriter:
    """Write one :class:`CycleRecord` per control cycle into a ROS 2 bag directory.

    Parameters
    ----------
    path : bag directory to create (must not exist); holds ``<name>.mcap`` and, once closed,
        ``metadata.yaml``.
    metadata : JSON-serialisable run description (trajectory, gains file, time scale, port,
        config...). Written to ``/swerve/metadata`` just before the first cycle (same time
        stamp) and at close to the bag's ``custom_data``.
    wheels : wheel names in robot.yaml order (joint names derive from them).
    flush_every : cycles between flushes of the pending MCAP chunk to the OS. 1 (default) makes
        the file readable to the last completed cycle after a crash; N loses at most N-1 cycles.
    layouts : the :class:`LogLayouts` of ``wheels`` (e.g. from a
        :class:`~swerve.tools.logs.layout_cache.LayoutCache`); default: :func:`probe_layouts`.

    Use as a context manager; leaving the ``with`` block (also by Ctrl-C or an exception) closes
    the bag cleanly, with index and ``metadata.yaml``.
    """

    def __init__(self, path: str | Path, metadata: dict, *,
                 wheels: Sequence[str] = DEFAULT_WHEELS, flush_every: int = 1,
                 layouts: LogLayouts | None = None):
        from rosbags.rosbag2 import StoragePlugin, Writer

        if flush_every < 1:
            raise ValueError(f"flush_every must be >= 1, got {flush_every}")
        self.path = Path(path)
        if self.path.exists():
            raise ConfigError(f"{self.path} exists already; run logs are never overwritten")
        self.metadata = dict(metadata)
        self.metadata.update(format=FORMAT, cycle_layout_version=LAYOUT_VERSION,
                             cycle_fields=[[n, s] for n, s in CYCLE_FIELDS],
                             joint_names=joint_names(wheels))
        try:
            self._metadata_json = json.dumps(self.metadata, allow_nan=True, default=str)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"run-log metadata is not JSON-serialisable: {exc}") from exc
        self.flush_every = int(flush_every)
        self.cycles_written = 0
        # rosbags builds its serialisers lazily (~35 ms); probing the layouts does it here, not
        # in the first control cycle (and layouts found before need neither them nor the type store)
        self._layouts = layouts if layouts is not None else probe_layouts(wheels)
        self._cdr = self._layouts.serializer
        self._bag = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._conn: dict[str, int] = {}       # topic -> channel ID
        self._open = False

    # -- context manager -------------------------------------------------------------------
    def __enter__(self) -> "RunLogWriter":
        self.open()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _output_error(self, exc: OSError) -> OutputError:
        """``exc`` (a full disk, a lost mount) as one line naming the log file."""
        found = sorted(self.path.glob("*.mcap")) if self.path.is_dir() else []
        return OutputError(f"cannot write run log {found[0] if found else self.path}: {exc.strerror or exc}")

    def open(self) -> None:
        """Create the bag, register every topic and write the metadata message."""
        try:
            self._open_bag()
        except OSError as exc:
            raise self._output_error(exc) from None

    def _open_bag(self) -> None:
        self._bag.open()
        for topic, msgtype in TOPICS.items():
            msgdef, rihs01 = self._layouts.schemas[msgtype]
            self._conn[topic] = self._bag.add_connection(topic, msgtype, msgdef=msgdef, rihs01=rihs01).id
        # rosbags keeps the current MCAP chunk in memory until it reaches 1 MiB; closing it early
        # is what makes the file crash-readable. Schemas and channels reach the disk before the
        # first cycle; the messages then go through the chunk writer.
        storage = self._bag.storage
        if not (hasattr(storage, "close_chunk") and hasattr(storage, "bio")):
            self._bag.abort()
            raise RuntimeError("this rosbags version has no McapWriter.close_chunk(); "
                               "crash-safe logging needs rosbags 0.11")
        if storage.chunk.bio.tell():
            storage.close_chunk()
        try:
            self._chunks = ChunkWriter(self._bag)
        except RuntimeError:
            self._bag.abort()
            raise
        self._chunks.flush()
        self._open = True
        self._bag.set_custom_data("swerve_metadata", self._metadata_json)

    def close(self) -> None:
        """Finish the MCAP (summary, index) and write ``metadata.yaml``. Idempotent."""
        if self._open:
            self._open = False
            try:
                if not self.cycles_written:
                    self._put_metadata(time.time_ns())
                self._chunks.flush()
                self._bag.close()
            except OSError as exc:
                raise self._output_error(exc) from None

    def _put_metadata(self, stamp_ns: int) -> None:
        # stamped like the first cycle, so the bag's time range is the run's (not 1970-now)
        self._chunks.add(self._conn["/swerve/metadata"], stamp_ns, self._layouts.string.encode(self._metadata_json))

    # -- writing ---------------------------------------------------------------------------
    def write(self, rec: CycleRecord) -> None:
        """Log one cycle on every topic; flush every ``flush_every`` cycles."""
        if not self._open:
            raise RuntimeError("RunLogWriter.write() outside an open log")
        ns = int(rec.stamp_ns)
        try:
            if not self.cycles_written:
                self._put_metadata(ns)
            add, conn = self._chunks.add, self._conn
            for topic, data in self._cdr.serialize(rec):
                add(conn[topic], ns, data)
            self.cycles_written += 1
            if self.cycles_written % self.flush_every == 0:
                self._chunks.flush()
        except OSError as exc:
            raise self._output_error(exc) from None


# -- reading ---------------------------------------------------------------------------------
@dataclass
class RunLog:
    """A run log read back: one array per :class:`CycleRecord` field, ``(n,)`` or ``(n, k)``.

    ``clean`` is False when the writer never closed the bag (crash, SIGKILL); the arrays then
    hold every cycle that reached the disk. ``damage`` lists the unreadable stretches of the file
    (:class:`Damage`, by byte offset); the arrays hold the cycles outside them.
    """

    path: Path
    metadata: dict
    fields: dict[str, np.ndarray]
    clean: bool
    layout: list = field(default_factory=list)
    damage: list = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.fields["t_s"].shape[0])

    def __getattr__(self, name: str):
        try:
            return self.__dict__["fields"][name]
        except KeyError:
            raise AttributeError(name) from None

    def record(self, i: int) -> CycleRecord:
        """Cycle ``i`` as a :class:`CycleRecord`."""
        return CycleRecord(**{k: (v[i].item() if v.ndim == 1 else v[i].copy())
                              for k, v in self.fields.items()})

    @property
    def recovery_note(self) -> str:
        """One line for the CLI; empty for a cleanly closed log."""
        if self.damage:
            first = self.damage[0]
            more = f" and {len(self.damage) - 1} more place(s)" if len(self.damage) > 1 else ""
            return f"log {first}{more}; recovered the {len(self)} intact cycles"
        return "" if self.clean else f"log was not closed cleanly; recovered {len(self)} cycles"

    def warn_if_recovered(self, command: str) -> None:
        """Print :attr:`recovery_note` to stderr for a log that was not closed but lost nothing."""
        if self.recovery_note and not self.damage:
            print(f"swerve {command}: {self.recovery_note}", file=sys.stderr)

    def raise_if_damaged(self) -> None:
        """Raise :class:`LogDamaged` naming the first unreadable stretch, if the log has one."""
        if self.damage:
            raise LogDamaged(f"{self.path}: {self.recovery_note}")


def _mcap_file(path: Path) -> Path:
    if not path.exists():
        raise ConfigError(f"no such run log: {path}")
    if path.is_file():
        return path
    found = sorted(path.glob("*.mcap"))
    if len(found) != 1:
        raise ConfigError(f"not a swerve run log: {path} holds {len(found)} .mcap files, expected 1")
    return found[0]


class LogDamaged(ConfigError):
    """A run log has unreadable stretches; the message names the first one's byte offset."""


def read_log(path: str | Path) -> RunLog:
    """Read a run log (bag directory or its ``.mcap`` file) into a :class:`RunLog`.

    Works on logs that were never closed: the MCAP is streamed record by record and reading
    stops at the first incomplete record. Raises :class:`ConfigError` for a missing path, a
    file that is not a swerve run log, or a log without a single complete cycle.
    """
    from .mcap_scan import Damage, scan

    path = Path(path)
    mcap_path = _mcap_file(path)
    channels, _, messages, footer, damage = scan(mcap_path)
    by_topic = {c.topic: c.id for c in channels.values()}
    if "/swerve/cycle" not in by_topic or "/swerve/metadata" not in by_topic:
        raise ConfigError(f"not a swerve run log: {path} has no /swerve/cycle or /swerve/metadata topic")
    ts = _typestore()
    meta_id, cycle_id = by_topic["/swerve/metadata"], by_topic["/swerve/cycle"]
    metadata: dict | None = None
    rows, stamps = [], []
    for offset, m in messages:
        try:
            if m.channel_id == cycle_id:
                row = np.asarray(ts.deserialize_cdr(m.data, TOPICS["/swerve/cycle"]).data, dtype=np.float64)
                if rows and row.shape != rows[0].shape:
                    raise ValueError(f"{row.size} values where the others have {rows[0].size}")
                rows.append(row)
                stamps.append(m.log_time)
            elif m.channel_id == meta_id and metadata is None:
                metadata = json.loads(ts.deserialize_cdr(m.data, TOPICS["/swerve/metadata"]).data)
                if not isinstance(metadata, dict):
                    raise ValueError("the metadata is not a JSON object")
        except Exception as exc:  # noqa: BLE001 - any decoding failure of a stored message is damage
            damage.append(Damage(offset, f"undecodable message in the chunk there: {type(exc).__name__}", None))
    if metadata is None or metadata.get("format") != FORMAT:
        lost = f" (its metadata is lost: {damage[0]})" if damage else ""
        raise ConfigError(f"not a swerve run log: {path} carries no swerve metadata{lost}")
    if not rows:
        raise ConfigError(f"empty run log: {path} holds no complete cycle")
    try:
        layout = [(str(n), int(s)) for n, s in metadata["cycle_fields"]]
        fields_ = unpack(np.vstack(rows), layout)
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: bad run-log metadata: cycle_fields does not describe the "
                          f"{rows[0].size}-value cycles ({type(exc).__name__}: {exc})") from None
    fields_["stamp_ns"] = np.asarray(stamps, dtype=np.int64)
    bag_dir = mcap_path.parent
    clean = footer and (bag_dir / "metadata.yaml").exists()
    return RunLog(path=path, metadata=metadata, fields=fields_, clean=clean and not damage, layout=layout,
                  damage=sorted(damage, key=lambda d: d.offset))


def repair_log(path: str | Path, out: str | Path | None = None) -> Path:
    """Copy every complete message of an unclosed log into a new, properly closed bag.

    The copy (default ``<log>-repaired``) has the MCAP summary/index and ``metadata.yaml``
    that ``ros2 bag`` and rosbags' reader need. Returns its path.
    """
    from rosbags.rosbag2 import StoragePlugin, Writer

    from .mcap_scan import scan

    path = Path(path)
    mcap_path = _mcap_file(path)
    channels, schemas, messages, _, _ = scan(mcap_path)
    out = Path(out) if out is not None else path.with_name(path.name.removesuffix(".mcap") + "-repaired")
    ts = _typestore()
    with Writer(out, version=9, storage_plugin=StoragePlugin.MCAP) as bag:
        conns = {}
        for cid, ch in sorted(channels.items()):
            msgtype = schemas[ch.schema_id].name
            conns[cid] = bag.add_connection(ch.topic, msgtype, msgdef=schemas[ch.schema_id].data.decode(),
                                            rihs01=ts.hash_rihs01(msgtype))
        for _, m in messages:
            bag.write(conns[m.channel_id], m.log_time, m.data)
    return out
