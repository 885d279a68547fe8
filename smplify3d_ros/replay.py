"""Bag in -> fits -> bag out, without a ROS runtime: `smplify3d replay IN [-o OUT.mcap] [--params FILE] [--png FILE]`.

Reads a rosbag2 recording (a bag directory, or a bare .mcap / .db3 file) with rosbags, synchronizes the
inputs with the node's synchronizer and parameters, runs the frame pipeline the node runs, and writes an
MCAP bag holding the input topics and every output topic (`/smplify3d/markers`, ... and `/diagnostics`),
each output at the recording time of the message that completed its frame. Prints a summary: frames,
people fitted, latency and, when the bag has ground truth on `/ground_truth/bodies` (the `~/bodies` JSON
schema, optionally with each body's `vertices`), MPJPE and PVE.

Input topics are the node's (`topics.*`); a topic missing from the bag is looked up by type instead (the
only Image, the only CameraInfo; PointCloud2 clouds with `u`, `v` fields are keypoints, with `x` points).
A LiDAR-camera transform on `/tf_static` is used when the bag has one, else the extrinsic parameters.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smplify3d_ros.eval import metrics
from smplify3d_ros.frame_pipeline import (
    NODE_NAME,
    OUTPUT_TYPES,
    OUTPUTS,
    DiagnosticsReporter,
    FrameMessages,
    FramePipeline,
    FrameResult,
    Transforms,
)
from smplify3d_ros.sync import ApproximateTimeSync

OUTPUT_TOPICS = {name: f"/{NODE_NAME}/{name}" for name in OUTPUTS}
DIAGNOSTICS_TOPIC = "/diagnostics"
GROUND_TRUTH_TOPIC = "/ground_truth/bodies"
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")


class ReplayError(RuntimeError):
    """The bag cannot be replayed (missing inputs, unreadable file); the message says why."""


# -- results ----------------------------------------------------------------------------------------------
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
    sync_dropped: int = 0
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

    def text(self) -> str:
        lines = [
            f"{self.bag}: {self.frames_synced} synchronized frames, {self.frames_published} published, "
            f"{self.people_fitted} people fitted",
            f"  mean latency {1e3 * self.mean_latency_s:.0f} ms per frame; wall time {self.wall_s:.1f} s",
        ]
        if self.drops:
            lines.append("  frames dropped: " + ", ".join(f"{k} {v}" for k, v in sorted(self.drops.items())))
        if self.people_dropped:
            lines.append("  people not fitted: "
                         + ", ".join(f"{k} {v}" for k, v in sorted(self.people_dropped.items())))
        if self.flags:
            lines.append("  fit flags: " + ", ".join(f"{k} {v}" for k, v in sorted(self.flags.items())))
        if self.ground_truth_frames:
            mpjpe = "n/a" if self.mpjpe_mm is None else f"{self.mpjpe_mm:.1f} mm"
            pve = "n/a" if self.pve_mm is None else f"{self.pve_mm:.1f} mm"
            lines.append(f"  ground truth: {self.people_evaluated} people in {self.ground_truth_frames} frames "
                         f"({self.people_missed} missed): MPJPE {mpjpe}, PVE {pve}")
        else:
            lines.append("  no ground truth in the bag")
        if self.output:
            lines.append(f"  wrote {self.output}")
        if self.png:
            lines.append(f"  wrote {self.png}")
        return "\n".join(lines)


# -- static transforms of the bag -------------------------------------------------------------------------
class StaticTransforms:
    """The bag's /tf_static tree: `lookup(target, source, stamp)` composes the edges between two frames."""

    def __init__(self) -> None:
        self._edges: dict[str, dict[str, np.ndarray]] = {}

    def __len__(self) -> int:
        return sum(len(v) for v in self._edges.values()) // 2

    def add(self, msg: Any) -> None:
        from scipy.spatial.transform import Rotation

        for t in msg.transforms:
            q, p = t.transform.rotation, t.transform.translation
            T = np.eye(4)
            T[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
            T[:3, 3] = (p.x, p.y, p.z)
            parent, child = str(t.header.frame_id).lstrip("/"), str(t.child_frame_id).lstrip("/")
            # edges[a][b] takes points in frame a into frame b; T takes child points into the parent frame
            self._edges.setdefault(child, {})[parent] = T
            self._edges.setdefault(parent, {})[child] = np.linalg.inv(T)

    def lookup(self, target: str, source: str, stamp: Any = None) -> np.ndarray | None:
        target, source = target.lstrip("/"), source.lstrip("/")
        if source not in self._edges or target not in self._edges:
            return None
        best: dict[str, np.ndarray] = {source: np.eye(4)}  # frame -> (source points -> frame)
        todo = deque([source])
        while todo:
            frame = todo.popleft()
            if frame == target:
                return best[frame]
            for other, T in self._edges[frame].items():
                if other not in best:
                    best[other] = T @ best[frame]  # source -> frame -> other
                    todo.append(other)
        return None


# -- ground truth -----------------------------------------------------------------------------------------
@dataclass
class TruthBody:
    person_id: int
    keypoints3d: np.ndarray | None  # (17, 3)
    vertices: np.ndarray | None  # (V, 3)
    model: str


def parse_ground_truth(text: str, fitter: Any) -> tuple[int, str, list[TruthBody]]:
    """A `/ground_truth/bodies` document -> (stamp ns, frame id, bodies). Geometry missing from the document
    is computed with the body model when the document's model is the fitter's."""
    from msg_adapters.factory import stamp_to_ns
    from smplify3d_ros.keypoints import COCO17_NAMES

    doc = json.loads(text)
    stamp = doc["stamp"]
    stamp_ns = (int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])) if isinstance(stamp, dict) \
        else stamp_to_ns(float(stamp))
    bodies = []
    for body in doc.get("bodies", []):
        kp = body.get("joints3d")
        kp3d = np.array([kp[name] for name in COCO17_NAMES], np.float64) if isinstance(kp, dict) and all(
            name in kp for name in COCO17_NAMES) else None
        verts = np.asarray(body["vertices"], np.float64) if body.get("vertices") else None
        if (kp3d is None or verts is None) and body.get("model") == fitter.model.name:
            model_kp, model_verts = _forward(body, fitter)
            kp3d = model_kp if kp3d is None else kp3d
            verts = model_verts if verts is None else verts
        bodies.append(TruthBody(int(body["id"]), kp3d, verts, str(body.get("model", ""))))
    return stamp_ns, str(doc.get("frame_id", "")), bodies


