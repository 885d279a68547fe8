"""A rosbag2 recording as the drivers' input: its synchronized sets of input messages, in recording order.

`BagReader` is to the replay what a dataset reader is to kiss-icp's pipeline: it opens the bag (MCAP or
sqlite3, through `sources`; no ROS runtime), finds the input topics, reads the small side topics first
(/tf_static, init_bodies) and then yields every message with the synchronized sets it completed, using
the node's synchronizer and settings (`runtime.sync`). Ground-truth documents are parsed as they come,
so memory does not grow with the bag's length.

Input topics are the node's (`topics.*`); a topic missing from the bag is looked up by type instead (the
only Image, the only CameraInfo; PointCloud2 clouds with `u`, `v` fields are keypoints, with `x` points).

No message stops the replay: the storage's faults (bad chunks, a cut file, corrupt sqlite3 rows:
`sources`), messages whose bytes are not their type and unusable ground-truth documents are counted in
`faults` by reason (sources.READ_*) and skipped.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from msg_adapters import clip
from msg_adapters.bodies import MAX_DOCUMENT_BYTES
from smplify3d_ros.eval.truth import GROUND_TRUTH_TOPIC, TruthFrame, parse_truth_document
from smplify3d_ros.replay.sources import READ_BAD_TRUTH, READ_UNDECODABLE, ReadFaults, SourceError, open_source
from smplify3d_ros.runtime.config import NodeConfig, TopicsConfig
from smplify3d_ros.runtime.messages import FrameMessages
from smplify3d_ros.runtime.sync import Synchronizer, make_synchronizer
from smplify3d_ros.runtime.transforms import TransformGraph

IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
TF_STATIC_TOPIC = "/tf_static"


class ReplayError(RuntimeError):
    """The bag cannot be replayed (missing inputs, unreadable file); the message says why."""


@dataclass
class InputTopics:
    image: str | None
    compressed: bool
    camera_info: str
    points: str
    keypoints: str
    init_bodies: str | None

    @property
    def synchronized(self) -> list[tuple[str, str]]:
        """(input name, topic) of the synchronized inputs, in the synchronizer's order."""
        image = [("image", self.image)] if self.image else []
        return image + [("camera_info", self.camera_info), ("points", self.points), ("keypoints", self.keypoints)]


@dataclass
class BagStep:
    """One recorded message, and what it completed."""

    connection: Any  # sources.BagConnection
    timestamp: int  # recording time, ns
    raw: bytes  # CDR bytes as recorded
    frames: list[FrameMessages] = field(default_factory=list)  # synchronized sets this message completed
    truth: TruthFrame | None = None  # the ground-truth document this message holds


def _fields_of_first(reader: Any, connection: Any, typestore: Any, tries: int = 10) -> set[str]:
    """The field names of the first decodable cloud of a topic (the main pass counts undecodable ones)."""
    for conn, _, raw in reader.messages(connections=[connection]):
        try:
            return {str(f.name) for f in typestore.deserialize_cdr(raw, conn.msgtype).fields}
        except Exception:  # noqa: BLE001 - rosbags raises several types for bytes of another type
            tries -= 1
            if tries == 0:
                break
    return set()


def _topic_list(by_topic: dict[str, str], limit: int = 20) -> str:
    """The bag's topics for an error message (bounded: a bag may hold thousands, with long names)."""
    items = [f"{clip(t, 80)} ({clip(mt, 60)})" for t, mt in sorted(by_topic.items())[:limit]]
    more = f" and {len(by_topic) - limit} more" if len(by_topic) > limit else ""
    return (", ".join(items) or "none") + more


