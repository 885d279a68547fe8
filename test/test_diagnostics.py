"""The /diagnostics building blocks without ROS: input rates and silence, per-input levels, the fitting
status's WARN and ERROR rules, latency percentiles, and messages of both runtimes."""

from __future__ import annotations

import pytest

from msg_adapters import RosbagsFactory
from smplify3d_ros.runtime.stats import (
    DiagnosticsReporter,
    InputCheck,
    InputMonitor,
    LatencyStats,
    LogLimiter,
    ProcessorStats,
    input_level,
)


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_rate_over_the_window_and_silence():
    clock = Clock()
    monitor = InputMonitor(["image", "points"], window_s=2.0, clock=clock)
    for _ in range(30):  # 10 Hz for 3 s
        clock.t += 0.1
        monitor.arrived("image")
    assert monitor.rate_hz("image", clock.t) == pytest.approx(10.0, abs=0.6)
    assert monitor.received["image"] == 30
    assert monitor.silent_s("image", clock.t) == pytest.approx(0.0)
    assert monitor.silent_s("points", clock.t) == pytest.approx(3.0), "never received: since start"
    clock.t += 1.5
    assert monitor.silent_s("image", clock.t) == pytest.approx(1.5)
    assert monitor.rate_hz("image", clock.t) == pytest.approx(2.5, abs=0.6), "5 of the window's messages left"
    assert len(monitor._times["image"]) <= 21, "bounded by the window"


def test_input_level_warns_on_silence_and_on_a_rate_off_the_expected_one():
    clock = Clock()
    monitor = InputMonitor(["points"], window_s=5.0, clock=clock)
    check = InputCheck("/velodyne_points", expected_hz=10.0, rate_tolerance=0.5, stale_after_s=1.0)
    assert input_level(monitor, "points", check, clock.t)[0] == "OK", "not stale yet after start"
    clock.t += 1.2
    level, message, values = input_level(monitor, "points", check, clock.t)
    assert level == "WARN" and message.startswith("no message yet for 1.2 s") and values["received"] == 0
    for _ in range(50):
        clock.t += 0.1
        monitor.arrived("points")
    assert input_level(monitor, "points", check, clock.t)[:2] == ("OK", "10.0 Hz")
    for _ in range(10):
        clock.t += 0.5  # 2 Hz
        monitor.arrived("points")
    level, message, _ = input_level(monitor, "points", check, clock.t)
    assert level == "WARN" and "outside [5.0, 15.0] Hz" in message
    unchecked = InputCheck("/keypoints", expected_hz=0.0, rate_tolerance=0.5, stale_after_s=1.0)
    assert input_level(monitor, "points", unchecked, clock.t)[0] == "OK", "expected 0: rate not checked"


@pytest.mark.parametrize("key", ["queue.dropped_stale", "sync.dropped_unmatched", "drop.bad_points",
                                 "bad_messages.image", "fits_flagged.diverged"])
def test_fitting_status_warns_when_frames_or_messages_were_lost_since_the_last_report(key):
    reporter = DiagnosticsReporter("smplify3d: fitting")
    assert reporter.fitting_level({key: 0}) == ("OK", "fitting")
    level, text = reporter.fitting_level({key: 3})
    assert level == "WARN" and text.startswith("3 ")
    assert reporter.fitting_level({key: 3})[0] == "OK", "only growth since the last report counts"


def test_fitting_status_errors_on_failed_frames_and_when_no_frame_can_be_built():
    reporter = DiagnosticsReporter("smplify3d: fitting")
    assert reporter.fitting_level({"drop.fit_error": 1, "queue.dropped_stale": 5})[0] == "ERROR"
    level, text = reporter.fitting_level({"drop.fit_error": 1}, no_frame="points silent for 1.3 s")
    assert (level, text) == ("ERROR", "no frame can be built: points silent for 1.3 s")


def test_latency_percentiles_over_the_window():
    stats = ProcessorStats(latency_window=10)
    for ms in range(1, 101):
        stats.record("fit", ms * 1e-3)
    values = stats.values()
    assert values["latency_ms.fit.max"] == pytest.approx(100.0)
    assert values["latency_ms.fit.p50"] == pytest.approx(95.5)
    assert values["latency_ms.fit.p90"] == pytest.approx(99.1)
    assert values["latency_ms.fit.p99"] == pytest.approx(99.91)
    assert LatencyStats(5).percentile(50) != LatencyStats(5).percentile(50), "nan without samples"


def test_message_has_one_status_per_input_in_both_runtimes():
    reporter = DiagnosticsReporter("smplify3d: fitting", "smplify3d_ros")
    inputs = [("image", "WARN", "no message for 1.5 s", {"received": 3}), ("points", "OK", "10.0 Hz", {})]
    msg = reporter.message(1_700_000_000_000_000_000, {"frames_in": 1}, RosbagsFactory(), inputs=inputs,
                           no_frame="image silent for 1.5 s")
    names = [s.name for s in msg.status]
    assert names == ["smplify3d: fitting", "smplify3d: input image", "smplify3d: input points"]
    assert [int(s.level) for s in msg.status] == [2, 1, 0]
    assert msg.status[1].values[0].key == "received" and msg.status[1].values[0].value == "3"
    assert {s.hardware_id for s in msg.status} == {"smplify3d_ros"}


def test_log_limiter_holds_repeats_back_and_counts_them():
    lines: list[str] = []

    class Log:
        def warning(self, text: str) -> None:
            lines.append(text)

    clock = Clock()
    limiter = LogLimiter(Log(), period_s=5.0, clock=clock)
    for _ in range(4):
        limiter.warning("bad.image", "bad image")
    clock.t += 6.0
    limiter.warning("bad.image", "bad image")
    limiter.warning("bad.points", "bad cloud")
    assert lines == ["bad image", "bad image (3 more since the last report)", "bad cloud"]
