"""A recording's messages, read so that no bad byte stops the replay: every fault is counted and skipped.

`open_source(path)` opens a rosbag2 bag directory, a bare `.mcap` or a bare `.db3` and returns a source
with `connections`, `messages(connections)`, `message_count`, `start_time`, `end_time`, `faults`. The
replay reads a bag in several passes (topic detection, side topics, the replay itself); a fault is
counted once however many passes meet it.

MCAP (read with the `mcap` package's record classes, bounded by the file's size; rosbags' reader stops at
the first bad chunk and refuses a file without its summary):
- with a summary, chunks are read through the chunk index and merged in log-time order, as rosbags does;
- without one (a recording cut while it was written: "File end magic is invalid"), the file is read from
  the start up to the cut, chunk by chunk, in file order (log-time order within a chunk), and the
  truncation is reported with the number of messages recovered;
- a chunk whose CRC does not match its data, which does not decompress, declares more than
  MAX_RECORD_BYTES or holds malformed records is counted and skipped; the other chunks are read.
  Chunks written with CRC 0 (rosbags' writer) cannot be checked: their corruption goes unnoticed.

sqlite3: rows are listed from the timestamp index and read one by one, so that a corrupt page costs the
rows stored on it, reported with their message index, not the rest of the bag.
"""

from __future__ import annotations

import heapq
import io
import struct
import zlib
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from msg_adapters import clip

MAX_RECORD_BYTES = 1 << 30  # a record (chunk) or decompressed chunk larger than this is refused unread
MAX_METADATA_BYTES = 16 << 20  # metadata.yaml
FAULT_LINES = 20  # fault descriptions kept for the summary (the counts are complete)
MCAP_MAGIC = b"\x89MCAP0\r\n"

# Faults by reason: ReplaySummary.read_drops keys, /diagnostics `drop.message.<reason>`.
READ_CHUNK_CRC = "chunk_crc_mismatch"  # a chunk whose data does not match its CRC
READ_BAD_CHUNK = "bad_chunk"  # a chunk that does not decompress, is malformed or too large
READ_TRUNCATED = "truncated"  # the file ends mid-record (cut while recording)
READ_STORAGE_CORRUPT = "storage_corrupt"  # a sqlite3 row (or the rest of the table) cannot be read
READ_UNDECODABLE = "undecodable"  # CDR bytes that are not a message of the connection's type
READ_BAD_TRUTH = "bad_ground_truth"  # a /ground_truth/bodies document that cannot be used
READ_UNKNOWN_CHANNEL = "unknown_channel"  # an MCAP message on a channel the file never declared
READ_BAD_COMPRESSION = "bad_message_compression"  # a per-message zstd blob (compression_mode: message)


class SourceError(RuntimeError):
    """The file cannot be read at all (not a bag, unreadable); the message says why."""


@dataclass
class BagConnection:
    """One topic of the recording, with what the output needs to copy it as recorded."""

    id: int
    topic: str
    msgtype: str
    schema_encoding: str  # ros2msg, ros2idl or "" (none recorded)
    schema_data: str  # the recorded message definition ("" when none)
    metadata: dict[str, str] = field(default_factory=dict)  # MCAP channel metadata (offered_qos_profiles)
    message_encoding: str = "cdr"
    digest: str = ""  # type_description_hash when recorded


class ReadFaults:
    """Faults by reason; a fault with a key is counted once (passes over the bag repeat them)."""

    def __init__(self, log: Any = None) -> None:
        self.counts: Counter = Counter()
        self.lines: list[str] = []
        self.truncated: str | None = None  # what a cut file said, for the summary
        self.log = log
        self._seen: set[Any] = set()

    def add(self, reason: str, text: str, key: Any = None, n: int = 1) -> None:
        if key is not None:
            if key in self._seen:
                return
            self._seen.add(key)
        self.counts[reason] += n
        if len(self.lines) < FAULT_LINES:
            self.lines.append(f"{reason}: {text}")
            if self.log is not None:
                self.log.warning(f"{reason}: {text}")


