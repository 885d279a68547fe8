"""`replay_bag`: a recording through the node's per-frame step, into an output bag and a summary.

Memory does not grow with the bag's length: messages stream from the storage, ground truth is scored as
it comes (`scoring`), the output is written chunk by chunk, and the summary keeps counters, running
means and the last MAX_FRAME_RECORDS frames' records (a few hundred bytes each).
"""

from __future__ import annotations

import logging
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from msg_adapters import clip
from smplify3d_ros.config import load_config
from smplify3d_ros.replay.output import Output, OutputError, check_output, prepare_output
from smplify3d_ros.replay.picture import PictureChooser
from smplify3d_ros.replay.reader import BagReader, BagStep, ReplayError
from smplify3d_ros.replay.sources import READ_BAD_TRUTH
from smplify3d_ros.replay.writer import BagWriter, write_metadata_yaml
from smplify3d_ros.runtime.config import load_node_config
from smplify3d_ros.runtime.outputs import DIAGNOSTICS_TYPE, NODE_NAME, OUTPUTS, output_topic, output_type
from smplify3d_ros.runtime.stats import DiagnosticsReporter
from smplify3d_ros.runtime.sync import sync_values
from smplify3d_ros.runtime.transforms import Transforms

if TYPE_CHECKING:  # the processor and the scorer load torch: imported once a run's outputs are checked,
    # so that a refused output or a missing bag is reported at once
    from smplify3d_ros.runtime.processor import FrameResult, MessageProcessor

OUTPUT_TOPICS = {name: f"/{NODE_NAME}/{name}" for name in OUTPUTS}
DIAGNOSTICS_TOPIC = "/diagnostics"
MAX_FRAME_RECORDS = 1000  # ReplaySummary.frames keeps the last this many published frames
PICTURE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")  # what --png can write
log = logging.getLogger("smplify3d_ros.replay")


@dataclass
class FrameRecord:
    """What one published frame held (camera frame unless output_frame says otherwise), float32."""

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
    init_bodies_dropped: dict[str, int] = field(default_factory=dict)  # init_bodies documents ignored
    keypoints_ignored: dict[str, int] = field(default_factory=dict)  # keypoint points ignored in used frames
    flags: dict[str, int] = field(default_factory=dict)
    sync: dict[str, int] = field(default_factory=dict)  # the synchronizer's counters (sync.*)
    read_drops: dict[str, int] = field(default_factory=dict)  # storage and message faults (sources.READ_*)
    read_problems: list[str] = field(default_factory=list)  # the first of them, described
    messages_read: int = 0  # messages the storage gave
    messages_in_bag: int = 0  # messages its index (or, cut, its readable part) counts
    truncated: str | None = None  # what a cut MCAP file said
    mean_latency_s: float = float("nan")  # per frame, fitting pipeline only
    wall_s: float = 0.0
    ground_truth_frames: int = 0
    people_evaluated: int = 0
    people_missed: int = 0  # ground-truth people without a fit in a fitted frame
    mpjpe_mm: float | None = None  # COCO-17 3D keypoints
    pve_mm: float | None = None  # mesh vertices (same body model as the ground truth only)
    frames: deque[FrameRecord] = field(default_factory=lambda: deque(maxlen=MAX_FRAME_RECORDS))
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
        sync = {k.removeprefix("sync.dropped_"): v for k, v in self.sync.items() if k.startswith("sync.dropped_")}
        for title, counts in (("frames dropped", self.drops), ("people not fitted", self.people_dropped),
                              ("fit flags", self.flags), ("messages the synchronizer dropped", sync),
                              ("init_bodies documents ignored", self.init_bodies_dropped),
                              ("keypoint points ignored", self.keypoints_ignored)):
            if any(counts.values()):
                lines.append(f"  {title}: " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items()) if v))
        lines += self._read_lines()
        if self.ground_truth_frames:
            mpjpe = "n/a" if self.mpjpe_mm is None else f"{self.mpjpe_mm:.1f} mm"
            pve = "n/a" if self.pve_mm is None else f"{self.pve_mm:.1f} mm"
            lines.append(f"  ground truth: {self.people_evaluated} people in {self.ground_truth_frames} frames "
                         f"({self.people_missed} missed): MPJPE {mpjpe}, PVE {pve}")
        else:
            lines.append("  no ground truth in the bag")
        lines += [f"  wrote {path}" for path in (self.output, self.png) if path]
        return "\n".join(lines)

    def _read_lines(self) -> list[str]:
        lines = []
        if self.truncated:
            lines.append(f"  truncated bag: {self.truncated}; replayed up to the cut")
        if self.read_drops:
            lines.append(f"  bag faults (skipped, {self.messages_read} of {self.messages_in_bag} messages read): "
                         + ", ".join(f"{k} {v}" for k, v in sorted(self.read_drops.items())))
            lines += [f"    {clip(problem, 200)}" for problem in self.read_problems[:5]]
        return lines


