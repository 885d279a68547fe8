"""The replay's output bag: the input topics copied as recorded, and every output topic added.

Written with the `mcap` package's writer: zstd chunks, each with its CRC (rosbags' MCAP writer writes CRC
0 and, by default, no compression), in the layout rosbag2's MCAP storage plugin writes and reads: profile
`ros2`, schemas `ros2msg` / `ros2idl` holding the message definitions, `cdr` channels whose metadata holds
`offered_qos_profiles` (and `topic_type_hash`), and the `rosbag2` metadata record with the bag's
`serialized_metadata`. rosbags, `ros2 bag` and Foxglove read it. `BagWriter` writes one file; where it
goes and under which name until it is complete is `output.Output`'s business.
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path
from typing import Any

import yaml

from smplify3d_ros.replay.sources import BagConnection, dump_qos

CHUNK_BYTES = 1 << 20  # uncompressed chunk size: a bad chunk costs at most about this much
ROSBAG2_VERSION = 9


class BagWriter:
    """An MCAP output bag written at `path`, to be called `name` once complete: input connections copied,
    output connections added on first use."""

    def __init__(self, path: Path, typestore: Any, name: str | None = None) -> None:
        from mcap.writer import CompressionType, Writer

        self.path = path
        self.name = name or path.name
        self.typestore = typestore
        self._file = open(path, "wb")  # noqa: SIM115 - closed by close() / abort()
        self._mcap = Writer(self._file, chunk_size=CHUNK_BYTES, compression=CompressionType.ZSTD,
                            enable_crcs=True)
        self._mcap.start(profile="ros2", library="smplify3d_ros replay (mcap)")
        self._schemas: dict[tuple[str, str, str], int] = {}
        self._topics: dict[int, dict[str, str]] = {}  # channel -> topic metadata for metadata.yaml
        self._copied: dict[int, int] = {}  # input connection id -> channel
        self._outputs: dict[str, int] = {}  # output topic -> channel
        self.not_copied: list[str] = []  # input topics without a message definition
        self._counts: Counter = Counter()
        self._start, self._end = 2**63 - 1, 0  # log time span

    # -- connections ----------------------------------------------------------------------------------
    def _channel(self, topic: str, msgtype: str, encoding: str, definition: str, metadata: dict[str, str],
                 message_encoding: str = "cdr", digest: str = "") -> int:
        key = (msgtype, encoding, definition)
        if key not in self._schemas:
            self._schemas[key] = self._mcap.register_schema(msgtype, encoding, definition.encode())
        metadata = dict(metadata)
        metadata.setdefault("offered_qos_profiles", dump_qos([]))
        if digest:
            metadata.setdefault("topic_type_hash", digest)
        channel = self._mcap.register_channel(topic, message_encoding, self._schemas[key], metadata)
        self._topics[channel] = {"name": topic, "type": msgtype, "serialization_format": message_encoding,
                                 "offered_qos_profiles": metadata["offered_qos_profiles"],
                                 "type_description_hash": digest}
        return channel

    def _definition(self, msgtype: str) -> tuple[str, str, str]:
        """(encoding, definition, RIHS01 hash) of a type the typestore knows."""
        definition, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
        return "ros2msg", definition, self.typestore.hash_rihs01(msgtype)

    def copy_connection(self, conn: BagConnection) -> None:
        """Copy an input topic with its recorded definition (else the typestore's, else not at all)."""
        encoding, definition, digest = conn.schema_encoding, conn.schema_data, conn.digest
        if not definition:
            if conn.msgtype not in self.typestore.types:
                self.not_copied.append(conn.topic)
                return
            encoding, definition, digest = self._definition(conn.msgtype)
        self._copied[conn.id] = self._channel(conn.topic, conn.msgtype, encoding, definition, conn.metadata,
                                              conn.message_encoding, digest)

    # -- messages -------------------------------------------------------------------------------------
    def _add(self, channel: int, timestamp: int, data: bytes) -> None:
        self._mcap.add_message(channel, log_time=timestamp, data=data, publish_time=timestamp,
                               sequence=self._counts[channel])
        self._counts[channel] += 1
        self._start, self._end = min(self._start, timestamp), max(self._end, timestamp)

    def write_raw(self, conn: BagConnection, timestamp: int, raw: bytes) -> None:
        channel = self._copied.get(conn.id)
        if channel is not None:
            self._add(channel, timestamp, raw)

    def write(self, topic: str, msgtype: str, msg: Any, timestamp: int) -> None:
        channel = self._outputs.get(topic)
        if channel is None:
            encoding, definition, digest = self._definition(msgtype)
            channel = self._outputs[topic] = self._channel(topic, msgtype, encoding, definition, {},
                                                           digest=digest)
        self._add(channel, timestamp, bytes(self.typestore.serialize_cdr(msg, msgtype)))

    # -- the end --------------------------------------------------------------------------------------
    def bag_information(self) -> dict[str, Any]:
        """`rosbag2_bagfile_information` of the bag, as rosbag2 (version 9) writes it."""
        count = sum(self._counts.values())
        start, end, file_name = (self._start, self._end, self.name) if count else (0, 0, self.name)
        return {
            "version": ROSBAG2_VERSION, "storage_identifier": "mcap", "relative_file_paths": [file_name],
            "duration": {"nanoseconds": end - start}, "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": count,
            "topics_with_message_count": [{"topic_metadata": meta, "message_count": self._counts[ch]}
                                          for ch, meta in self._topics.items()],
            "compression_format": "", "compression_mode": "",
            "files": [{"path": file_name, "starting_time": {"nanoseconds_since_epoch": start},
                       "duration": {"nanoseconds": end - start}, "message_count": count}],
            "custom_data": None, "ros_distro": "jazzy",
        }

    def close(self) -> dict[str, Any]:
        """Finish the file (summary, CRCs, the rosbag2 metadata record), flush it to disk; returns the
        bag information (for a bag directory's metadata.yaml)."""
        info = self.bag_information()
        self._mcap.add_metadata("rosbag2", {"serialized_metadata": yaml.safe_dump(info, sort_keys=False)})
        self._mcap.finish()
        self._file.flush()
        os.fsync(self._file.fileno())  # the rename that publishes the file must not precede its bytes
        self._file.close()
        return info

    def abort(self) -> None:
        """Close without finishing: the file is incomplete (and removed by the caller)."""
        self._file.close()


def write_metadata_yaml(directory: Path, info: dict[str, Any]) -> None:
    """A bag directory's metadata.yaml."""
    text = yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False)
    (directory / "metadata.yaml").write_text(text, encoding="utf-8")
