"""Counters and latencies of the frame processor, and the /diagnostics message built from them."""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from msg_adapters import MessageFactory, diagnostics_array
from smplify3d_ros.runtime.messages import DROP_FIT_ERROR, DROP_INTERNAL

STAGES = ("convert", "extract", "fit", "outputs", "total")


class LatencyStats:
    """Per-stage latency: the last `window` values (mean, max) and totals since start."""

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
    latency: dict[str, LatencyStats] = field(default_factory=lambda: {s: LatencyStats() for s in STAGES})
    people_per_frame: deque = field(default_factory=lambda: deque(maxlen=100))

    def record(self, stage: str, seconds: float) -> None:
        if stage not in self.latency:
            self.latency[stage] = LatencyStats()
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
                                ("fits_flagged", self.flags), ("init_bodies_dropped", self.init_bodies_dropped)):
            values.update({f"{prefix}.{key}": n for key, n in sorted(counter.items())})
        values["init_bodies_used"] = self.init_bodies_used
        for stage, lat in self.latency.items():
            if lat.recent:
                values[f"latency_ms.{stage}.mean"] = 1e3 * lat.mean
                values[f"latency_ms.{stage}.max"] = 1e3 * lat.max
        return values


class DiagnosticsReporter:
    """Builds `/diagnostics` messages: level OK, WARN when frames were dropped or fits flagged `diverged`
    since the last report, ERROR when handling a frame raised (a bug) since the last report."""

    def __init__(self, name: str, hardware_id: str = "smplify3d_ros") -> None:
        self.name = name
        self.hardware_id = hardware_id
        self._last: dict[str, float] = {}

    def message(self, stamp: Any, values: dict[str, Any], factory: MessageFactory | None = None) -> Any:
        totals = {
            key: sum(v for k, v in values.items() if k.startswith(prefix) and isinstance(v, (int, float)))
            for key, prefix in (("errors", f"drop.{DROP_FIT_ERROR}"), ("internal", f"drop.{DROP_INTERNAL}"),
                                ("drops", "drop."), ("diverged", "fits_flagged.diverged"))
        }
        new = {key: total - self._last.get(key, 0) for key, total in totals.items()}
        self._last = totals
        if new["errors"] + new["internal"] > 0:
            level, text = "ERROR", f"{int(new['errors'] + new['internal'])} frame(s) failed with an error"
        elif new["drops"] > 0 or new["diverged"] > 0:
            level, text = "WARN", f"{int(new['drops'])} frame(s) dropped, {int(new['diverged'])} fit(s) diverged"
        else:
            level, text = "OK", "fitting"
        return diagnostics_array(stamp, self.name, level, text, values, factory, self.hardware_id)
