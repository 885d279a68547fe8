"""The input synchronizer both drivers use: N inputs, a slop, bounded queues, every drop counted.

`ApproximateTimeSync` is the package's own (the default of the node and the replay). The policy: when a
message arrives, each other input's message nearest to it in time is taken; if all of them lie within
`slop` of each other the set is emitted. Messages older than an emitted set can never be part of a later
one (stamps only grow on each input), so they are dropped as unmatched. A stamp that goes back on an
input (a bag restarted, simulated time reset) clears every queue: the counters say how often.

Inputs named in `latest` (the node's camera info, `sync.latest_camera_info`) are not matched: each set
takes the latest message such an input has delivered. A camera's intrinsics do not change from frame to
frame, and a small message sent right after a large image is the one a loaded DDS reader receives late
(its reliable repair comes in a burst up to a second later, measured over loopback): matched, it held
back every frame waiting for it. A set completed before a `latest` input's first message is dropped and
counted (`dropped_no_latest`).

`MessageFiltersSync` puts ROS's `message_filters.ApproximateTimeSynchronizer` behind the same interface
(`sync.use_message_filters: true`, when message_filters is installed): the same `add`, the same
duplicate and time-reset handling, the same `SyncStats`. message_filters never drops a message that an
emitted set made too old; it keeps it until its queue overflows, so there such messages are counted as
`dropped_overflow`, not `dropped_unmatched`.

Thread safe: `add` may be called from several threads; the callback runs outside the lock.
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any, Protocol


def header_stamp_ns(msg: Any) -> int:
    """Integer nanoseconds of `msg.header.stamp` (rclpy and rosbags messages alike)."""
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


@dataclass
class SyncStats:
    """Counters since construction (or `reset_stats`)."""

    received: list[int] = field(default_factory=list)  # messages per input
    matched: int = 0  # sets emitted
    dropped_overflow: int = 0  # messages pushed out of a full queue before any match
    dropped_unmatched: int = 0  # messages older than an emitted set: they can never match
    dropped_duplicate: int = 0  # a second message with the same stamp on one input
    dropped_reset: int = 0  # messages cleared by a time reset
    dropped_no_latest: int = 0  # sets complete before a `latest` input (camera info) had any message
    time_resets: int = 0  # stamps that went back on an input

    @property
    def dropped(self) -> int:
        return self.dropped_overflow + self.dropped_unmatched + self.dropped_duplicate + self.dropped_reset


class _Synchronizer:
    """What both synchronizers share: `add`, the per-input stamp checks (a repeated stamp is a duplicate,
    a stamp going back a time reset that clears every queue) and the counters; subclasses match."""

    def __init__(
        self,
        n_inputs: int,
        slop_s: float,
        queue_size: int,
        callback: Callable[..., None],
        stamp_ns: Callable[[Any], int] = header_stamp_ns,
        latest: Collection[int] = (),
    ) -> None:
        if n_inputs < 1:
            raise ValueError(f"n_inputs must be >= 1, got {n_inputs}")
        if any(not 0 <= i < n_inputs for i in latest) or len(set(latest)) >= n_inputs:
            raise ValueError(f"latest must name some but not all of inputs 0..{n_inputs - 1}, got {list(latest)}")
        if slop_s < 0:
            raise ValueError(f"slop_s must be >= 0, got {slop_s}")
        if queue_size < 1:
            raise ValueError(f"queue_size must be >= 1, got {queue_size}")
        self.n_inputs = n_inputs
        self.slop_s = slop_s
        self.slop_ns = round(slop_s * 1e9)
        self.queue_size = queue_size
        self.callback = callback
        self.stamp_ns = stamp_ns
        self.latest_inputs = frozenset(latest)
        self._slots = [i for i in range(n_inputs) if i not in self.latest_inputs]  # matched inputs, in order
        self.n_matched = len(self._slots)
        self._latest: dict[int, Any] = {}  # `latest` input -> its last message
        self._last: list[int | None] = [None] * n_inputs
        self._lock = threading.RLock()
        self.stats = SyncStats(received=[0] * n_inputs)

    def add(self, index: int, msg: Any, stamp_ns: int | None = None) -> bool:
        """Offer one message of input `index`; returns True when it completed a set (callback called)."""
        if not 0 <= index < self.n_inputs:
            raise IndexError(f"input {index} out of range (0..{self.n_inputs - 1})")
        stamp = self.stamp_ns(msg) if stamp_ns is None else int(stamp_ns)
        with self._lock:
            matched = self._add_locked(index, msg, stamp)
            matched = None if matched is None else self._with_latest(matched)
            self.stats.matched += matched is not None
        if matched is not None:
            self.callback(*matched)
            return True
        return False

    def _with_latest(self, matched: list[Any]) -> list[Any] | None:
        """The matched inputs' set with each `latest` input's last message put in its place (input order);
        None, counted, while a `latest` input has had none."""
        if not self.latest_inputs:
            return matched
        if len(self._latest) < len(self.latest_inputs):
            self.stats.dropped_no_latest += 1
            return None
        by_input = dict(zip(self._slots, matched, strict=True)) | self._latest
        return [by_input[i] for i in range(self.n_inputs)]

    def reset(self) -> None:
        """Forget every queued message (counted as reset drops) and the last stamps."""
        with self._lock:
            self.stats.dropped_reset += sum(self.queue_lengths())
            self._clear()
            self._last = [None] * self.n_inputs

    def _add_locked(self, index: int, msg: Any, stamp: int) -> list[Any] | None:
        self.stats.received[index] += 1
        last = self._last[index]
        if last is not None and stamp < last:
            self.stats.time_resets += 1
            self.reset()
        elif last is not None and stamp == last:
            self.stats.dropped_duplicate += 1
            return None
        self._last[index] = stamp
        if index in self.latest_inputs:
            self._latest[index] = msg
            return None
        return self._match(self._slots.index(index), msg, stamp)

    # -- the policy ----------------------------------------------------------------------------------
    def queue_lengths(self) -> list[int]:
        raise NotImplementedError

    def _clear(self) -> None:
        raise NotImplementedError

    def _match(self, index: int, msg: Any, stamp: int) -> list[Any] | None:
        """Queue the message of matched input `index` (its position among the matched inputs); the set it
        completes, one message per matched input in their order, or None."""
        raise NotImplementedError


class ApproximateTimeSync(_Synchronizer):
    """Match messages of `n_inputs` streams whose stamps lie within `slop_s` of each other (the package's
    own policy, module docstring). `callback(*messages)` receives one message per input, in input order."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._queues: list[deque[tuple[int, Any]]] = [deque() for _ in range(self.n_matched)]

    def queue_lengths(self) -> list[int]:
        with self._lock:
            return [len(q) for q in self._queues]

    def _clear(self) -> None:
        for q in self._queues:
            q.clear()

    def _match(self, index: int, msg: Any, stamp: int) -> list[Any] | None:
        queue = self._queues[index]
        queue.append((stamp, msg))
        if len(queue) > self.queue_size:
            queue.popleft()
            self.stats.dropped_overflow += 1
        picks = self._nearest(index, stamp)
        if picks is None:
            return None
        stamps = [self._queues[i][k][0] for i, k in enumerate(picks)]
        if max(stamps) - min(stamps) > self.slop_ns:
            return None
        out = []
        for i, k in enumerate(picks):
            q = self._queues[i]
            for _ in range(k):  # older than the emitted set: can never match again
                q.popleft()
                self.stats.dropped_unmatched += 1
            out.append(q.popleft()[1])
        return out

    def _nearest(self, index: int, stamp: int) -> list[int] | None:
        """Per input, the queue position of the message nearest to `stamp` (None if a queue is empty)."""
        picks = []
        for i, q in enumerate(self._queues):
            if not q:
                return None
            if i == index:
                picks.append(len(q) - 1)
                continue
            picks.append(min(range(len(q)), key=lambda k, q=q: abs(q[k][0] - stamp)))
        return picks


