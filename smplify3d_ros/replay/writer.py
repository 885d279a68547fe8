"""The replay's output bag: the input topics copied as recorded, and every output topic added."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any


class BagWriter:
    """An MCAP output bag: input connections copied, output connections added on first use."""

    def __init__(self, output: Path, typestore: Any) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        self.output = output
        self.typestore = typestore
        self.single_file = output.suffix == ".mcap"
        if output.exists():
            if output.is_dir():
                shutil.rmtree(output)
            else:
                output.unlink()
        output.parent.mkdir(parents=True, exist_ok=True)
        if self.single_file:  # rosbags writes a directory; keep its .mcap file only
            self._tmp = Path(tempfile.mkdtemp(prefix=".replay-", dir=output.parent))
            self.bag_dir = self._tmp / output.stem
        else:
            self.bag_dir = output
        self.writer = Writer(self.bag_dir, version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self._copied: dict[int, Any] = {}
        self._outputs: dict[str, Any] = {}

    def copy_connection(self, conn: Any) -> None:
        kwargs: dict[str, Any] = {"offered_qos_profiles": getattr(conn.ext, "offered_qos_profiles", ())}
        if conn.msgtype in self.typestore.types:
            kwargs["typestore"] = self.typestore
        elif conn.msgdef and conn.msgdef.data:
            kwargs.update(msgdef=conn.msgdef.data, rihs01=conn.digest)
        else:
            return  # a type rosbags cannot describe: not copied
        self._copied[conn.id] = self.writer.add_connection(conn.topic, conn.msgtype, **kwargs)

    def write_raw(self, conn: Any, timestamp: int, raw: bytes) -> None:
        out = self._copied.get(conn.id)
        if out is not None:
            self.writer.write(out, timestamp, raw)

    def write(self, topic: str, msgtype: str, msg: Any, timestamp: int) -> None:
        conn = self._outputs.get(topic)
        if conn is None:
            conn = self._outputs[topic] = self.writer.add_connection(topic, msgtype, typestore=self.typestore)
        self.writer.write(conn, timestamp, self.typestore.serialize_cdr(msg, msgtype))

    def close(self) -> None:
        self.writer.close()
        if self.single_file:
            shutil.move(str(self.bag_dir / f"{self.bag_dir.name}.mcap"), self.output)
            shutil.rmtree(self._tmp, ignore_errors=True)
