"""`smplify3d make-bags`: small synthetic rosbag2 recordings of a Jackal with a VLP-16, with ground truth.

Each bag is one `simulate_sequence` scenario at 10 Hz, written the way the robot's drivers would publish
it (topics, frames, field layouts: docs/bags.md, `bag_messages`), plus the simulator's ground truth and
its simulated image-HMR estimate as `~/bodies` JSON documents. Generation is deterministic: the same seeds
give the same messages. MCAP bags use MCAP's zstd chunk compression (read natively by ROS 2's MCAP storage
plugin and by rosbags); the sqlite3 bag is uncompressed, as `ros2 bag record -s sqlite3` writes it.

`read_ground_truth(bag)` reads the ground truth back, for tests and for scoring replays.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from smplify3d_ros.eval.truth import GROUND_TRUTH_TOPIC, TruthBody, parse_truth_document
from smplify3d_ros.geometry import invert
from smplify3d_ros.sim.bag_messages import (  # noqa: F401 - HMR_TOPIC, BagTopics: the bags' layout, for readers
    BASE_FRAME,
    HMR_TOPIC,
    TF_STATIC_TOPIC,
    BagSpec,
    BagTopics,
    frame_messages,
    tf_static_message,
)

SIM_EPOCH_NS = 1_700_000_000 * 1_000_000_000  # stamp of a sequence's t = 0 (2023-11-14 22:13:20 UTC)
RATE_HZ = 10.0
BAGS_DIR = Path(__file__).resolve().parents[2] / "bags"
MAX_BAG_BYTES = 10 * 1024 * 1024

BAGS: tuple[BagSpec, ...] = (
    BagSpec("walk", "walk", seed=3, n_frames=25),
    BagSpec("crossing", "crossing", seed=0, n_frames=20),
    BagSpec("close", "close", seed=0, n_frames=25),
    BagSpec("far", "far", seed=0, n_frames=25),
    BagSpec("walk_sqlite3", "walk", seed=3, n_frames=6, storage="sqlite3"),
    # tracking sequences: people walking, stopping, turning and crossing for 6 s, the detector giving track
    # ids in one and none in the other (compressed images only, the camera's side of the scan, no meshes)
    BagSpec("people_ids", "people", seed=5, n_frames=60, raw_image=False, view_width_deg=110.0,
            truth_vertices=False),
    BagSpec("people_anonymous", "people", seed=8, n_frames=60, raw_image=False, track_ids=False,
            view_width_deg=110.0, truth_vertices=False),
)


def read_ground_truth(bag_path: str | Path, topic: str = GROUND_TRUTH_TOPIC) -> dict[int, list[TruthBody]]:
    """Ground truth of a bag (MCAP or sqlite3 rosbag2 directory): {stamp ns: bodies}, stamps in
    ascending order. The stamp is the image's (header stamp of every input message of that frame)."""
    from rosbags.highlevel import AnyReader

    out: dict[int, list[TruthBody]] = {}
    with AnyReader([Path(bag_path)]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            raise ValueError(f"{bag_path}: no {topic} topic (topics: {sorted(reader.topics)})")
        for connection, _, raw in reader.messages(connections=connections):
            truth = parse_truth_document(reader.deserialize(raw, connection.msgtype).data)
            out[truth.stamp_ns] = truth.bodies
    return dict(sorted(out.items()))


# -- writing ----------------------------------------------------------------------------------------------
def _tf_static_qos() -> list[Any]:
    """The QoS a /tf_static publisher offers (reliable, transient local, depth 1), for the bag's metadata."""
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)
    return [Qos(QosHistory.KEEP_LAST, 1, QosReliability.RELIABLE, QosDurability.TRANSIENT_LOCAL, zero, zero,
                QosLiveliness.AUTOMATIC, zero, False)]