# -- MCAP records -------------------------------------------------------------------------------------
class _Cut(Exception):
    """The records end before the data does (a cut file, or a corrupt record length)."""

    def __init__(self, offset: int) -> None:
        super().__init__(f"record at byte {offset} runs past the end")
        self.offset = offset


def _records(stream: Any, start: int, end: int) -> Iterator[tuple[int, int, bytes]]:
    """(offset, opcode, body) of each record between `start` and `end`; _Cut when one runs past `end`."""
    pos = start
    stream.seek(start)
    while pos < end:
        head = stream.read(9)
        if len(head) < 9:
            raise _Cut(pos)
        opcode, length = struct.unpack("<BQ", head)
        if length > min(end - pos - 9, MAX_RECORD_BYTES):
            raise _Cut(pos)
        body = stream.read(length)
        if len(body) < length:
            raise _Cut(pos)
        yield pos, opcode, body
        pos += 9 + length


def _parse(record_type: Any, body: bytes, *args: Any) -> Any:
    from mcap.data_stream import ReadDataStream

    return record_type.read(ReadDataStream(io.BytesIO(body)), *args)


class _ChunkFault(Exception):
    def __init__(self, reason: str, text: str) -> None:
        super().__init__(text)
        self.reason = reason


def bounded_zstd(data: bytes, limit: int) -> bytes:
    """zstd data decompressed, reading at most `limit` + 1 MiB (the frame's declared size is not trusted)."""
    import zstandard

    reader = zstandard.ZstdDecompressor().stream_reader(data)
    parts, total = [], 0
    while piece := reader.read(1 << 20):
        parts.append(piece)
        total += len(piece)
        if total > limit:
            break
    return b"".join(parts)


def _decompress(chunk: Any) -> bytes:
    """A chunk's records, checked against its declared size and CRC; _ChunkFault otherwise. The output
    is never larger than the declared size (a hostile zstd header cannot make it allocate more)."""
    size = int(chunk.uncompressed_size)
    if size > MAX_RECORD_BYTES:
        raise _ChunkFault(READ_BAD_CHUNK, f"declares {size} bytes uncompressed (limit {MAX_RECORD_BYTES})")
    try:
        if chunk.compression == "":
            data = bytes(chunk.data)
        elif chunk.compression == "zstd":
            data = bounded_zstd(chunk.data, size)
        elif chunk.compression == "lz4":
            import lz4.frame

            data = lz4.frame.LZ4FrameDecompressor().decompress(chunk.data, max_length=size + 1)
        else:
            raise _ChunkFault(READ_BAD_CHUNK, f"unknown compression {clip(chunk.compression, 40)!r}")
    except _ChunkFault:
        raise
    except Exception as e:  # noqa: BLE001 - zstd / lz4 raise their own types for corrupt frames
        raise _ChunkFault(READ_BAD_CHUNK, f"{chunk.compression} data does not decompress: {clip(e)}") from None
    if len(data) != size:
        raise _ChunkFault(READ_BAD_CHUNK, f"holds {len(data)}+ bytes, declares {size}")
    if chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        raise _ChunkFault(READ_CHUNK_CRC, "its data does not match its CRC")
    return data


@dataclass
class _Message:
    channel: int
    log_time: int
    data: bytes