def resolve_topics(reader: Any, typestore: Any, topics: TopicsConfig) -> InputTopics:
    """Configured topic names, else the bag's only topic of the right type (see the module docstring)."""
    by_topic = {c.topic: c.msgtype for c in reader.connections}

    def pick(configured: str, msgtype: str, what: str, required: bool = True) -> str | None:
        if configured and by_topic.get(configured) == msgtype:
            return configured
        candidates = sorted(t for t, mt in by_topic.items() if mt == msgtype)
        if len(candidates) == 1:
            return candidates[0]
        if required:
            raise ReplayError(f"cannot tell the {what} topic: {clip(configured)!r} is not in the bag and it "
                              f"has {len(candidates)} {msgtype} topics; topics: {_topic_list(by_topic)}")
        return None

    camera_info = pick(topics.camera_info, "sensor_msgs/msg/CameraInfo", "camera info")
    image = pick(topics.compressed_image or topics.image, IMAGE_TYPES[1 if topics.compressed else 0], "image",
                 required=False)
    compressed = topics.compressed
    if image is None:
        image = pick("", IMAGE_TYPES[1 - int(topics.compressed)], "image", required=False)
        compressed = image is not None and not topics.compressed
    clouds = {t for t, mt in by_topic.items() if mt == "sensor_msgs/msg/PointCloud2"}
    found = {"points": topics.points if topics.points in clouds else None,
             "keypoints": topics.keypoints if topics.keypoints in clouds else None}
    if None in found.values():
        kinds: dict[str, list[str]] = {"keypoints": [], "points": []}
        for conn in reader.connections:
            if conn.topic in clouds and conn.topic not in found.values():
                names = _fields_of_first(reader, conn, typestore)
                if {"u", "v", "joint"} <= names:
                    kinds["keypoints"].append(conn.topic)
                elif {"x", "y", "z"} <= names:
                    kinds["points"].append(conn.topic)
        for what, candidates in kinds.items():
            if found[what] is None:
                if len(candidates) != 1:
                    raise ReplayError(f"cannot tell the {what} topic: {clip(getattr(topics, what))!r} is not "
                                      f"in the bag and {len(candidates)} PointCloud2 topics look like "
                                      f"{what}: {clip(candidates)}")
                found[what] = candidates[0]
    init = topics.init_bodies if topics.init_bodies and by_topic.get(topics.init_bodies) == "std_msgs/msg/String" \
        else None
    assert camera_info is not None
    return InputTopics(image, compressed, camera_info, found["points"], found["keypoints"], init)


