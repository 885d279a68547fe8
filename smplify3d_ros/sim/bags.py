"""`smplify3d make-bags`: small synthetic rosbag2 recordings of a Jackal with a VLP-16, with ground truth.

Each bag is one `simulate_sequence` scenario at 10 Hz, written the way the robot's drivers would publish
it (topics, frames, field layouts: docs/bags.md), plus the simulator's ground truth and its simulated
image-HMR estimate as `~/bodies` JSON documents. Generation is deterministic: the same seeds give the same
messages. MCAP bags use MCAP's zstd chunk compression (read natively by ROS 2's MCAP storage plugin and by
rosbags); the sqlite3 bag is uncompressed, as `ros2 bag record -s sqlite3` writes it.

`read_ground_truth(bag)` reads the ground truth back, for tests and for scoring replays.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

SIM_EPOCH_NS = 1_700_000_000 * 1_000_000_000  # stamp of a sequence's t = 0 (2023-11-14 22:13:20 UTC)
RATE_HZ = 10.0
VIEW_WIDTH_DEG = 180.0  # velodyne driver `view_width` (view_direction 0): the forward half of each scan
VERTEX_DECIMALS = 3  # ground-truth vertices in millimetres: keeps a body near 70 kB in a bag
GROUND_TRUTH_TOPIC = "/ground_truth/bodies"
HMR_TOPIC = "/hmr/bodies"
TF_STATIC_TOPIC = "/tf_static"
BASE_FRAME = "base_link"
BAGS_DIR = Path(__file__).resolve().parents[2] / "bags"
MAX_BAG_BYTES = 10 * 1024 * 1024


@dataclass(frozen=True)
class BagSpec:
    """One recording: a `simulate_sequence` scenario, its seed and length, and how it is stored."""

    name: str  # bag directory name under bags/
    scenario: str  # key of `sim.sequence.scenarios`
    seed: int
    n_frames: int
    storage: str = "mcap"  # "mcap" (zstd chunk compression) or "sqlite3" (uncompressed)
    raw_image: bool = True  # also write sensor_msgs/Image next to the CompressedImage


BAGS: tuple[BagSpec, ...] = (
    BagSpec("walk", "walk", seed=3, n_frames=25),
    BagSpec("crossing", "crossing", seed=0, n_frames=20),
    BagSpec("close", "close", seed=0, n_frames=25),
    BagSpec("far", "far", seed=0, n_frames=25),
    BagSpec("walk_sqlite3", "walk", seed=3, n_frames=6, storage="sqlite3"),
)


@dataclass(frozen=True)
class BagTopics:
    """Topic names of a synthetic bag: the node's default input topics (params/base/node.yaml)."""

    image: str
    compressed_image: str
    camera_info: str
    points: str
    keypoints: str
    lidar_frame: str
    camera_frame: str

    @classmethod
    def from_config(cls, node_config: Any) -> BagTopics:
        topics, ext = node_config.topics, node_config.extrinsic
        image = topics.image or "/camera/color/image_raw"
        compressed = topics.compressed_image or f"{image}/compressed"  # image_transport's naming
        return cls(
            image,
            compressed,
            topics.camera_info,
            topics.points,
            topics.keypoints,
            ext.lidar_frame,
            ext.camera_frame,
        )


# -- ground truth -----------------------------------------------------------------------------------------
@dataclass
class GroundTruthBody:
    """One simulated person at one stamp, camera optical frame (`frame_id` of the document)."""

    person_id: int
    params: Any  # smplify3d_ros.types.BodyParams
    keypoints3d: np.ndarray  # (17, 3) float64 COCO-17, m
    vertices: np.ndarray  # (V, 3) float64, m (rounded to 1 mm)
    detected: bool  # whether the keypoint topic has this person at this stamp
    visible_fraction: float  # fraction of the silhouette the camera sees (occluders, image border)
    lidar_points: int  # returns on this person in the published scan