class Synchronizer(Protocol):
    stats: SyncStats
    latest_inputs: frozenset[int]

    def add(self, index: int, msg: Any, stamp_ns: int | None = None) -> bool: ...

    def reset(self) -> None: ...

    def queue_lengths(self) -> list[int]: ...


class MessageFiltersSync(_Synchronizer):
    """message_filters' approximate-time synchronizer with `ApproximateTimeSync`'s interface (module
    docstring). Each input is a `message_filters.SimpleFilter` fed by `add`; the synchronizer's queues
    (a dict of stamps per input, the smallest evicted beyond `queue_size`) are mirrored to count drops."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        import message_filters

        super().__init__(*args, **kwargs)
        self._mf = message_filters
        self._emitted: list[Any] | None = None
        self._build()

    def _build(self) -> None:
        self._filters = [self._mf.SimpleFilter() for _ in range(self.n_matched)]
        self._sync = self._mf.ApproximateTimeSynchronizer(self._filters, self.queue_size, self.slop_s)
        self._sync.registerCallback(self._on_set)
        self._queued: list[set[int]] = [set() for _ in range(self.n_matched)]

    def _on_set(self, *msgs: Any) -> None:
        self._emitted = list(msgs)

    def queue_lengths(self) -> list[int]:
        with self._lock:
            return [len(q) for q in self._queued]

    def _clear(self) -> None:
        self._build()  # a new message_filters synchronizer: its queues cannot be cleared from outside

    def _match(self, index: int, msg: Any, stamp: int) -> list[Any] | None:
        queue = self._queued[index]
        queue.add(stamp)
        if len(queue) > self.queue_size:
            queue.discard(min(queue))
            self.stats.dropped_overflow += 1
        self._emitted = None
        self._filters[index].signalMessage(msg)
        matched, self._emitted = self._emitted, None
        for i, m in enumerate(matched or ()):
            self._queued[i].discard(self.stamp_ns(m))
        return matched


def make_synchronizer(
    n_inputs: int, slop_s: float, queue_size: int, callback: Callable[..., None], use_message_filters: bool,
    log: Any = None, latest: Collection[int] = (),
) -> Synchronizer:
    """The built-in synchronizer, or message_filters' when asked for and importable (else the built-in,
    with a log line saying so). `latest`: inputs whose latest message joins each set (module docstring)."""
    if use_message_filters:
        try:
            return MessageFiltersSync(n_inputs, slop_s, queue_size, callback, latest=latest)
        except ImportError:
            if log is not None:
                log.info("sync.use_message_filters: message_filters is not installed; using the built-in "
                         "synchronizer")
    return ApproximateTimeSync(n_inputs, slop_s, queue_size, callback, latest=latest)


def sync_values(sync: Synchronizer) -> dict[str, int]:
    """The synchronizer's counters as /diagnostics values (`sync.*`), the same for either implementation."""
    s = sync.stats
    return {
        "sync.matched": s.matched, "sync.dropped_unmatched": s.dropped_unmatched,
        "sync.dropped_overflow": s.dropped_overflow, "sync.dropped_duplicate": s.dropped_duplicate,
        "sync.dropped_reset": s.dropped_reset, "sync.dropped_no_latest": s.dropped_no_latest,
        "sync.time_resets": s.time_resets,
    }