def _chunk_records(body: bytes) -> tuple[list[Any], list[_Message], str | None]:
    """Schemas, channels and messages of a chunk record (a problem after some records: the ones before,
    and its text)."""
    from mcap.opcode import Opcode
    from mcap.records import Channel, Chunk, Message, Schema

    try:
        chunk = _parse(Chunk, body)
    except Exception as e:  # noqa: BLE001 - a malformed chunk header
        raise _ChunkFault(READ_BAD_CHUNK, f"malformed chunk header: {clip(e)}") from None
    data = _decompress(chunk)
    declared: list[Any] = []
    messages: list[_Message] = []
    try:
        for _, opcode, rec in _records(io.BytesIO(data), 0, len(data)):
            if opcode == Opcode.MESSAGE:
                m = _parse(Message, rec, len(rec))
                messages.append(_Message(m.channel_id, m.log_time, m.data))
            elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                declared.append(_parse(Schema if opcode == Opcode.SCHEMA else Channel, rec))
    except Exception as e:  # noqa: BLE001 - malformed records inside a chunk whose CRC was 0 or right
        return declared, messages, f"malformed records after {len(messages)} messages: {clip(e)}"
    return declared, messages, None


def _qos_text(value: Any) -> str:
    return value if isinstance(value, str) else ""


class _Registry:
    """Schemas and channels of one or more MCAP files -> BagConnections with ids unique over the files."""

    def __init__(self) -> None:
        self.connections: list[BagConnection] = []
        self._schemas: dict[tuple[int, int], Any] = {}
        self._channels: dict[tuple[int, int], BagConnection] = {}
        self._by_key: dict[tuple[str, str, str], BagConnection] = {}

    def declare(self, file: int, record: Any) -> None:
        from mcap.records import Schema

        if isinstance(record, Schema):
            self._schemas[(file, record.id)] = record
            return
        if (file, record.id) in self._channels:
            return
        schema = self._schemas.get((file, record.schema_id))
        msgtype = schema.name if schema is not None else ""
        key = (record.topic, msgtype, record.message_encoding)
        conn = self._by_key.get(key)
        if conn is None:
            data = schema.data.decode("utf-8", "replace") if schema is not None else ""
            conn = BagConnection(len(self.connections) + 1, record.topic, msgtype,
                                 schema.encoding if schema is not None else "", data, dict(record.metadata),
                                 record.message_encoding, record.metadata.get("topic_type_hash", ""))
            self.connections.append(conn)
            self._by_key[key] = conn
        self._channels[(file, record.id)] = conn

    def channel(self, file: int, channel_id: int) -> BagConnection | None:
        return self._channels.get((file, channel_id))


@dataclass
class _Summary:
    chunk_indexes: list[Any]
    message_count: int | None
    start_time: int | None
    end_time: int | None


