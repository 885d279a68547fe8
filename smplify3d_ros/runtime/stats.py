"""Counters and latencies of the frame processor, input monitoring, and the /diagnostics messages.

/diagnostics follows diagnostic_updater's layout: one DiagnosticStatus per task, named `<node>: <task>`,
with a level and one line saying why. `fitting` summarizes the frame path (ERROR when handling a frame
raised or when no frame can be built, WARN when frames were dropped); `input <name>` is one status per
subscribed input (WARN when it is silent or its rate is off the expected one), like diagnostic_updater's
FrequencyStatus and TimeStampStatus.
"""

from __future__ import annotations

import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from msg_adapters import MessageFactory, diagnostics_array
from msg_adapters.diagnostics import diagnostic_status, diagnostics_message
from smplify3d_ros.runtime.messages import DROP_FIT_ERROR, DROP_INTERNAL

STAGES = ("convert", "extract", "fit", "outputs", "total")
PERCENTILES = (50, 90, 99)


class LatencyStats:
    """Per-stage latency: the last `window` values (mean, percentiles, max) and totals since start."""

    def __init__(self, window: int = 100) -> None:
        self.recent: deque[float] = deque(maxlen=window)
        self.count = 0
        self.total = 0.0

    def add(self, seconds: float) -> None:
        self.recent.append(seconds)
        self.count += 1
        self.total += seconds

    @property
    def mean(self) -> float:
        return float(np.mean(self.recent)) if self.recent else float("nan")

    @property
    def max(self) -> float:
        return float(np.max(self.recent)) if self.recent else float("nan")

    @property
    def overall_mean(self) -> float:
        return self.total / self.count if self.count else float("nan")

    def percentile(self, q: float) -> float:
        return float(np.percentile(self.recent, q)) if self.recent else float("nan")


@dataclass
class ProcessorStats:
    frames_in: int = 0  # frames offered to `process`
    frames_published: int = 0  # frames whose outputs were produced (including frames without people)
    frames_empty: int = 0  # ... of which had nobody to fit
    people_fitted: int = 0
    time_resets: int = 0  # clock resets (stamp jumped back by more than sync.time_reset_s)
    init_bodies_used: int = 0  # people seeded from an init_bodies document
    drops: Counter = field(default_factory=Counter)  # frames not published, by DROP_* reason
    people_dropped: Counter = field(default_factory=Counter)  # people not fitted, by PERSON_* reason
    init_bodies_dropped: Counter = field(default_factory=Counter)  # init_bodies documents ignored, by reason
    flags: Counter = field(default_factory=Counter)  # fit flags (image_only, diverged, ...)
    keypoints_ignored: Counter = field(default_factory=Counter)  # keypoint points not used, by reason
    latency_window: int = 100  # frames the latency statistics are computed over
    tracking: Any = None  # tracking.tracker.TrackerStats of the processor's tracker (None: no tracking)
    latency: dict[str, LatencyStats] = field(default_factory=dict)
    people_per_frame: deque = field(default_factory=lambda: deque(maxlen=100))

    def __post_init__(self) -> None:
        for stage in STAGES:
            self.latency.setdefault(stage, LatencyStats(self.latency_window))

    def record(self, stage: str, seconds: float) -> None:
        if stage not in self.latency:
            self.latency[stage] = LatencyStats(self.latency_window)
        self.latency[stage].add(seconds)

    def values(self) -> dict[str, float | int | str]:
        """Flat key -> value view for /diagnostics and the replay summary."""
        values: dict[str, float | int | str] = {
            "frames_in": self.frames_in,
            "frames_published": self.frames_published,
            "frames_without_people": self.frames_empty,
            "people_fitted": self.people_fitted,
            "people_per_frame_mean": float(np.mean(self.people_per_frame)) if self.people_per_frame else 0.0,
            "people_per_frame_last": self.people_per_frame[-1] if self.people_per_frame else 0,
            "frames_dropped": sum(self.drops.values()),
            "time_resets": self.time_resets,
        }
        for prefix, counter in (("drop", self.drops), ("people_dropped", self.people_dropped),
                                ("fits_flagged", self.flags), ("init_bodies_dropped", self.init_bodies_dropped),
                                ("keypoints_ignored", self.keypoints_ignored)):
            values.update({f"{prefix}.{key}": n for key, n in sorted(counter.items())})
        values["init_bodies_used"] = self.init_bodies_used
        if self.tracking is not None:
            values.update({"tracking.tracks_started": self.tracking.tracks_started,
                           "tracking.tracks_ended": self.tracking.tracks_ended,
                           **{f"tracking.fits_{k}": n for k, n in sorted(self.tracking.fits.items())}})
        for stage, lat in self.latency.items():
            if lat.recent:
                values[f"latency_ms.{stage}.mean"] = 1e3 * lat.mean
                values.update({f"latency_ms.{stage}.p{q}": 1e3 * lat.percentile(q) for q in PERCENTILES})
                values[f"latency_ms.{stage}.max"] = 1e3 * lat.max
        return values