def _forward(body: dict, fitter: Any) -> tuple[np.ndarray, np.ndarray]:
    import torch

    names = list(fitter.model.joint_names)
    pose = np.zeros((len(names), 3))
    for name, value in body.get("pose", {}).items():
        pose[names.index(name)] = value
    dt, dev = fitter.dtype, fitter.device
    args = [torch.as_tensor(np.asarray(a, np.float64), dtype=dt, device=dev)[None]
            for a in (body["shape"], pose, body["root_orient"], body["transl"])]
    with torch.no_grad():
        out = fitter.model(*args)
    return out.keypoints[0].cpu().double().numpy(), out.vertices[0].cpu().double().numpy()


class Evaluator:
    """MPJPE (COCO-17 keypoints) and PVE (vertices) of the fits against the ground truth, per person id,
    in mm, without any alignment (the fits must be where the people are)."""

    def __init__(self, docs: dict[int, tuple[str, list[TruthBody]]], slop_ns: int) -> None:
        self.docs = docs
        self.slop_ns = slop_ns
        self.joint_errors: list[float] = []
        self.vertex_errors: list[float] = []
        self.frames = 0
        self.people = 0
        self.missed = 0

    def add(self, result: FrameResult) -> None:
        if not self.docs:
            return
        stamp = min(self.docs, key=lambda s: abs(s - result.stamp_ns))
        if abs(stamp - result.stamp_ns) > self.slop_ns:
            return
        frame_id, truth = self.docs[stamp]
        if frame_id and frame_id != result.frame_id:
            return  # fits in another frame (output_frame): not comparable
        self.frames += 1
        fits = {fit.person_id: fit for fit in result.fits}
        for body in truth:
            fit = fits.get(body.person_id)
            if fit is None:
                self.missed += 1
                continue
            self.people += 1
            if body.keypoints3d is not None:
                self.joint_errors.append(metrics.mpjpe(fit.keypoints3d, body.keypoints3d))
            if body.vertices is not None and body.model == fit.model and len(body.vertices) == len(fit.vertices):
                self.vertex_errors.append(metrics.pve(fit.vertices, body.vertices))


# -- bag reading ------------------------------------------------------------------------------------------
@dataclass
class InputTopics:
    image: str | None
    compressed: bool
    camera_info: str
    points: str
    keypoints: str
    init_bodies: str | None