class _McapFile:
    """One MCAP file: its summary when it has a readable one, else what a pass from the start finds."""

    def __init__(self, path: Path, number: int, registry: _Registry, faults: ReadFaults) -> None:
        self.path, self.number, self.registry, self.faults = path, number, registry, faults
        self.size = path.stat().st_size
        self.stream = open(path, "rb")  # noqa: SIM115 - closed by close()
        if self.stream.read(8) != MCAP_MAGIC:
            self.stream.close()
            raise SourceError(f"{path}: not an MCAP file (bad magic)")
        self.summary = self._read_summary()
        self.message_count, self.start_time, self.end_time = 0, None, None
        if self.summary is not None:
            self.message_count = self.summary.message_count or 0
            self.start_time, self.end_time = self.summary.start_time, self.summary.end_time
        else:
            self._scan()

    def close(self) -> None:
        self.stream.close()

    # -- structure ------------------------------------------------------------------------------------
    def _read_summary(self) -> _Summary | None:
        """The summary section (schemas, channels, chunk index, statistics); None if absent or unreadable."""
        from mcap.opcode import Opcode
        from mcap.records import ChunkIndex, Footer, Statistics

        if self.size < 8 + 9 + 20 + 8:
            return None
        self.stream.seek(self.size - 8 - 9 - 20)
        tail = self.stream.read(9 + 20 + 8)
        if tail[-8:] != MCAP_MAGIC or tail[0] != Opcode.FOOTER:
            return None
        try:
            footer = _parse(Footer, tail[9:29])
            if not 8 < footer.summary_start < self.size:
                return None
            chunks, stats = [], None
            for _, opcode, body in _records(self.stream, footer.summary_start, self.size - 8):
                if opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self.registry.declare(self.number, _parse(_record_class(opcode), body))
                elif opcode == Opcode.CHUNK_INDEX:
                    chunks.append(_parse(ChunkIndex, body))
                elif opcode == Opcode.STATISTICS:
                    stats = _parse(Statistics, body)
                elif opcode == Opcode.FOOTER:
                    break
        except Exception:  # noqa: BLE001 - a damaged summary: read the data section instead
            return None
        if not chunks:
            return None  # unchunked file: messages lie in the data section
        if stats is None:
            return _Summary(chunks, None, min(c.message_start_time for c in chunks),
                            max(c.message_end_time for c in chunks))
        return _Summary(chunks, stats.message_count, stats.message_start_time, stats.message_end_time)

    def _scan(self) -> None:
        """No summary: one pass over the data section for the channels, message count and time span."""
        for message in self._stream_messages(None, count_faults=False):
            self.message_count += 1
            t = message.log_time
            self.start_time = t if self.start_time is None else min(self.start_time, t)
            self.end_time = t if self.end_time is None else max(self.end_time, t)

    # -- messages -------------------------------------------------------------------------------------
    def messages(self, wanted: set[int] | None) -> Iterator[tuple[BagConnection, int, bytes]]:
        source = self._seeking_messages(wanted) if self.summary is not None else \
            self._stream_messages(wanted, count_faults=True)
        for message in source:
            conn = self.registry.channel(self.number, message.channel)
            if conn is None:
                self.faults.add(READ_UNKNOWN_CHANNEL, f"{self.path.name}: a message on undeclared channel "
                                f"{message.channel}", key=(self.path, "channel", message.channel))
            elif wanted is None or conn.id in wanted:
                yield conn, message.log_time, message.data

    def _chunk(self, offset: int, body: bytes, count_faults: bool) -> list[_Message]:
        """The messages of the chunk record at `offset`, in log-time order ([] when it is unusable)."""
        try:
            declared, messages, problem = _chunk_records(body)
        except _ChunkFault as e:
            if count_faults:
                self.faults.add(e.reason, f"{self.path.name}: chunk at byte {offset} skipped: {e}",
                                key=(self.path, offset))
            return []
        for record in declared:
            self.registry.declare(self.number, record)
        if problem is not None and count_faults:
            self.faults.add(READ_BAD_CHUNK, f"{self.path.name}: chunk at byte {offset}: {problem}",
                            key=(self.path, offset))
        return sorted(messages, key=lambda m: m.log_time)

    def _seeking_messages(self, wanted: set[int] | None) -> Iterator[_Message]:
        """Chunks through the index, merged by log time; each is read when the merge reaches its start."""
        assert self.summary is not None
        indexes = sorted(self.summary.chunk_indexes, key=lambda c: (c.message_start_time, c.chunk_start_offset))
        sources = [self._indexed_chunk(i, c) for i, c in enumerate(indexes) if self._may_hold(c, wanted)]
        for _, _, message in heapq.merge(*sources, key=lambda item: item[:2]):
            if message is not None:
                yield message

    def _may_hold(self, index: Any, wanted: set[int] | None) -> bool:
        if wanted is None or not index.message_index_offsets:
            return True
        return any((c := self.registry.channel(self.number, ch)) is not None and c.id in wanted
                   for ch in index.message_index_offsets)

    def _indexed_chunk(self, order: int, index: Any) -> Iterator[tuple[int, tuple[int, int], _Message | None]]:
        yield index.message_start_time, (order, -1), None  # read the chunk only when the merge gets here
        offset = index.chunk_start_offset
        try:
            _, opcode, body = next(_records(self.stream, offset, min(offset + index.chunk_length, self.size)))
        except (_Cut, StopIteration):
            self.faults.add(READ_BAD_CHUNK, f"{self.path.name}: chunk at byte {offset} runs past the end",
                            key=(self.path, offset))
            return
        from mcap.opcode import Opcode

        if opcode != Opcode.CHUNK:
            self.faults.add(READ_BAD_CHUNK, f"{self.path.name}: the index points at byte {offset}, which "
                            "holds no chunk", key=(self.path, offset))
            return
        for i, message in enumerate(self._chunk(offset, body, count_faults=True)):
            yield message.log_time, (order, i), message

    def _stream_messages(self, wanted: set[int] | None, count_faults: bool) -> Iterator[_Message]:
        """The data section from the start, up to the end of the file or the cut."""
        from mcap.opcode import Opcode
        from mcap.records import Message

        recovered = 0
        try:
            for offset, opcode, body in _records(self.stream, 8, self.size):
                if opcode == Opcode.CHUNK:
                    for message in self._chunk(offset, body, count_faults):
                        recovered += 1
                        yield message
                elif opcode == Opcode.MESSAGE:
                    m = _parse(Message, body, len(body))
                    recovered += 1
                    yield _Message(m.channel_id, m.log_time, m.data)
                elif opcode in (Opcode.SCHEMA, Opcode.CHANNEL):
                    self.registry.declare(self.number, _parse(_record_class(opcode), body))
                elif opcode in (Opcode.DATA_END, Opcode.FOOTER):
                    return
        except _Cut as cut:
            if count_faults and wanted is None:
                text = (f"{self.path.name} ends at byte {self.size} inside a record that starts at byte "
                        f"{cut.offset} (cut while recording?): {recovered} messages recovered")
                self.faults.add(READ_TRUNCATED, text, key=(self.path, "truncated"))
                self.faults.truncated = text
        except Exception as e:  # noqa: BLE001 - a malformed record outside any chunk
            if count_faults:
                self.faults.add(READ_BAD_CHUNK, f"{self.path.name}: unreadable after {recovered} messages: "
                                f"{clip(e)}", key=(self.path, "stream"))


