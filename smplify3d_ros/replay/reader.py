"""A rosbag2 recording as the drivers' input: its synchronized sets of input messages, in recording order.

`BagReader` is to the replay what a dataset reader is to kiss-icp's pipeline: it opens the bag (MCAP or
sqlite3, with rosbags; no ROS runtime), finds the input topics, reads the small side topics first
(/tf_static, init_bodies) and then yields every message with the synchronized sets it completed, using
the node's synchronizer and settings (`runtime.sync`). Ground-truth documents are parsed as they come,
so memory does not grow with the bag's length.

Input topics are the node's (`topics.*`); a topic missing from the bag is looked up by type instead (the
only Image, the only CameraInfo; PointCloud2 clouds with `u`, `v` fields are keypoints, with `x` points).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from smplify3d_ros.eval.truth import GROUND_TRUTH_TOPIC, TruthFrame, parse_truth_document
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

    connection: Any  # rosbags Connection
    timestamp: int  # recording time, ns
    raw: bytes  # CDR bytes as recorded
    frames: list[FrameMessages] = field(default_factory=list)  # synchronized sets this message completed
    truth: TruthFrame | None = None  # the ground-truth document this message holds


def _fields_of_first(reader: Any, connection: Any, typestore: Any) -> set[str]:
    for conn, _, raw in reader.messages(connections=[connection]):
        msg = typestore.deserialize_cdr(raw, conn.msgtype)
        return {str(f.name) for f in msg.fields}
    return set()


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
            have = ", ".join(f"{t} ({mt})" for t, mt in sorted(by_topic.items())) or "none"
            raise ReplayError(f"cannot tell the {what} topic: {configured!r} is not in the bag and it has "
                              f"{len(candidates)} {msgtype} topics; topics: {have}")
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
                    raise ReplayError(f"cannot tell the {what} topic: {getattr(topics, what)!r} is not in the "
                                      f"bag and {len(candidates)} PointCloud2 topics look like {what}: "
                                      f"{candidates}")
                found[what] = candidates[0]
    init = topics.init_bodies if topics.init_bodies and by_topic.get(topics.init_bodies) == "std_msgs/msg/String" \
        else None
    assert camera_info is not None
    return InputTopics(image, compressed, camera_info, found["points"], found["keypoints"], init)


class BagReader:
    """See the module docstring. Use as a context manager; iterate for `BagStep`s."""

    def __init__(self, path: str | Path, node: NodeConfig, log: Any = None) -> None:
        from rosbags.rosbag2 import Reader
        from rosbags.typesys import Stores, get_typestore

        self.path = Path(path)
        if not self.path.exists():
            raise ReplayError(f"{self.path} does not exist")
        self.node = node
        self.log = log
        self.typestore = get_typestore(Stores.ROS2_JAZZY)
        try:
            self.reader = Reader(self.path)
            self.reader.open()
        except Exception as e:  # noqa: BLE001 - rosbags raises several types for unreadable bags
            raise ReplayError(f"cannot read {self.path}: {e}") from e
        try:
            self.topics = resolve_topics(self.reader, self.typestore, node.topics)
        except Exception:
            self.reader.close()
            raise
        self.tf = TransformGraph()
        self.init_docs: list[tuple[int, str]] = []  # (stamp ns or -1 if unreadable, document)
        self._read_side_topics()
        self.truth_errors = 0  # ground-truth documents that could not be parsed

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
        for conn, _, raw in self.reader.messages(connections=conns) if conns else ():
            msg = self.typestore.deserialize_cdr(raw, conn.msgtype)
            if conn.topic in tf_topics and conn.msgtype == "tf2_msgs/msg/TFMessage":
                self.tf.add(msg, static=conn.topic == TF_STATIC_TOPIC)
            elif conn.topic == self.topics.init_bodies:
                self.init_docs.append((_document_stamp_ns(msg.data), msg.data))

    def synchronizer(self, on_set: Any) -> Synchronizer:
        sync = self.node.sync
        return make_synchronizer(len(self.topics.synchronized), sync.slop_s, sync.queue_size, on_set,
                                 sync.use_message_filters, self.log)

    def __iter__(self) -> Iterator[BagStep]:
        names = [name for name, _ in self.topics.synchronized]
        index = {topic: i for i, (_, topic) in enumerate(self.topics.synchronized)}
        completed: list[FrameMessages] = []

        def on_set(*msgs: Any) -> None:
            by = dict(zip(names, msgs, strict=True))
            completed.append(FrameMessages(by["camera_info"], by["points"], by["keypoints"], by.get("image"),
                                           self.topics.compressed))

        self.sync = self.synchronizer(on_set)
        for conn, timestamp, raw in self.reader.messages():
            step = BagStep(conn, timestamp, raw)
            i = index.get(conn.topic)
            if i is not None:
                self.sync.add(i, self.typestore.deserialize_cdr(raw, conn.msgtype))
                step.frames, completed[:] = list(completed), []
            elif conn.topic == GROUND_TRUTH_TOPIC and conn.msgtype == "std_msgs/msg/String":
                step.truth = self._truth(raw, conn.msgtype)
            yield step

    def _truth(self, raw: bytes, msgtype: str) -> TruthFrame | None:
        try:
            return parse_truth_document(self.typestore.deserialize_cdr(raw, msgtype).data)
        except (ValueError, KeyError, TypeError) as e:
            self.truth_errors += 1
            if self.log is not None:
                self.log.warning(f"{GROUND_TRUTH_TOPIC}: ignored a document: {e}")
            return None


def _document_stamp_ns(text: str) -> int:
    """The stamp of a bodies document (-1 when unreadable: the processor's parser says why later)."""
    try:
        stamp = json.loads(text)["stamp"]
        if isinstance(stamp, dict):
            return int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])
        return round(float(stamp) * 1e9)
    except (ValueError, KeyError, TypeError, RecursionError):
        return -1