class BagReader:
    """See the module docstring. Use as a context manager; iterate for `BagStep`s."""

    def __init__(self, path: str | Path, node: NodeConfig, log: Any = None) -> None:
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if not self.path.exists():
            raise ReplayError(f"{self.path} does not exist")
        self.node = node
        self.log = log
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        try:
            self.reader = open_source(self.path, log)
        except SourceError as e:
            raise ReplayError(str(e)) from None
        except Exception as e:  # noqa: BLE001 - rosbags and sqlite raise several types for unreadable bags
            raise ReplayError(f"cannot read {self.path}: {clip(' '.join(str(e).split()), 200)}") from None
        self.faults: ReadFaults = self.reader.faults
        try:
            self.topics = resolve_topics(self.reader, self.typestore, node.topics)
        except Exception:
            self.reader.close()
            raise
        self.tf = TransformGraph()
        self.init_docs: list[tuple[int, str]] = []  # (stamp ns or -1 if unreadable, document)
        self.messages_read = 0  # messages the main pass got from the storage
        self._read_side_topics()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def close(self) -> None:
        self.reader.close()

    @property
    def connections(self) -> list[Any]:
        return list(self.reader.connections)

    @property
    def message_count(self) -> int:
        return int(self.reader.message_count)

    @property
    def duration_ns(self) -> tuple[int, int]:
        return int(self.reader.start_time), int(self.reader.end_time)

    def _read_side_topics(self) -> None:
        """One pass over /tf_static, /tf and init_bodies (small topics) before the replay: the TF graph holds
        every recorded transform, so that lookups at a frame's stamp interpolate like tf2."""
        from smplify3d_ros.runtime.transforms import TF_TOPIC

        tf_topics = {TF_STATIC_TOPIC, TF_TOPIC}
        wanted = tf_topics | ({self.topics.init_bodies} if self.topics.init_bodies else set())
        conns = [c for c in self.reader.connections if c.topic in wanted]
        for conn, timestamp, raw in self.reader.messages(connections=conns) if conns else ():
            msg = self._decode(conn, timestamp, raw)
            if msg is None:
                continue
            try:
                if conn.topic in tf_topics and conn.msgtype == "tf2_msgs/msg/TFMessage":
                    self.tf.add(msg, static=conn.topic == TF_STATIC_TOPIC)
                elif conn.topic == self.topics.init_bodies:
                    self.init_docs.append((_document_stamp_ns(msg.data), msg.data))
            except Exception as e:  # noqa: BLE001 - a transform with unusable values
                self.faults.add(READ_UNDECODABLE, f"{clip(conn.topic)} at {timestamp}: {clip(e)}",
                                key=(conn.id, timestamp))

    def _decode(self, conn: Any, timestamp: int, raw: bytes) -> Any:
        """The message, or None (counted) when its bytes are not a `conn.msgtype`."""
        try:
            return self.typestore.deserialize_cdr(raw, conn.msgtype)
        except Exception as e:  # noqa: BLE001 - rosbags raises SerdeError, ValueError, IndexError, ...
            self.faults.add(READ_UNDECODABLE, f"{clip(conn.topic)} at {timestamp}: not a {clip(conn.msgtype)} "
                            f"({type(e).__name__}: {clip(e)})", key=(conn.id, timestamp, len(raw)))
            return None

    def synchronizer(self, on_set: Any) -> Synchronizer:
        sync = self.node.sync
        names = [name for name, _ in self.topics.synchronized]
        latest = [names.index("camera_info")] if sync.latest_camera_info else []
        return make_synchronizer(len(names), sync.slop_s, sync.queue_size, on_set, sync.use_message_filters,
                                 self.log, latest)

    def __iter__(self) -> Iterator[BagStep]:
        names = [name for name, _ in self.topics.synchronized]
        index = {topic: i for i, (_, topic) in enumerate(self.topics.synchronized)}
        completed: list[FrameMessages] = []

        def on_set(*msgs: Any) -> None:
            by = dict(zip(names, msgs, strict=True))
            completed.append(FrameMessages(by["camera_info"], by["points"], by["keypoints"], by.get("image"),
                                           self.topics.compressed))

        self.sync = self.synchronizer(on_set)
        self.messages_read = 0
        for conn, timestamp, raw in self.reader.messages():
            self.messages_read += 1
            step = BagStep(conn, timestamp, raw)
            i = index.get(conn.topic)
            if i is not None:
                self._synchronize(i, conn, timestamp, raw)
                step.frames, completed[:] = list(completed), []
            elif conn.topic == GROUND_TRUTH_TOPIC and conn.msgtype == "std_msgs/msg/String":
                step.truth = self._truth(conn, timestamp, raw)
            yield step

    def _synchronize(self, index: int, conn: Any, timestamp: int, raw: bytes) -> None:
        msg = self._decode(conn, timestamp, raw)
        if msg is None:
            return
        try:
            self.sync.add(index, msg)
        except (AttributeError, TypeError, ValueError, OverflowError) as e:  # a header without a stamp
            self.faults.add(READ_UNDECODABLE, f"{clip(conn.topic)} at {timestamp}: no usable header stamp "
                            f"({clip(e)})", key=(conn.id, timestamp, len(raw)))

    def _truth(self, conn: Any, timestamp: int, raw: bytes) -> TruthFrame | None:
        msg = self._decode(conn, timestamp, raw)
        if msg is None:
            return None
        try:
            return parse_truth_document(msg.data)
        except Exception as e:  # noqa: BLE001 - a hostile document must not stop the replay
            self.faults.add(READ_BAD_TRUTH, f"{GROUND_TRUTH_TOPIC} at {timestamp}: ignored a document: "
                            f"{clip(e)}", key=(conn.id, timestamp))
            return None

    @property
    def truth_errors(self) -> int:
        """Ground-truth documents that could not be used."""
        return self.faults.counts[READ_BAD_TRUTH]


def _document_stamp_ns(text: str) -> int:
    """The stamp of a bodies document (-1 when unreadable: the processor's parser says why later)."""
    if len(text) > MAX_DOCUMENT_BYTES:
        return -1
    try:
        stamp = json.loads(text)["stamp"]
        if isinstance(stamp, dict):
            return int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])
        return round(float(stamp) * 1e9)
    except (ValueError, KeyError, TypeError, RecursionError):
        return -1