def _record_class(opcode: int) -> Any:
    from mcap.opcode import Opcode
    from mcap.records import Channel, Schema

    return Schema if opcode == Opcode.SCHEMA else Channel


class McapSource:
    """One or more MCAP files (a split bag is read file after file)."""

    def __init__(self, paths: list[Path], log: Any = None, per_message_zstd: bool = False) -> None:
        self.faults = ReadFaults(log)
        self.per_message_zstd = per_message_zstd
        self._registry = _Registry()
        self._files: list[_McapFile] = []
        try:
            for i, path in enumerate(paths):
                self._files.append(_McapFile(path, i, self._registry, self.faults))
        except Exception:
            self.close()
            raise

    @property
    def connections(self) -> list[BagConnection]:
        return list(self._registry.connections)

    @property
    def message_count(self) -> int:
        return sum(f.message_count for f in self._files)

    @property
    def start_time(self) -> int:
        times = [f.start_time for f in self._files if f.start_time is not None]
        return min(times) if times else 0

    @property
    def end_time(self) -> int:
        times = [f.end_time for f in self._files if f.end_time is not None]
        return max(times) + 1 if times else 0

    def messages(self, connections: Any = None) -> Iterator[tuple[BagConnection, int, bytes]]:
        wanted = None if connections is None else {c.id for c in connections}
        for f in self._files:
            for conn, timestamp, data in f.messages(wanted):
                if self.per_message_zstd:
                    try:
                        data = bounded_zstd(data, MAX_RECORD_BYTES)
                    except Exception as e:  # noqa: BLE001 - a corrupt per-message blob
                        self.faults.add(READ_BAD_COMPRESSION, f"{f.path.name}: message at {timestamp}: "
                                        f"{clip(e)}", key=(f.path, conn.id, timestamp))
                        continue
                yield conn, timestamp, data

    def close(self) -> None:
        for f in self._files:
            f.close()