def _view_mask(points_lidar: np.ndarray, view_width_deg: float) -> np.ndarray:
    """Points within the driver's forward view (`view_direction` 0, `view_width`)."""
    azimuth = np.degrees(np.arctan2(points_lidar[:, 1], points_lidar[:, 0]))
    return np.abs(azimuth) <= view_width_deg / 2.0


def truth_document(sim: Any, stamp_ns: int, frame_id: str, joint_names: list[str], keep: np.ndarray) -> str:
    """The `/ground_truth/bodies` JSON: the `~/bodies` schema plus `vertices`, `detected`,
    `visible_fraction`, `lidar_points` per body (docs/bags.md)."""
    from msg_adapters.bodies import fits_to_bodies_json
    from smplify3d_ros.types import BodyFit, FitQuality

    detected = {int(i) for i in sim.frame.person_ids}
    labels = np.asarray(sim.point_labels)[keep]
    fits, extras = [], []
    for person in sim.people:
        n_points = int(np.count_nonzero(labels == person.person_id))
        quality = FitQuality(float("nan"), float("nan"), n_points, [], False, float("nan"))
        fits.append(
            BodyFit(
                person.person_id,
                person.params,
                joint_names,
                person.vertices,
                person.keypoints3d,
                person.joints,
                quality,
            )
        )
        extras.append(
            {
                "vertices": np.round(person.vertices.astype(np.float64), VERTEX_DECIMALS).tolist(),
                "detected": person.person_id in detected,
                "visible_fraction": round(float(sim.visible_fraction.get(person.person_id, 0.0)), 4),
                "lidar_points": n_points,
            }
        )
    doc = json.loads(fits_to_bodies_json(fits, _stamp(stamp_ns), frame_id))
    for body, extra in zip(doc["bodies"], extras, strict=True):
        body.update(extra)
    return json.dumps(doc, separators=(",", ":"))


def hmr_document(sim: Any, model: Any, stamp_ns: int, frame_id: str) -> str:
    """The simulated image-HMR estimate of every detected person as a `~/bodies` document (usable as the
    node's `init_bodies` input)."""
    import torch

    from msg_adapters.bodies import fits_to_bodies_json
    from smplify3d_ros.types import BodyFit, FitQuality

    fits = []
    dtype = model.anat_frames.dtype
    for pid in np.asarray(sim.frame.person_ids).tolist():
        params = sim.hmr_init.get(int(pid))
        if params is None:
            continue
        with torch.no_grad():
            out = model(
                *(
                    torch.as_tensor(a, dtype=dtype)[None]
                    for a in (params.shape, params.pose, params.root_orient, params.transl)
                )
            )
        quality = FitQuality(float("nan"), float("nan"), 0, [], False, float("nan"))
        fits.append(
            BodyFit(
                int(pid),
                params,
                list(model.joint_names),
                out.vertices[0].numpy(),
                out.keypoints[0].numpy(),
                out.joints[0].numpy(),
                quality,
            )
        )
    return fits_to_bodies_json(fits, _stamp(stamp_ns), frame_id)


