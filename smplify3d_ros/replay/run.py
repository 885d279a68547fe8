"""`replay_bag`: a recording through the node's per-frame step, into an output bag and a summary."""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smplify3d_ros.config import load_config
from smplify3d_ros.replay.picture import PictureChooser
from smplify3d_ros.replay.reader import BagReader, BagStep, ReplayError
from smplify3d_ros.replay.scoring import TruthScorer
from smplify3d_ros.replay.writer import BagWriter
from smplify3d_ros.runtime.config import load_node_config
from smplify3d_ros.runtime.outputs import DIAGNOSTICS_TYPE, NODE_NAME, OUTPUTS, output_topic, output_type
from smplify3d_ros.runtime.processor import FrameResult, MessageProcessor
from smplify3d_ros.runtime.stats import DiagnosticsReporter
from smplify3d_ros.runtime.sync import sync_values
from smplify3d_ros.runtime.transforms import Transforms

OUTPUT_TOPICS = {name: f"/{NODE_NAME}/{name}" for name in OUTPUTS}
DIAGNOSTICS_TOPIC = "/diagnostics"
log = logging.getLogger("smplify3d_ros.replay")


@dataclass
class FrameRecord:
    """What one published frame held (camera frame unless output_frame says otherwise)."""

    stamp_ns: int
    person_ids: list[int]
    keypoints3d: np.ndarray  # (P, 17, 3)
    transl: np.ndarray  # (P, 3)
    latency_s: float