# -- hri_msgs/Skeleton2D keypoint input ----------------------------------------------------------------------
@dataclass
class SkeletonSet:
    """The Skeleton2D messages of one image stamp: what one keypoint message would hold."""

    stamp_ns: int
    header: Any  # the tracked list's header (stamp and frame of the image)
    skeletons: dict[str, Any] = field(default_factory=dict)  # body id -> hri_msgs/Skeleton2D
    missing: list[str] = field(default_factory=list)  # listed bodies whose skeleton did not arrive


class SkeletonAssembler:
    """REP-155 publishes one Skeleton2D per body (`<ns>/<id>/skeleton2d`) and the list of tracked bodies
    (`<ns>/tracked`, hri_msgs/IdsList); this joins them into one set per image stamp, as the keypoint input
    needs. A stamp's set is complete once its tracked list and every listed body's skeleton of that stamp
    have arrived; a tracked list of a later stamp completes the older sets with what they have (a missing
    skeleton is left out and counted). At most `max_pending` stamps wait; skeletons of unlisted stamps are
    kept as long. `on_set(SkeletonSet)` is called outside the lock, oldest stamp first."""

    def __init__(self, on_set: Callable[[SkeletonSet], None], max_pending: int = 10,
                 stamp_ns: Callable[[Any], int] = header_stamp_ns) -> None:
        self.on_set = on_set
        self.max_pending = max_pending
        self.stamp_ns = stamp_ns
        self._tracked: dict[int, tuple[Any, list[str]]] = {}  # stamp -> (header, ids)
        self._skeletons: dict[int, dict[str, Any]] = {}  # stamp -> body id -> skeleton
        self._lock = threading.Lock()
        self.sets = 0
        self.missing = 0  # listed skeletons that never arrived for their stamp
        self.unlisted = 0  # skeletons dropped without a tracked list of their stamp

    def add_tracked(self, msg: Any) -> None:
        stamp = self.stamp_ns(msg)
        with self._lock:
            self._tracked[stamp] = (msg.header, [str(i) for i in msg.ids])
            ready = self._ready_locked(flush_before=stamp)
        for s in ready:
            self.on_set(s)

    def add_skeleton(self, body_id: str, msg: Any) -> None:
        stamp = self.stamp_ns(msg)
        with self._lock:
            self._skeletons.setdefault(stamp, {})[body_id] = msg
            ready = self._ready_locked(flush_before=None)
        for s in ready:
            self.on_set(s)

    def _ready_locked(self, flush_before: int | None) -> list[SkeletonSet]:
        out = []
        for stamp in sorted(self._tracked):
            header, ids = self._tracked[stamp]
            got = self._skeletons.get(stamp, {})
            complete = all(i in got for i in ids)
            if not complete and (flush_before is None or stamp >= flush_before):
                continue
            del self._tracked[stamp]
            got = self._skeletons.pop(stamp, {})
            s = SkeletonSet(stamp, header, {i: got[i] for i in ids if i in got}, [i for i in ids if i not in got])
            self.missing += len(s.missing)
            self.sets += 1
            out.append(s)
        self._bound_locked()
        return out

    def _bound_locked(self) -> None:
        while len(self._tracked) > self.max_pending:
            del self._tracked[min(self._tracked)]
        while len(self._skeletons) > self.max_pending:
            self.unlisted += len(self._skeletons.pop(min(self._skeletons)))
