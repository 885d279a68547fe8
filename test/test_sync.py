"""The built-in approximate-time synchronizer: matching, slop, bounded queues, drops, time going back."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import pytest

from smplify3d_ros.runtime.sync import ApproximateTimeSync, header_stamp_ns

MS = 1_000_000  # ns


@dataclass
class Msg:
    name: str
    t_ns: int


def make(n: int = 3, slop_s: float = 0.01, queue: int = 5):
    out: list[tuple] = []
    sync = ApproximateTimeSync(n, slop_s, queue, lambda *m: out.append(m), stamp_ns=lambda m: m.t_ns)
    return sync, out


def feed(sync, index: int, t_ms: float, name: str = "") -> Msg:
    msg = Msg(name or f"{index}@{t_ms}", round(t_ms * MS))
    sync.add(index, msg)
    return msg


def test_matches_within_slop_in_input_order():
    sync, out = make(3, slop_s=0.01)
    a = feed(sync, 0, 100.0)
    b = feed(sync, 2, 104.0)
    assert out == []
    c = feed(sync, 1, 96.0)
    assert out == [(a, c, b)]
    assert sync.stats.matched == 1
    assert sync.queue_lengths() == [0, 0, 0]


def test_rejects_sets_wider_than_slop():
    sync, out = make(2, slop_s=0.01)
    feed(sync, 0, 100.0)
    feed(sync, 1, 111.0)
    assert out == []
    assert sync.stats.matched == 0


def test_picks_nearest_and_drops_older_as_unmatched():
    # A 30 Hz camera against a 10 Hz LiDAR: the image nearest the scan is used, older ones can never match.
    sync, out = make(2, slop_s=0.02, queue=10)
    images = [feed(sync, 0, t) for t in (0.0, 33.0, 66.0, 100.0)]
    assert out == []
    scan = feed(sync, 1, 99.0)
    assert out == [(images[3], scan)]
    assert sync.stats.dropped_unmatched == 3
    assert sync.queue_lengths() == [0, 0]


def test_newer_messages_stay_queued_for_the_next_set():
    sync, out = make(2, slop_s=0.02, queue=10)
    feed(sync, 0, 0.0)
    i1 = feed(sync, 0, 100.0)
    s0 = feed(sync, 1, 1.0)  # completes (0, s0); i1 is newer and waits
    assert len(out) == 1 and out[0][1] is s0
    assert sync.queue_lengths() == [1, 0]
    s1 = feed(sync, 1, 101.0)
    assert out[1] == (i1, s1)
    assert sync.stats.dropped == 0


def test_queue_is_bounded_and_overflow_counted():
    sync, out = make(2, slop_s=0.001, queue=4)
    for k in range(50):
        feed(sync, 0, 10.0 * k)  # the other input never arrives
    assert sync.queue_lengths() == [4, 0]
    assert sync.stats.dropped_overflow == 46
    assert out == []


def test_time_going_back_resets_and_counts():
    sync, out = make(2, slop_s=0.01, queue=5)
    feed(sync, 0, 1000.0)
    feed(sync, 1, 2000.0)  # waits: no partner
    feed(sync, 0, 1500.0)
    assert sync.queue_lengths() == [2, 1]
    a = feed(sync, 0, 10.0)  # the clock restarted (bag loop): everything before is gone
    assert sync.stats.time_resets == 1
    assert sync.stats.dropped_reset == 3
    assert sync.queue_lengths() == [1, 0]
    b = feed(sync, 1, 12.0)  # going back on input 1 too: no second reset, last stamps were cleared
    assert sync.stats.time_resets == 1
    assert out == [(a, b)]


def test_duplicate_stamp_dropped():
    sync, out = make(2, slop_s=0.01)
    feed(sync, 0, 5.0)
    feed(sync, 0, 5.0)
    assert sync.stats.dropped_duplicate == 1
    assert sync.queue_lengths() == [1, 0]


def test_single_input_passes_through():
    sync, out = make(1, slop_s=0.01)
    msgs = [feed(sync, 0, t) for t in (1.0, 2.0, 3.0)]
    assert out == [(m,) for m in msgs]


def test_bad_arguments():
    with pytest.raises(ValueError):
        ApproximateTimeSync(0, 0.1, 5, print)
    with pytest.raises(ValueError):
        ApproximateTimeSync(2, -0.1, 5, print)
    with pytest.raises(ValueError):
        ApproximateTimeSync(2, 0.1, 0, print)
    sync, _ = make(2)
    with pytest.raises(IndexError):
        sync.add(2, Msg("x", 0))


def test_header_stamps_of_ros_messages():
    from msg_adapters import RosbagsFactory

    f = RosbagsFactory()
    msgs = [f.make("std_msgs/msg/Header", stamp=f.time(1_700_000_000.5 + 0.1 * k)) for k in range(3)]
    out = []
    sync = ApproximateTimeSync(2, 0.05, 5, lambda *m: out.append(m))
    for m in msgs:
        sync.add(0, type("M", (), {"header": m})())
    scan = type("M", (), {"header": f.make("std_msgs/msg/Header", stamp=f.time(1_700_000_000.71))})()
    sync.add(1, scan)
    assert len(out) == 1 and abs(header_stamp_ns(out[0][0]) - 1_700_000_000_700_000_000) < 1000


def test_threads_do_not_lose_sets():
    sync, out = make(2, slop_s=0.001, queue=1000)
    n = 500

    def run(index: int) -> None:
        for k in range(n):
            sync.add(index, Msg(f"{index}", k * 10 * MS))

    threads = [threading.Thread(target=run, args=(i,)) for i in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sync.stats.matched + sync.stats.dropped_unmatched // 2 >= n - 5
    assert len(out) == sync.stats.matched
    assert all(a.t_ns == b.t_ns for a, b in out)


@pytest.mark.parametrize("kind", ["builtin", "message_filters"])
def test_a_latest_input_joins_every_set_without_being_matched(kind):
    """The camera info (`sync.latest_camera_info`): each set takes its latest message, whatever its
    stamp; a late or missing one holds back no set; sets before its first message are dropped, counted."""
    import node_support

    from smplify3d_ros.runtime.sync import make_synchronizer

    @dataclass
    class Stamped:
        name: str
        header: object

    def msg(name: str, t_ms: float) -> Stamped:
        sec, ns = divmod(round(t_ms * MS), 1_000_000_000)
        return Stamped(name, type("H", (), {"stamp": type("T", (), {"sec": sec, "nanosec": ns})()})())

    out: list[tuple] = []
    with node_support.fake_modules("message_filters"):
        sync = make_synchronizer(3, 0.01, 5, lambda *m: out.append(tuple(x.name for x in m)),
                                 kind == "message_filters", latest=[1])
    assert type(sync).__name__ == ("MessageFiltersSync" if kind == "message_filters" else "ApproximateTimeSync")
    sync.add(0, msg("image@0", 0.0))
    sync.add(2, msg("points@0", 2.0))  # complete but no camera info yet: dropped, counted
    assert out == [] and sync.stats.dropped_no_latest == 1
    sync.add(1, msg("info@100", 100.0))
    sync.add(0, msg("image@100", 100.0))
    sync.add(2, msg("points@100", 101.0))
    assert out == [("image@100", "info@100", "points@100")]
    for t in (200.0, 300.0):  # the camera info of these frames comes late (or never): they are not held back
        sync.add(0, msg(f"image@{t:.0f}", t))
        sync.add(2, msg(f"points@{t:.0f}", t + 1.0))
    assert out[1:] == [("image@200", "info@100", "points@200"), ("image@300", "info@100", "points@300")]
    sync.add(1, msg("info@200", 200.0))  # a late info is the latest from now on, and completes nothing
    sync.add(0, msg("image@400", 400.0))
    sync.add(2, msg("points@400", 400.0))
    assert out[3:] == [("image@400", "info@200", "points@400")]
    assert sync.stats.matched == 4 and sync.queue_lengths() == [0, 0]
    assert sync.latest_inputs == frozenset({1})


def test_latest_inputs_must_leave_one_to_match():
    for latest in ([2], [0, 1], [-1]):
        with pytest.raises(ValueError, match="latest"):
            ApproximateTimeSync(2, 0.1, 5, print, latest=latest)