class _Replay:
    """One replay: the reader's steps through the processor, into the writer, the scorer and the picture."""

    def __init__(self, reader: BagReader, processor: MessageProcessor, writer: BagWriter | None,
                 summary: ReplaySummary, png: bool, diagnostics_period_s: float) -> None:
        from smplify3d_ros.replay.scoring import TruthScorer

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
            self.add_truth(step)
        for msgs in step.frames:
            self.summary.frames_synced += 1
            stamp_ns = msgs.stamp_ns
            for s, doc in self.init_docs:
                if abs(s - stamp_ns) <= self.slop_ns:
                    self.processor.add_init_bodies(doc)
            result = self.processor.process(msgs)
            if result.ok:
                self._published(result, step.timestamp)

    def add_truth(self, step: BagStep) -> None:
        try:
            self.scorer.add_truth(step.truth)
        except Exception as e:  # noqa: BLE001 - a parsed document the scorer cannot use (e.g. wrong sizes)
            self.reader.faults.add(READ_BAD_TRUTH, f"ground truth at {step.timestamp} not scored: "
                                   f"{type(e).__name__}: {clip(e)}", key=("score", step.timestamp))

    def _published(self, result: FrameResult, timestamp: int) -> None:
        fits = result.fits
        try:
            self.scorer.add_result(result.stamp_ns, result.frame_id, fits)
        except Exception as e:  # noqa: BLE001 - as add_truth: the pair is not scored, the replay goes on
            self.reader.faults.add(READ_BAD_TRUTH, f"frame {result.stamp_ns} not scored: {type(e).__name__}: "
                                   f"{clip(e)}", key=("score", result.stamp_ns))
        self.summary.frames.append(FrameRecord(
            result.stamp_ns, [f.person_id for f in fits],
            np.array([f.keypoints3d for f in fits], np.float32).reshape(-1, 17, 3),
            np.array([f.params.transl for f in fits], np.float32).reshape(-1, 3),
            result.latency.get("total", float("nan"))))
        if self.picture is not None and result.frame is not None:
            self.picture.offer(result.frame, fits, timestamp)
        if self.writer is None:
            return
        for name, msg in result.outputs.items():
            self.writer.write(output_topic(name), output_type(name), msg, timestamp)
        if self.last_diagnostics is None or timestamp - self.last_diagnostics >= self.period_ns:
            self.last_diagnostics = timestamp
            self._diagnostics(result.stamp, timestamp)

    def values(self) -> dict[str, Any]:
        """/diagnostics values: the processor's, the synchronizer's and the bag's faults."""
        faults = {f"drop.message.{reason}": n for reason, n in sorted(self.reader.faults.counts.items())}
        return {**self.processor.stats.values(), **sync_values(self.reader.sync), **faults}

    def _diagnostics(self, stamp: Any, timestamp: int) -> None:
        msg = self.reporter.message(stamp, self.values(), self.processor.factory)
        self.writer.write(DIAGNOSTICS_TOPIC, DIAGNOSTICS_TYPE, msg, timestamp)

    def finish(self, last_timestamp: int | None) -> None:
        if self.writer is not None and self.last_diagnostics is not None:
            end = max(self.last_diagnostics, last_timestamp or 0) + 1
            self._diagnostics(end, end)
        self.scorer.finish()
        stats, summary, scorer, faults = self.processor.stats, self.summary, self.scorer, self.reader.faults
        summary.frames_published = stats.frames_published
        summary.people_fitted = stats.people_fitted
        summary.drops = dict(stats.drops)
        summary.people_dropped = dict(stats.people_dropped)
        summary.init_bodies_dropped = dict(stats.init_bodies_dropped)
        summary.keypoints_ignored = dict(getattr(stats, "keypoints_ignored", {}))
        summary.flags = dict(stats.flags)
        summary.sync = sync_values(self.reader.sync)
        summary.read_drops, summary.read_problems = dict(faults.counts), list(faults.lines)
        summary.truncated = faults.truncated
        summary.messages_read, summary.messages_in_bag = self.reader.messages_read, self.reader.message_count
        summary.mean_latency_s = stats.latency["total"].overall_mean
        summary.ground_truth_frames, summary.people_evaluated = scorer.frames, scorer.people
        summary.people_missed, summary.mpjpe_mm, summary.pve_mm = scorer.missed, scorer.mpjpe_mm, scorer.pve_mm


def _inputs(bag: Path) -> list[Path]:
    """The paths an output must not touch: the bag and, for a directory, what it holds (first: an output
    equal to one of its files is told so)."""
    return [*bag.iterdir(), bag] if bag.is_dir() else [bag]


def _open_writer(output: Output, reader: BagReader) -> BagWriter:
    name = output.file.name if output.directory else output.target.name
    writer = BagWriter(output.file, reader.typestore, name)
    for conn in reader.connections:
        writer.copy_connection(conn)
    if writer.not_copied:
        log.warning(f"not copied (no message definition in the bag): {clip(writer.not_copied)}")
    return writer