def _stamp(stamp_ns: int) -> SimpleNamespace:
    """A stamp-like object (`sec`, `nanosec`): keeps nanoseconds exact where float seconds would not."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return SimpleNamespace(sec=sec, nanosec=nanosec)


def parse_truth_document(text: str | bytes) -> tuple[int, str, list[GroundTruthBody]]:
    """A `/ground_truth/bodies` document -> (stamp ns, frame id, bodies)."""
    from msg_adapters.bodies import bodies_json_to_params
    from smplify3d_ros.keypoints import COCO17_NAMES

    doc = json.loads(text)
    entries = doc.get("bodies", [])
    joint_names = list(entries[0]["pose"]) if entries else []
    _, frame_id, params = bodies_json_to_params(text, joint_names)
    stamp = doc["stamp"]
    stamp_ns = int(stamp["sec"]) * 1_000_000_000 + int(stamp["nanosec"])
    bodies = []
    for entry in entries:
        pid = int(entry["id"])
        joints3d = entry["joints3d"]
        bodies.append(
            GroundTruthBody(
                person_id=pid,
                params=params[pid],
                keypoints3d=np.array([joints3d[name] for name in COCO17_NAMES], dtype=np.float64),
                vertices=np.asarray(entry["vertices"], dtype=np.float64).reshape(-1, 3),
                detected=bool(entry["detected"]),
                visible_fraction=float(entry["visible_fraction"]),
                lidar_points=int(entry["lidar_points"]),
            )
        )
    return stamp_ns, frame_id, bodies


def read_ground_truth(
    bag_path: str | Path, topic: str = GROUND_TRUTH_TOPIC
) -> dict[int, list[GroundTruthBody]]:
    """Ground truth of a bag (MCAP or sqlite3 rosbag2 directory): {stamp ns: bodies}, stamps in
    ascending order. The stamp is the image's (header stamp of every input message of that frame)."""
    from rosbags.highlevel import AnyReader

    out: dict[int, list[GroundTruthBody]] = {}
    with AnyReader([Path(bag_path)]) as reader:
        connections = [c for c in reader.connections if c.topic == topic]
        if not connections:
            raise ValueError(f"{bag_path}: no {topic} topic (topics: {sorted(reader.topics)})")
        for connection, _, raw in reader.messages(connections=connections):
            stamp_ns, _, bodies = parse_truth_document(reader.deserialize(raw, connection.msgtype).data)
            out[stamp_ns] = bodies
    return dict(sorted(out.items()))