@dataclass
class ReplaySummary:
    bag: str
    frames_synced: int = 0  # synchronized input sets
    frames_published: int = 0
    people_fitted: int = 0
    drops: dict[str, int] = field(default_factory=dict)
    people_dropped: dict[str, int] = field(default_factory=dict)
    flags: dict[str, int] = field(default_factory=dict)
    sync: dict[str, int] = field(default_factory=dict)  # the synchronizer's counters (sync.*)
    mean_latency_s: float = float("nan")  # per frame, fitting pipeline only
    wall_s: float = 0.0
    ground_truth_frames: int = 0
    people_evaluated: int = 0
    people_missed: int = 0  # ground-truth people without a fit in a fitted frame
    mpjpe_mm: float | None = None  # COCO-17 3D keypoints
    pve_mm: float | None = None  # mesh vertices (same body model as the ground truth only)
    frames: list[FrameRecord] = field(default_factory=list)
    output: str | None = None
    png: str | None = None

    @property
    def sync_dropped(self) -> int:
        return sum(v for k, v in self.sync.items() if k.startswith("sync.dropped_"))

    def text(self) -> str:
        lines = [
            f"{self.bag}: {self.frames_synced} synchronized frames, {self.frames_published} published, "
            f"{self.people_fitted} people fitted",
            f"  mean latency {1e3 * self.mean_latency_s:.0f} ms per frame; wall time {self.wall_s:.1f} s",
        ]
        for title, counts in (("frames dropped", self.drops), ("people not fitted", self.people_dropped),
                              ("fit flags", self.flags)):
            if counts:
                lines.append(f"  {title}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
        if self.ground_truth_frames:
            mpjpe = "n/a" if self.mpjpe_mm is None else f"{self.mpjpe_mm:.1f} mm"
            pve = "n/a" if self.pve_mm is None else f"{self.pve_mm:.1f} mm"
            lines.append(f"  ground truth: {self.people_evaluated} people in {self.ground_truth_frames} frames "
                         f"({self.people_missed} missed): MPJPE {mpjpe}, PVE {pve}")
        else:
            lines.append("  no ground truth in the bag")
        lines += [f"  wrote {path}" for path in (self.output, self.png) if path]
        return "\n".join(lines)


class _Replay:
    """One replay: the reader's steps through the processor, into the writer, the scorer and the picture."""

    def __init__(self, reader: BagReader, processor: MessageProcessor, writer: BagWriter | None,
                 summary: ReplaySummary, png: bool, diagnostics_period_s: float) -> None:
        self.reader, self.processor, self.writer, self.summary = reader, processor, writer, summary
        self.slop_ns = round(processor.node.sync.slop_s * 1e9)
        self.scorer = TruthScorer(processor.fitter.model, self.slop_ns)
        start, end = reader.duration_ns
        self.picture = PictureChooser((start + end) / 2) if png else None
        self.reporter = DiagnosticsReporter(f"{NODE_NAME}: fitting", "smplify3d_ros")
        self.period_ns = diagnostics_period_s * 1e9
        self.last_diagnostics: int | None = None
        self.init_docs = [(s, doc) for s, doc in reader.init_docs if s >= 0]
        for _, doc in (d for d in reader.init_docs if d[0] < 0):
            processor.add_init_bodies(doc)  # unreadable stamp: the parser counts and reports it

    def step(self, step: BagStep) -> None:
        if self.writer is not None:
            self.writer.write_raw(step.connection, step.timestamp, step.raw)
        if step.truth is not None:
            self.scorer.add_truth(step.truth)
        for msgs in step.frames:
            self.summary.frames_synced += 1
            stamp_ns = msgs.stamp_ns
            for s, doc in self.init_docs:
                if abs(s - stamp_ns) <= self.slop_ns:
                    self.processor.add_init_bodies(doc)
            result = self.processor.process(msgs)
            if result.ok:
                self._published(result, step.timestamp)

    def _published(self, result: FrameResult, timestamp: int) -> None:
        fits = result.fits
        self.scorer.add_result(result.stamp_ns, result.frame_id, fits)
        self.summary.frames.append(FrameRecord(
            result.stamp_ns, [f.person_id for f in fits], np.array([f.keypoints3d for f in fits]).reshape(-1, 17, 3),
            np.array([f.params.transl for f in fits]).reshape(-1, 3), result.latency.get("total", float("nan"))))
        if self.picture is not None and result.frame is not None:
            self.picture.offer(result.frame, fits, timestamp)
        if self.writer is None:
            return
        for name, msg in result.outputs.items():
            self.writer.write(output_topic(name), output_type(name), msg, timestamp)
        if self.last_diagnostics is None or timestamp - self.last_diagnostics >= self.period_ns:
            self.last_diagnostics = timestamp
            self._diagnostics(result.stamp, timestamp)

    def _diagnostics(self, stamp: Any, timestamp: int) -> None:
        values = {**self.processor.stats.values(), **sync_values(self.reader.sync)}
        msg = self.reporter.message(stamp, values, self.processor.factory)
        self.writer.write(DIAGNOSTICS_TOPIC, DIAGNOSTICS_TYPE, msg, timestamp)

    def finish(self, last_timestamp: int | None) -> None:
        if self.writer is not None and self.last_diagnostics is not None:
            end = max(self.last_diagnostics, last_timestamp or 0) + 1
            self._diagnostics(end, end)
        self.scorer.finish()
        stats, summary, scorer = self.processor.stats, self.summary, self.scorer
        summary.frames_published = stats.frames_published
        summary.people_fitted = stats.people_fitted
        summary.drops = dict(stats.drops)
        summary.people_dropped = dict(stats.people_dropped)
        summary.flags = dict(stats.flags)
        summary.sync = sync_values(self.reader.sync)
        summary.mean_latency_s = stats.latency["total"].overall_mean
        summary.ground_truth_frames, summary.people_evaluated = scorer.frames, scorer.people
        summary.people_missed, summary.mpjpe_mm, summary.pve_mm = scorer.missed, scorer.mpjpe_mm, scorer.pve_mm


def replay_bag(
    bag: str | Path,
    output: str | Path | None = None,
    params: str | Path | None = None,
    png: str | Path | None = None,
    progress: bool = True,
    max_frames: int | None = None,
    config: Any = None,
    node_config: Any = None,
    fitter: Any = None,
) -> ReplaySummary:
    """Run the node's per-frame step over a bag; see the package docstring. Raises ReplayError for
    unusable bags, ConfigError for unusable parameters."""
    from tqdm import tqdm

    from msg_adapters import RosbagsFactory

    t_start = time.perf_counter()
    config = config or load_config(params)
    node_config = node_config or load_node_config(params)
    summary = ReplaySummary(str(bag))
    with BagReader(bag, node_config, log) as reader:
        processor = MessageProcessor(config, node_config, RosbagsFactory(reader.typestore), fitter=fitter,
                                     transforms=Transforms(node_config.extrinsic, reader.tf.lookup, log=log),
                                     log=log, keep_frames=png is not None)
        writer = None
        if output is not None:
            writer = BagWriter(Path(output), reader.typestore)
            for conn in reader.connections:
                writer.copy_connection(conn)
        replay = _Replay(reader, processor, writer, summary, png is not None, node_config.diagnostics_period_s)
        timestamp = last_frame = None
        bar = tqdm(total=reader.message_count, unit="msg", disable=not progress, desc=Path(bag).name,
                   file=sys.stderr)
        try:
            for step in reader:
                bar.update(1)
                timestamp = step.timestamp
                if max_frames is None or summary.frames_synced < max_frames:
                    replay.step(step)
                    last_frame = timestamp
                elif step.truth is not None:  # past the last frame: only the ground truth it still waits for
                    replay.scorer.add_truth(step.truth)
                if max_frames is not None and summary.frames_synced >= max_frames and (
                        not replay.scorer.waiting or timestamp > last_frame + replay.scorer.window_ns):
                    break
            bar.close()
            replay.finish(timestamp)
        finally:
            if writer is not None:
                writer.close()
                summary.output = str(output)
        if png is not None:
            if replay.picture.write(Path(png), processor.fitter.faces_np):
                summary.png = str(png)
            else:
                log.warning(f"no fitted frame: {png} not written")
    summary.wall_s = time.perf_counter() - t_start
    return summary


__all__ = ["FrameRecord", "ReplayError", "ReplaySummary", "replay_bag"]