def _close_writer(writer: BagWriter, output: Output) -> None:
    info = writer.close()
    if output.directory:
        write_metadata_yaml(output.temp, info)  # last: a directory without it is no bag
    output.commit()


def _replay_steps(reader: BagReader, replay: _Replay, summary: ReplaySummary, max_frames: int | None,
                  bar: Any) -> int | None:
    """The main loop; returns the last message's timestamp."""
    timestamp = last_frame = None
    for step in reader:
        bar.update(1)
        timestamp = step.timestamp
        if max_frames is None or summary.frames_synced < max_frames:
            replay.step(step)
            last_frame = timestamp
        elif step.truth is not None:  # past the last frame: only the ground truth it still waits for
            replay.add_truth(step)
        if max_frames is not None and summary.frames_synced >= max_frames and (
                not replay.scorer.waiting or timestamp > last_frame + replay.scorer.window_ns):
            break
    return timestamp


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
    overwrite: bool = False,
) -> ReplaySummary:
    """Run the node's per-frame step over a bag; see the package docstring. Raises ReplayError for
    unusable bags, OutputError (a ReplayError) for outputs it must not or cannot write, ConfigError for
    unusable parameters. Outputs appear only when complete (`output.Output`)."""
    t_start = time.perf_counter()
    bag = Path(bag)
    if not bag.exists():
        raise ReplayError(f"{bag} does not exist")
    if png is not None and Path(png).suffix.lower() not in PICTURE_SUFFIXES:
        raise OutputError(f"{png}: a picture file name must end in one of {', '.join(PICTURE_SUFFIXES)}")
    if png is not None and output is not None and Path(png).resolve() == Path(output).resolve():
        raise OutputError(f"{png}: the picture and the output bag need different names")
    # outputs are checked before anything heavy loads (a refusal is reported at once), and their partial
    # files created once torch is in (an interrupt while it loads leaves nothing to clean up)
    for target, directory in ((output, output is not None and Path(output).suffix != ".mcap"), (png, False)):
        if target is not None:
            check_output(target, _inputs(bag), overwrite, directory)
    from smplify3d_ros.runtime.processor import MessageProcessor  # noqa: F401 - loads torch, see above

    outputs: list[Output] = []
    try:  # checked before anything is fitted: a run must not fail at its end for its output's sake
        out = None if output is None else prepare_output(output, _inputs(bag), overwrite,
                                                         directory=Path(output).suffix != ".mcap")
        outputs += [out] if out is not None else []
        picture = None if png is None else prepare_output(png, _inputs(bag), overwrite)
        outputs += [picture] if picture is not None else []
        config = config or load_config(params)
        node_config = node_config or load_node_config(params)
        summary = _run(bag, out, picture, progress, max_frames, config, node_config, fitter)
    finally:
        for made in outputs:
            made.discard()  # a no-op once committed; else what this run created is removed
    summary.wall_s = time.perf_counter() - t_start
    return summary


def _run(bag: Path, out: Output | None, picture: Output | None, progress: bool, max_frames: int | None,
         config: Any, node_config: Any, fitter: Any) -> ReplaySummary:
    from tqdm import tqdm

    from msg_adapters import RosbagsFactory
    from smplify3d_ros.runtime.heap import freeze_startup_heap
    from smplify3d_ros.runtime.processor import MessageProcessor

    summary = ReplaySummary(str(bag))
    with BagReader(bag, node_config, log) as reader:
        processor = MessageProcessor(config, node_config, RosbagsFactory(reader.typestore), fitter=fitter,
                                     transforms=Transforms(node_config.extrinsic, reader.tf.lookup, log=log),
                                     log=log, keep_frames=picture is not None, build_outputs=out is not None)
        processor.frames.start_background()  # as the node does: the refreshes' process loads meanwhile
        freeze_startup_heap()  # as the node does: no full collection walks the body model per frame
        writer = None if out is None else _open_writer(out, reader)
        replay = _Replay(reader, processor, writer, summary, picture is not None, node_config.diagnostics_period_s)
        bar = tqdm(total=reader.message_count, unit="msg", disable=not progress, desc=bag.name, file=sys.stderr)
        try:
            replay.finish(_replay_steps(reader, replay, summary, max_frames, bar))
            if writer is not None:
                _close_writer(writer, out)
                summary.output = str(out.target)
        except BaseException:
            if writer is not None:
                writer.abort()
            raise
        finally:
            bar.close()
            processor.frames.close()
    if picture is not None:
        if replay.picture.write(picture.temp, processor.fitter.faces_np, picture.target.suffix):
            picture.commit()
            summary.png = str(picture.target)
        else:
            log.warning(f"no fitted frame: {picture.target} not written")
    return summary


__all__ = ["FrameRecord", "OutputError", "ReplayError", "ReplaySummary", "replay_bag"]