def write_bag(spec: BagSpec, out_dir: Path, profile: str | None = None, progress: bool = True) -> Path:
    """Simulate `spec` and write it to `out_dir / spec.name` (must not exist). Returns the bag directory."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from tqdm import tqdm

    from msg_adapters import RosbagsFactory
    from smplify3d_ros.body import load_body_model
    from smplify3d_ros.runtime.config import load_node_config
    from smplify3d_ros.sim.config import load_sim_config
    from smplify3d_ros.sim.scene import make_mount
    from smplify3d_ros.sim.world import simulate_sequence

    sim_config = load_sim_config(profile)
    topics = BagTopics.from_config(load_node_config(profile))
    factory = RosbagsFactory()
    typestore = factory.typestore
    model = load_body_model(sim_config.body_model)
    mount = make_mount(sim_config.mount)
    path = out_dir / spec.name
    plugin = StoragePlugin.MCAP if spec.storage == "mcap" else StoragePlugin.SQLITE3
    writer = Writer(path, version=9, storage_plugin=plugin)
    if spec.storage == "mcap":
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    writer.set_custom_data("smplify3d.scenario", spec.scenario)
    writer.set_custom_data("smplify3d.seed", str(spec.seed))
    connections: dict[str, Any] = {}

    def write(topic: str, msgtype: str, msg: Any, stamp_ns: int, qos: list[Any] | None = None) -> None:
        if topic not in connections:
            connections[topic] = writer.add_connection(
                topic, msgtype, typestore=typestore, offered_qos_profiles=qos or ()
            )
        writer.write(connections[topic], stamp_ns, typestore.serialize_cdr(msg, msgtype))

    frames = simulate_sequence(spec.seed, sim_config, spec.scenario, spec.n_frames, RATE_HZ, sensor="vlp16")
    with writer:
        tf = tf_static_message(
            factory,
            SIM_EPOCH_NS,
            [
                (BASE_FRAME, topics.lidar_frame, mount.T_world_lidar),
                (topics.lidar_frame, topics.camera_frame, invert(mount.T_cam_lidar)),
            ],
        )
        write(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", tf, SIM_EPOCH_NS, _tf_static_qos())
        bar = tqdm(frames, total=spec.n_frames, desc=spec.name, unit="frame", disable=not progress)
        for sim in bar:
            if not np.allclose(sim.frame.T_cam_lidar, mount.T_cam_lidar):
                raise RuntimeError("the simulator's extrinsic differs from its mount's")
            stamp_ns = SIM_EPOCH_NS + sim.frame.stamp_ns
            for topic, msgtype, msg in frame_messages(sim, spec, topics, factory, model, stamp_ns):
                write(topic, msgtype, msg, stamp_ns)
    return path


def bag_size(path: Path) -> int:
    return sum(f.stat().st_size for f in Path(path).rglob("*") if f.is_file())


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=BAGS_DIR, help=f"output directory (default: {BAGS_DIR})")
    parser.add_argument(
        "--only",
        nargs="*",
        default=None,
        metavar="NAME",
        help=f"bags to write (default: all of {', '.join(s.name for s in BAGS)})",
    )
    parser.add_argument("--force", action="store_true", help="replace bags that exist")
    parser.add_argument("--params", metavar="PROFILE", default=None, help="params profile name or YAML path")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    specs = [s for s in BAGS if args.only is None or s.name in args.only]
    unknown = set(args.only or ()) - {s.name for s in BAGS}
    if unknown:
        print(f"smplify3d make-bags: unknown bag(s) {sorted(unknown)}; known: {', '.join(s.name for s in BAGS)}",
              file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    status = 0
    for spec in specs:
        path = args.out / spec.name
        if path.exists():
            if not args.force:
                print(f"{path} exists (use --force to replace it)", file=sys.stderr)
                status = 1
                continue
            shutil.rmtree(path)
        write_bag(spec, args.out, args.params, progress=not args.no_progress)
        size = bag_size(path)
        note = "" if size < MAX_BAG_BYTES else "  (over the 10 MB budget)"
        print(
            f"{path}: {spec.scenario}, {spec.n_frames} frames, {spec.storage}, {size / 2**20:.2f} MiB{note}"
        )
    return status


def main() -> int:  # `python -m smplify3d_ros.sim.bags`
    parser = argparse.ArgumentParser(prog="smplify3d make-bags", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args())


if __name__ == "__main__":
    raise SystemExit(main())
