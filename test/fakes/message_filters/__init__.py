"""A small stand-in for ROS 2's `message_filters` (not installable here): `SimpleFilter` and the
`ApproximateTimeSynchronizer` policy of message_filters' Python implementation (queues keyed by stamp, the
smallest stamp evicted beyond `queue_size`, a set emitted when one message per input lies within `slop`),
so that `sync.use_message_filters: true` can be exercised. Tests put this directory on sys.path."""

from __future__ import annotations

import itertools
import threading
from typing import Any

FAKE = True


class SimpleFilter:
    def __init__(self) -> None:
        self.callbacks: dict[int, tuple[Any, tuple]] = {}

    def registerCallback(self, cb: Any, *args: Any) -> int:  # noqa: N802 - message_filters' name
        conn = len(self.callbacks)
        self.callbacks[conn] = (cb, args)
        return conn

    def signalMessage(self, *msg: Any) -> None:  # noqa: N802
        for cb, args in list(self.callbacks.values()):
            cb(*(msg + args))


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


class ApproximateTimeSynchronizer(SimpleFilter):
    def __init__(self, fs: list[SimpleFilter], queue_size: int, slop: float) -> None:
        super().__init__()
        self.queue_size = queue_size
        self.slop_ns = round(slop * 1e9)
        self.lock = threading.Lock()
        self.queues: list[dict[int, Any]] = [{} for _ in fs]
        for i, (f, q) in enumerate(zip(fs, self.queues, strict=True)):
            f.registerCallback(self.add, q, i)

    def add(self, msg: Any, my_queue: dict[int, Any], my_index: int) -> None:
        stamp = _stamp_ns(msg)
        with self.lock:
            my_queue[stamp] = msg
            while len(my_queue) > self.queue_size:
                del my_queue[min(my_queue)]
            others = [q for i, q in enumerate(self.queues) if i != my_index]
            candidates = []
            for q in others:
                near = sorted((s for s in q if abs(s - stamp) <= self.slop_ns), key=lambda s: abs(s - stamp))
                if not near:
                    return
                candidates.append(near)
            for combo in itertools.product(*candidates):
                stamps = list(combo)
                stamps.insert(my_index, stamp)
                if max(stamps) - min(stamps) < self.slop_ns:
                    msgs = [q[s] for q, s in zip(self.queues, stamps, strict=True)]
                    for q, s in zip(self.queues, stamps, strict=True):
                        del q[s]
                    break
            else:
                return
        self.signalMessage(*msgs)