# -- inputs -----------------------------------------------------------------------------------------------
class InputMonitor:
    """Arrival times of each subscribed input: counts, rate over a window, time since the last message,
    and messages that could not be handled (counted per input, never raised out of a callback)."""

    def __init__(self, names: list[str], window_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.window_s = window_s
        self.clock = clock
        self.started = clock()
        self.received = dict.fromkeys(names, 0)
        self.errors: Counter = Counter()
        self._times: dict[str, deque[float]] = {name: deque() for name in names}
        self._last: dict[str, float | None] = dict.fromkeys(names)
        self._lock = threading.Lock()

    def arrived(self, name: str) -> None:
        now = self.clock()
        with self._lock:
            self.received[name] += 1
            self._last[name] = now
            times = self._times[name]
            times.append(now)
            while times and times[0] <= now - self.window_s:  # bounded: at most the window's messages
                times.popleft()

    def failed(self, name: str) -> None:
        with self._lock:
            self.errors[name] += 1

    def rate_hz(self, name: str, now: float) -> float:
        """Messages per second over the last `window_s` (or since start, when shorter)."""
        with self._lock:
            n = sum(t > now - self.window_s for t in self._times[name])
        return n / max(min(self.window_s, now - self.started), 1e-3)

    def silent_s(self, name: str, now: float) -> float:
        """Seconds since the input's last message (since start when it never had one)."""
        with self._lock:
            last = self._last[name]
        return now - (self.started if last is None else last)


@dataclass
class InputCheck:
    """What an input status is judged by (the `diagnostics` section of params/base/node.yaml)."""

    topic: str
    expected_hz: float  # 0: rate not checked
    rate_tolerance: float
    stale_after_s: float


def input_level(monitor: InputMonitor, name: str, check: InputCheck, now: float) -> tuple[str, str, dict]:
    """(level, message, values) of one input's status."""
    rate, silent = monitor.rate_hz(name, now), monitor.silent_s(name, now)
    values: dict[str, Any] = {"topic": check.topic, "received": monitor.received[name], "rate_hz": rate,
                              "expected_hz": check.expected_hz, "silent_s": silent,
                              "bad_messages": monitor.errors[name]}
    if silent >= check.stale_after_s:
        what = "no message yet" if monitor.received[name] == 0 else "no message"
        return "WARN", f"{what} for {silent:.1f} s (stale after {check.stale_after_s:g} s)", values
    low = check.expected_hz * (1.0 - check.rate_tolerance)
    high = check.expected_hz * (1.0 + check.rate_tolerance)
    full_window = now - monitor.started >= monitor.window_s  # a shorter count says little about a rate
    if check.expected_hz > 0 and full_window and not low <= rate <= high:
        return "WARN", f"rate {rate:.1f} Hz outside [{low:.1f}, {high:.1f}] Hz", values
    return "OK", f"{rate:.1f} Hz", values


# counters whose growth since the last report makes the fitting status WARN (frames or sets lost)
_WARN_COUNTERS = (("drops", "drop."), ("diverged", "fits_flagged.diverged"), ("sync", "sync.dropped_"),
                  ("stale", "queue.dropped_stale"), ("bad", "bad_messages."))


class DiagnosticsReporter:
    """Builds `/diagnostics` messages (module docstring). The fitting status is ERROR when handling a frame
    raised (a bug) since the last report or when `no_frame` says why no frame can be built, WARN when
    frames, synchronized sets or messages were dropped or fits diverged since the last report."""

    def __init__(self, name: str, hardware_id: str = "smplify3d_ros") -> None:
        self.name = name
        self.hardware_id = hardware_id
        self._last: dict[str, float] = {}

    def _new_counts(self, values: Mapping[str, Any]) -> dict[str, float]:
        prefixes = (("errors", f"drop.{DROP_FIT_ERROR}"), ("internal", f"drop.{DROP_INTERNAL}"), *_WARN_COUNTERS)
        totals = {key: sum(v for k, v in values.items() if k.startswith(prefix) and isinstance(v, (int, float))
                           and not isinstance(v, bool)) for key, prefix in prefixes}
        new = {key: total - self._last.get(key, 0) for key, total in totals.items()}
        self._last = totals
        return new

    def fitting_level(self, values: Mapping[str, Any], no_frame: str | None = None) -> tuple[str, str]:
        new = self._new_counts(values)
        failed = int(new["errors"] + new["internal"])
        if failed:
            return "ERROR", f"{failed} frame(s) failed with an error"
        if no_frame:
            return "ERROR", f"no frame can be built: {no_frame}"
        lost = {key: int(new[key]) for key, _ in _WARN_COUNTERS if new[key] > 0}
        if lost:
            words = {"drops": "frame(s) dropped", "diverged": "fit(s) diverged", "sync": "message(s) unmatched",
                     "stale": "frame(s) skipped (fitting slower than the inputs)", "bad": "bad message(s)"}
            return "WARN", ", ".join(f"{n} {words[key]}" for key, n in lost.items())
        return "OK", "fitting"

    def message(self, stamp: Any, values: dict[str, Any], factory: MessageFactory | None = None,
                inputs: list[tuple[str, str, str, dict]] | None = None, no_frame: str | None = None) -> Any:
        """The DiagnosticArray: the fitting status, then one status per entry of `inputs`
        ((name, level, message, values), see `input_level`)."""
        level, text = self.fitting_level(values, no_frame)
        if not inputs:
            return diagnostics_array(stamp, self.name, level, text, values, factory, self.hardware_id)
        base = self.name.rsplit(":", 1)[0]
        statuses = [diagnostic_status(self.name, level, text, values, factory, self.hardware_id)]
        statuses += [diagnostic_status(f"{base}: input {name}", lvl, msg, vals, factory, self.hardware_id)
                     for name, lvl, msg, vals in inputs]
        return diagnostics_message(stamp, statuses, factory)


class LogLimiter:
    """Logs a line per key at most every `period_s`, with the count of the lines held back in between."""

    def __init__(self, log: Any, period_s: float = 5.0, clock: Callable[[], float] = time.monotonic) -> None:
        self.log = log
        self.period_s = period_s
        self.clock = clock
        self._times: dict[str, tuple[float, int]] = {}
        self._lock = threading.Lock()

    def warning(self, key: str, text: str) -> None:
        now = self.clock()
        with self._lock:
            last, held = self._times.get(key, (-1e18, 0))
            if now - last < self.period_s:
                self._times[key] = (last, held + 1)
                return
            self._times[key] = (now, 0)
        self.log.warning(text + (f" ({held} more since the last report)" if held else ""))
