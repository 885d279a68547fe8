"""A stand-in for ROS 2's `message_filters` Python package (not on the Python package index), with the
same approximate-time policy, so that tests run the node and the replay with `sync.use_message_filters`.

Only what `smplify3d_ros.runtime.sync.MessageFiltersSync` uses: `SimpleFilter` and
`ApproximateTimeSynchronizer(fs, queue_size, slop)`. The policy, as in ROS 2 Jazzy's implementation:
each input keeps a dict of messages by stamp (the oldest evicted beyond `queue_size`); when a message
arrives, each other input's stamps within `slop` of it are candidates, nearest first; the first
combination whose spread is below `slop` is emitted and removed from the queues.
"""

from __future__ import annotations

import itertools
import threading

FAKE = True  # tests check they run against this stand-in, not a real install


def _stamp_ns(msg) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


class SimpleFilter:
    def __init__(self) -> None:
        self.callbacks: dict[int, tuple] = {}

    def registerCallback(self, callback, *args) -> int:  # noqa: N802 - message_filters' API
        conn = len(self.callbacks)
        self.callbacks[conn] = (callback, args)
        return conn

    def signalMessage(self, *msg) -> None:  # noqa: N802 - message_filters' API
        for callback, args in list(self.callbacks.values()):
            callback(*(msg + args))


class ApproximateTimeSynchronizer(SimpleFilter):
    def __init__(self, fs, queue_size: int, slop: float, allow_headerless: bool = False) -> None:
        super().__init__()
        self.queue_size = queue_size
        self.slop_ns = round(slop * 1e9)
        self.lock = threading.Lock()
        self.queues: list[dict[int, object]] = [{} for _ in fs]
        for index, f in enumerate(fs):
            f.registerCallback(self.add, self.queues[index], index)

    def add(self, msg, my_queue: dict, my_index: int) -> None:
        stamp = _stamp_ns(msg)
        with self.lock:
            my_queue[stamp] = msg
            while len(my_queue) > self.queue_size:
                del my_queue[min(my_queue)]
            others = [i for i in range(len(self.queues)) if i != my_index]
            candidates = []
            for i in others:
                near = sorted((s for s in self.queues[i] if abs(s - stamp) <= self.slop_ns),
                              key=lambda s: abs(s - stamp))
                if not near:
                    return
                candidates.append(near)
            for combo in itertools.product(*candidates):
                stamps = dict(zip(others, combo, strict=True))
                stamps[my_index] = stamp
                if max(stamps.values()) - min(stamps.values()) < self.slop_ns:
                    msgs = [self.queues[i][stamps[i]] for i in range(len(self.queues))]
                    for i in range(len(self.queues)):
                        del self.queues[i][stamps[i]]
                    self.signalMessage(*msgs)
                    return