def _fields_of_first(reader: Any, connection: Any, typestore: Any) -> set[str]:
    for conn, _, raw in reader.messages(connections=[connection]):
        msg = typestore.deserialize_cdr(raw, conn.msgtype)
        return {str(f.name) for f in msg.fields}
    return set()


def resolve_topics(reader: Any, typestore: Any, topics: Any) -> InputTopics:
    """Configured topic names, else the bag's only topic of the right type (see the module docstring)."""
    by_topic = {c.topic: c.msgtype for c in reader.connections}

    def pick(configured: str, msgtype: str, what: str, required: bool = True) -> str | None:
        if configured and by_topic.get(configured) == msgtype:
            return configured
        candidates = sorted(t for t, mt in by_topic.items() if mt == msgtype)
        if len(candidates) == 1:
            return candidates[0]
        if required:
            have = ", ".join(f"{t} ({mt})" for t, mt in sorted(by_topic.items())) or "none"
            raise ReplayError(f"cannot tell the {what} topic: {configured!r} is not in the bag and it has "
                              f"{len(candidates)} {msgtype} topics; topics: {have}")
        return None

    camera_info = pick(topics.camera_info, "sensor_msgs/msg/CameraInfo", "camera info")
    image = pick(topics.compressed_image or topics.image, IMAGE_TYPES[1 if topics.compressed else 0], "image",
                 required=False)
    compressed = topics.compressed
    if image is None:
        image = pick("", IMAGE_TYPES[1 - int(topics.compressed)], "image", required=False)
        compressed = image is not None and not topics.compressed
    clouds = {t for t, mt in by_topic.items() if mt == "sensor_msgs/msg/PointCloud2"}
    points = topics.points if topics.points in clouds else None
    keypoints = topics.keypoints if topics.keypoints in clouds else None
    if points is None or keypoints is None:
        kinds: dict[str, list[str]] = {"keypoints": [], "points": []}
        for conn in reader.connections:
            if conn.topic in clouds and conn.topic not in (points, keypoints):
                names = _fields_of_first(reader, conn, typestore)
                if {"u", "v", "joint"} <= names:
                    kinds["keypoints"].append(conn.topic)
                elif {"x", "y", "z"} <= names:
                    kinds["points"].append(conn.topic)
        for what, found in kinds.items():
            if (points if what == "points" else keypoints) is None:
                if len(found) != 1:
                    raise ReplayError(f"cannot tell the {what} topic: {getattr(topics, what)!r} is not in the "
                                      f"bag and {len(found)} PointCloud2 topics look like {what}: {found}")
                if what == "points":
                    points = found[0]
                else:
                    keypoints = found[0]
    init = topics.init_bodies if topics.init_bodies and by_topic.get(topics.init_bodies) == "std_msgs/msg/String" \
        else None
    assert camera_info is not None and points is not None and keypoints is not None
    return InputTopics(image, compressed, camera_info, points, keypoints, init)


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