# -- messages ---------------------------------------------------------------------------------------------
def tf_static_message(factory: Any, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]]) -> Any:
    """tf2_msgs/TFMessage of (parent, child, T_parent_child) transforms."""
    from scipy.spatial.transform import Rotation

    items = []
    for parent, child, T in transforms:
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat(canonical=True)  # w >= 0
        items.append(
            factory.make(
                "geometry_msgs/msg/TransformStamped",
                header=factory.header(_stamp_msg(factory, stamp_ns), parent),
                child_frame_id=child,
                transform=factory.make(
                    "geometry_msgs/msg/Transform",
                    translation=factory.make("geometry_msgs/msg/Vector3", x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                    rotation=factory.make("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
                ),
            )
        )
    return factory.make("tf2_msgs/msg/TFMessage", transforms=items)


def _stamp_msg(factory: Any, stamp_ns: int) -> Any:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return factory.make("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def velodyne_cloud(
    factory: Any, stamp: Any, frame_id: str, points: np.ndarray, fields: dict[str, np.ndarray]
) -> Any:
    """PointCloud2 laid out like the ROS 2 velodyne driver's XYZIRT cloud: x, y, z, intensity (float32),
    ring (uint16), time (float32, s after the stamp); unorganized, 22-byte points."""
    from msg_adapters.pointcloud2 import make_pointcloud2

    points = np.asarray(points, dtype=np.float32)
    return make_pointcloud2(
        stamp,
        frame_id,
        {
            "x": points[:, 0],
            "y": points[:, 1],
            "z": points[:, 2],
            "intensity": np.asarray(fields["intensity"], dtype=np.float32),
            "ring": np.asarray(fields["ring"], dtype=np.uint16),
            "time": np.asarray(fields["time"], dtype=np.float32),
        },
        factory,
    )


def _tf_static_qos() -> list[Any]:
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)
    return [
        Qos(
            QosHistory.KEEP_LAST,
            1,
            QosReliability.RELIABLE,
            QosDurability.TRANSIENT_LOCAL,
            zero,
            zero,
            QosLiveliness.AUTOMATIC,
            zero,
            False,
        )
    ]


def frame_messages(
    sim: Any, spec: BagSpec, topics: BagTopics, factory: Any, model: Any, stamp_ns: int
) -> Iterator[tuple[str, str, Any]]:
    """(topic, msgtype, message) of one simulated frame, in publishing order."""
    from msg_adapters import camera_model_to_msg, numpy_to_compressed, numpy_to_image, write_keypoints

    frame = sim.frame
    stamp = _stamp_msg(factory, stamp_ns)
    cam = topics.camera_frame
    yield (
        topics.camera_info,
        "sensor_msgs/msg/CameraInfo",
        camera_model_to_msg(frame.camera, stamp, cam, factory),
    )
    if spec.raw_image:
        yield topics.image, "sensor_msgs/msg/Image", numpy_to_image(frame.image, "rgb8", stamp, cam, factory)
    yield (
        topics.compressed_image,
        "sensor_msgs/msg/CompressedImage",
        numpy_to_compressed(frame.image, stamp, cam, factory, quality=90),
    )
    keep = _view_mask(frame.points_lidar, VIEW_WIDTH_DEG)
    fields = {name: values[keep] for name, values in sim.lidar_fields.items()}
    yield (
        topics.points,
        "sensor_msgs/msg/PointCloud2",
        velodyne_cloud(factory, stamp, topics.lidar_frame, frame.points_lidar[keep], fields),
    )
    yield (
        topics.keypoints,
        "sensor_msgs/msg/PointCloud2",
        write_keypoints(frame.keypoints, frame.person_ids, stamp, cam, factory),
    )
    string = "std_msgs/msg/String"
    yield HMR_TOPIC, string, factory.make(string, data=hmr_document(sim, model, stamp_ns, cam))
    truth = truth_document(sim, stamp_ns, cam, list(model.joint_names), keep)
    yield GROUND_TRUTH_TOPIC, string, factory.make(string, data=truth)


# -- writing ----------------------------------------------------------------------------------------------
def write_bag(spec: BagSpec, out_dir: Path, config: Any | None = None, progress: bool = True) -> Path:
    """Simulate `spec` and write it to `out_dir / spec.name` (must not exist). Returns the bag directory."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
    from tqdm import tqdm

    from msg_adapters import RosbagsFactory
    from smplify3d_ros.body import load_body_model
    from smplify3d_ros.config import load_config
    from smplify3d_ros.sim.scene import make_mount
    from smplify3d_ros.sim.world import simulate_sequence

    config = config or load_config()
    topics = BagTopics.from_config(config.node)
    factory = RosbagsFactory()
    typestore = factory.typestore
    model = load_body_model(config.sim.body_model)
    mount = make_mount(config.sim.mount)
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

    frames = simulate_sequence(spec.seed, config.sim, spec.scenario, spec.n_frames, RATE_HZ, sensor="vlp16")
    with writer:
        tf = tf_static_message(
            factory,
            SIM_EPOCH_NS,
            [
                (BASE_FRAME, topics.lidar_frame, mount.T_world_lidar),
                (topics.lidar_frame, topics.camera_frame, np.linalg.inv(mount.T_cam_lidar)),
            ],
        )
        write(TF_STATIC_TOPIC, "tf2_msgs/msg/TFMessage", tf, SIM_EPOCH_NS, _tf_static_qos())
        bar = tqdm(frames, total=spec.n_frames, desc=spec.name, unit="frame", disable=not progress)
        for sim in bar:
            if not np.allclose(sim.frame.T_cam_lidar, mount.T_cam_lidar):
                raise RuntimeError("the simulator's extrinsic differs from its mount's")
            stamp_ns = SIM_EPOCH_NS + round(sim.frame.stamp * 1e9)
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
    parser.add_argument("--profile", default=None, help="params profile name or YAML path")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from smplify3d_ros.config import load_config

    specs = [s for s in BAGS if args.only is None or s.name in args.only]
    unknown = set(args.only or ()) - {s.name for s in BAGS}
    if unknown:
        print(f"unknown bag(s) {sorted(unknown)}; known: {', '.join(s.name for s in BAGS)}", file=sys.stderr)
        return 2
    config = load_config(args.profile)
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
        write_bag(spec, args.out, config, progress=not args.no_progress)
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