# -- sqlite3 ------------------------------------------------------------------------------------------
_LIST_BY_TIME = "SELECT id, timestamp FROM messages WHERE {topics}(timestamp, id) > (?, ?) " \
                "ORDER BY timestamp, id LIMIT 256"
_LIST_BY_ID = "SELECT id, timestamp FROM messages WHERE {topics}id > ? ORDER BY id LIMIT 256"


class SqliteSource:
    """A sqlite3 bag (directory or bare .db3): rosbags for its topics, rows read one at a time."""

    def __init__(self, path: Path, log: Any = None) -> None:
        from rosbags.rosbag2 import Reader

        self.faults = ReadFaults(log)
        self.reader = Reader(path)
        self.reader.open()
        storage = self.reader.storage
        self.files = [s.path for s in getattr(storage, "storages", [storage])]
        self.per_message_zstd = (self.reader.compression_mode or "") == "message"
        self.connections = [_from_rosbags(c) for c in self.reader.connections]

    @property
    def message_count(self) -> int:
        return int(self.reader.message_count)

    @property
    def start_time(self) -> int:
        return int(self.reader.start_time)

    @property
    def end_time(self) -> int:
        return int(self.reader.end_time)

    def close(self) -> None:
        self.reader.close()

    def messages(self, connections: Any = None) -> Iterator[tuple[BagConnection, int, bytes]]:
        wanted = None if connections is None else {c.id for c in connections}
        for path in self.files:
            yield from self._file_messages(path, wanted)

    def _file_messages(self, path: Path, wanted: set[int] | None) -> Iterator[tuple[BagConnection, int, bytes]]:
        import apsw

        db = apsw.Connection(f"file:{path}?immutable=1", flags=apsw.SQLITE_OPEN_READONLY | apsw.SQLITE_OPEN_URI)
        try:
            by_key = {(c.topic, c.msgtype): c for c in self.connections}
            topics = {tid: by_key.get((name, msgtype)) for tid, name, msgtype in
                      db.execute("SELECT id, name, type FROM topics")}
            ids = [tid for tid, c in topics.items() if c is not None and (wanted is None or c.id in wanted)]
            for index, (row, timestamp) in enumerate(self._rows(db, path, ids if wanted is not None else None)):
                message = self._row(db, path, index, row, timestamp, topics)
                if message is not None:
                    yield message
        finally:
            db.close()

    def _rows(self, db: Any, path: Path, topic_ids: list[int] | None) -> Iterator[tuple[int, int]]:
        """(row id, timestamp) in time order, from the timestamp index; in row order if the index fails."""
        import apsw

        topics = f"topic_id IN ({','.join(str(int(t)) for t in topic_ids)}) AND " if topic_ids is not None else ""
        last, n, by_time = (-(2**63), -1), 0, True
        while True:
            try:
                query = (_LIST_BY_TIME if by_time else _LIST_BY_ID).format(topics=topics)
                rows = db.execute(query, last if by_time else (last[1],)).fetchall()
            except apsw.Error as e:
                if by_time and n == 0:
                    by_time = False  # the index is damaged: the table's own order is the recording order
                    continue
                self.faults.add(READ_STORAGE_CORRUPT, f"{path.name}: cannot list the messages after message "
                                f"index {n}: {clip(e)}; the rest of the file is not read", key=(path, "list"))
                return
            if not rows:
                return
            for row in rows:
                n += 1
                yield row[0], row[1]
            last = (rows[-1][1], rows[-1][0])

    def _row(self, db: Any, path: Path, index: int, row: int, timestamp: int,
             topics: dict[int, BagConnection | None]) -> tuple[BagConnection, int, bytes] | None:
        import apsw

        try:
            found = db.execute("SELECT topic_id, data FROM messages WHERE id = ?", (row,)).fetchone()
        except apsw.Error as e:
            self.faults.add(READ_STORAGE_CORRUPT, f"{path.name}: message index {index} (row {row}, log time "
                            f"{timestamp}) unreadable: {clip(e)}", key=(path, row))
            return None
        conn = topics.get(found[0]) if found else None
        if conn is None:
            return None
        data = bytes(found[1])
        if self.per_message_zstd:
            try:
                data = bounded_zstd(data, MAX_RECORD_BYTES)
            except Exception as e:  # noqa: BLE001 - a corrupt per-message blob
                self.faults.add(READ_BAD_COMPRESSION, f"{path.name}: message index {index}: {clip(e)}",
                                key=(path, row))
                return None
        return conn, timestamp, data