# -- the replay -------------------------------------------------------------------------------------------
def replay_bag(
    bag: str | Path,
    output: str | Path | None = None,
    params: str | Path | None = None,
    png: str | Path | None = None,
    progress: bool = True,
    max_frames: int | None = None,
    config: Any = None,
    fitter: Any = None,
) -> ReplaySummary:
    """Run the frame pipeline over a bag; see the module docstring. Raises ReplayError for unusable bags."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore
    from tqdm import tqdm

    from msg_adapters import RosbagsFactory
    from smplify3d_ros.config import load_config

    t_start = time.perf_counter()
    bag = Path(bag)
    if not bag.exists():
        raise ReplayError(f"{bag} does not exist")
    config = config or load_config(params)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    factory = RosbagsFactory(typestore)
    summary = ReplaySummary(str(bag))
    try:
        reader = Reader(bag)
        reader.open()
    except Exception as e:  # noqa: BLE001 - rosbags raises several types for unreadable bags
        raise ReplayError(f"cannot read {bag}: {e}") from e
    writer = None
    try:
        topics = resolve_topics(reader, typestore, config.node.topics)
        tf = StaticTransforms()
        truth_docs: dict[int, tuple[str, list[TruthBody]]] = {}
        init_docs: list[tuple[int, str]] = []
        pipeline = FramePipeline(config, factory, fitter=fitter, keep_frames=png is not None)
        pipeline.transforms = Transforms(config.node.extrinsic, tf.lookup, log=pipeline.log)
        _read_side_topics(reader, typestore, topics, tf, truth_docs, init_docs, pipeline)

        names = (["image"] if topics.image else []) + ["camera_info", "points", "keypoints"]
        topic_index = {getattr(topics, name): i for i, name in enumerate(names)}
        pending: list[FrameMessages] = []

        def on_set(*msgs: Any) -> None:
            by = dict(zip(names, msgs, strict=True))
            pending.append(FrameMessages(by["camera_info"], by["points"], by["keypoints"], by.get("image"),
                                         topics.compressed))

        sync = ApproximateTimeSync(len(names), config.node.sync.slop_s, config.node.sync.queue_size, on_set)
        if output is not None:
            writer = BagWriter(Path(output), typestore)
            for conn in reader.connections:
                writer.copy_connection(conn)
        evaluator = Evaluator(truth_docs, round(config.node.sync.slop_s * 1e9))
        reporter = DiagnosticsReporter(f"{NODE_NAME}: fitting", "smplify3d_ros")
        best: tuple[tuple[int, float], Any, list] | None = None
        middle = (reader.start_time + reader.end_time) / 2
        last_diag = None
        init_stamps = [s for s, _ in init_docs]
        bar = tqdm(total=reader.message_count, unit="msg", disable=not progress, desc=bag.name, file=sys.stderr)
        for conn, timestamp, raw in reader.messages():
            bar.update(1)
            if writer is not None:
                writer.write_raw(conn, timestamp, raw)
            index = topic_index.get(conn.topic)
            if index is None:
                continue
            sync.add(index, typestore.deserialize_cdr(raw, conn.msgtype))
            while pending:
                msgs = pending.pop(0)
                summary.frames_synced += 1
                stamp_ns = sync.stamp_ns(msgs.image if msgs.image is not None else msgs.keypoints)
                slop = round(config.node.sync.slop_s * 1e9)
                for k, s in enumerate(init_stamps):
                    if abs(s - stamp_ns) <= slop:
                        pipeline.add_init_bodies(init_docs[k][1])
                result = pipeline.process(msgs)
                if not result.ok:
                    continue
                evaluator.add(result)
                summary.frames.append(FrameRecord(
                    result.stamp_ns, [f.person_id for f in result.fits],
                    np.array([f.keypoints3d for f in result.fits]).reshape(-1, 17, 3),
                    np.array([f.params.transl for f in result.fits]).reshape(-1, 3),
                    result.latency.get("total", float("nan"))))
                if writer is not None:
                    for name, msg in result.outputs.items():
                        writer.write(OUTPUT_TOPICS[name], OUTPUT_TYPES[name], msg, timestamp)
                if png is not None and result.frame is not None:  # most people, nearest the middle
                    key = (len(result.fits), -abs(timestamp - middle))
                    if best is None or key > best[0]:
                        best = (key, result.frame, result.fits)
                if writer is not None and (last_diag is None or
                                           timestamp - last_diag >= config.node.diagnostics_period_s * 1e9):
                    last_diag = timestamp
                    values = {**pipeline.diagnostic_values(), **_sync_values(sync)}
                    msg = reporter.message(result.stamp, values, factory)
                    writer.write(DIAGNOSTICS_TOPIC, "diagnostic_msgs/msg/DiagnosticArray", msg, timestamp)
            if max_frames is not None and summary.frames_synced >= max_frames:
                break
        bar.close()
        if writer is not None and last_diag is not None:
            end = max(last_diag, timestamp) + 1
            values = {**pipeline.diagnostic_values(), **_sync_values(sync)}
            writer.write(DIAGNOSTICS_TOPIC, "diagnostic_msgs/msg/DiagnosticArray",
                         reporter.message(end * 1e-9, values, factory), end)
        _fill_summary(summary, pipeline, sync, evaluator)
        if png is not None:
            summary.png = _write_png(Path(png), best, pipeline)
    finally:
        reader.close()
        if writer is not None:
            writer.close()
            summary.output = str(output)
    summary.wall_s = time.perf_counter() - t_start
    return summary


def _read_side_topics(reader: Any, typestore: Any, topics: InputTopics, tf: StaticTransforms,
                      truth_docs: dict, init_docs: list, pipeline: FramePipeline) -> None:
    """One pass over /tf_static, ground truth and init_bodies (small topics) before the replay."""
    wanted = {"/tf_static", GROUND_TRUTH_TOPIC} | ({topics.init_bodies} if topics.init_bodies else set())
    conns = [c for c in reader.connections if c.topic in wanted]
    for conn, _, raw in reader.messages(connections=conns) if conns else ():
        msg = typestore.deserialize_cdr(raw, conn.msgtype)
        if conn.topic == "/tf_static" and conn.msgtype == "tf2_msgs/msg/TFMessage":
            tf.add(msg)
        elif conn.topic == GROUND_TRUTH_TOPIC and conn.msgtype == "std_msgs/msg/String":
            try:
                stamp_ns, frame_id, bodies = parse_ground_truth(msg.data, pipeline.fitter)
            except (ValueError, KeyError, TypeError) as e:
                pipeline.log.warning(f"{GROUND_TRUTH_TOPIC}: ignored a document: {e}")
                continue
            truth_docs[stamp_ns] = (frame_id, bodies)
        elif conn.topic == topics.init_bodies:
            try:
                stamp = json.loads(msg.data)["stamp"]
                stamp_ns = int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"]) if isinstance(stamp, dict) \
                    else round(float(stamp) * 1e9)
            except (ValueError, KeyError, TypeError):
                stamp_ns = -1  # the pipeline's parser reports what is wrong when the frame comes
            init_docs.append((stamp_ns, msg.data))


def _sync_values(sync: ApproximateTimeSync) -> dict[str, int]:
    s = sync.stats
    return {"sync.matched": s.matched, "sync.dropped_unmatched": s.dropped_unmatched,
            "sync.dropped_overflow": s.dropped_overflow, "sync.time_resets": s.time_resets}


def _fill_summary(summary: ReplaySummary, pipeline: FramePipeline, sync: ApproximateTimeSync,
                  evaluator: Evaluator) -> None:
    stats = pipeline.stats
    summary.frames_published = stats.frames_published
    summary.people_fitted = stats.people_fitted
    summary.drops = dict(stats.drops)
    summary.people_dropped = dict(stats.people_dropped)
    summary.flags = dict(stats.flags)
    summary.sync_dropped = sync.stats.dropped
    summary.mean_latency_s = stats.latency["total"].overall_mean
    summary.ground_truth_frames = evaluator.frames
    summary.people_evaluated = evaluator.people
    summary.people_missed = evaluator.missed
    if evaluator.joint_errors:
        summary.mpjpe_mm = float(np.mean(evaluator.joint_errors))
    if evaluator.vertex_errors:
        summary.pve_mm = float(np.mean(evaluator.vertex_errors))


def _write_png(path: Path, best: Any, pipeline: FramePipeline) -> str | None:
    import cv2

    from smplify3d_ros.overlay import overlay_image, top_view

    if best is None:
        pipeline.log.warning(f"no fitted frame: {path} not written")
        return None
    _, frame, fits = best
    if pipeline.node.output_frame and pipeline.node.output_frame != frame.frame_id:
        pipeline.log.warning("output_frame is not the camera frame: the overlay needs camera-frame fits")
        return None
    image = overlay_image(frame, fits, pipeline.fitter.faces_np)
    image = np.hstack([image, top_view(frame, fits, image.shape[0])])
    path.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
        raise ReplayError(f"could not write {path}")
    return str(path)


# -- command line -----------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", metavar="IN", help="rosbag2 recording: a bag directory, or a .mcap / .db3 file")
    parser.add_argument("-o", "--output", metavar="OUT.mcap",
                        help="output bag: a .mcap file, or a directory name for a rosbag2 bag directory")
    parser.add_argument("--params", metavar="FILE", default=None,
                        help="params profile name (e.g. ouster64) or YAML path; default: jackal_vlp16")
    parser.add_argument("--png", metavar="FILE", help="write a picture of the fit of one representative frame")
    parser.add_argument("--max-frames", type=int, default=None, help="stop after this many synchronized frames")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """`smplify3d replay`: 0 on success, 1 when nothing could be fitted, 2 for an unusable bag or params."""
    import logging

    from smplify3d_ros.config import ConfigError

    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    try:
        summary = replay_bag(args.bag, args.output, args.params, args.png, progress=not args.no_progress,
                             max_frames=args.max_frames)
    except (ReplayError, ConfigError) as e:
        print(f"smplify3d replay: {e}", file=sys.stderr)
        return 2
    print(summary.text())
    return 0 if summary.frames_published > 0 else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="smplify3d replay", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