def _from_rosbags(conn: Any) -> BagConnection:
    """A rosbags Connection as a BagConnection (its QoS serialized as rosbag2 version 9 writes it)."""
    from rosbags.interfaces import MessageDefinitionFormat

    encoding = {MessageDefinitionFormat.MSG: "ros2msg", MessageDefinitionFormat.IDL: "ros2idl"}.get(
        conn.msgdef.format, "")
    qos = getattr(conn.ext, "offered_qos_profiles", [])
    return BagConnection(conn.id, conn.topic, conn.msgtype, encoding, conn.msgdef.data or "",
                         {"offered_qos_profiles": dump_qos(qos)},
                         getattr(conn.ext, "serialization_format", "cdr"), conn.digest or "")


def dump_qos(qos: list[Any]) -> str:
    """QoS profiles as the YAML text rosbag2 (version 9) stores in MCAP channel metadata."""
    from rosbags.rosbag2.metadata import dump_qos_v9
    from ruamel.yaml import YAML

    stream = io.StringIO()
    yaml = YAML(typ="safe")
    yaml.default_flow_style = False
    yaml.dump(dump_qos_v9(list(qos)), stream)
    return stream.getvalue().strip()


# -- opening ------------------------------------------------------------------------------------------
def _bag_directory(path: Path) -> tuple[str, list[Path], str]:
    """(storage identifier, storage files, compression mode) of a rosbag2 directory, from metadata.yaml."""
    import yaml

    meta = path / "metadata.yaml"
    if not meta.is_file():
        raise SourceError(f"{path}: not a rosbag2 directory (no metadata.yaml)")
    if meta.stat().st_size > MAX_METADATA_BYTES:
        raise SourceError(f"{meta}: larger than {MAX_METADATA_BYTES >> 20} MiB, not a rosbag2 metadata file")
    try:
        info = yaml.safe_load(meta.read_text(encoding="utf-8"))["rosbag2_bagfile_information"]
        storage = str(info["storage_identifier"])
        files = [path / Path(str(name)).name for name in info["relative_file_paths"]]
        mode = str(info.get("compression_mode") or "").lower()
    except (yaml.YAMLError, UnicodeDecodeError, KeyError, TypeError) as e:
        raise SourceError(f"{meta}: not a rosbag2 metadata file ({clip(' '.join(str(e).split()))})") from None
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise SourceError(f"{path}: storage files listed in metadata.yaml are missing: {clip(missing)}")
    return storage, files, "" if mode == "none" else mode


def open_source(path: Path, log: Any = None) -> McapSource | SqliteSource:
    """The source for a bag directory, a .mcap or a .db3 file; SourceError when it cannot be read."""
    if not path.is_dir():
        return McapSource([path], log) if path.suffix == ".mcap" else SqliteSource(path, log)
    storage, files, mode = _bag_directory(path)
    if storage == "sqlite3":
        return SqliteSource(path, log)  # rosbags reads its metadata (and per-message compression)
    if storage != "mcap":
        raise SourceError(f"{path}: storage {clip(storage, 40)!r} is not supported (mcap, sqlite3)")
    if mode not in ("", "message"):
        raise SourceError(f"{path}: a {clip(mode, 20)}-compressed bag; decompress it first (ros2 bag "
                          "decompress)")
    return McapSource(files, log, per_message_zstd=mode == "message")
