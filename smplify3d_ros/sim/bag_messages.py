"""The messages of one simulated frame, laid out as a Jackal's drivers publish them (docs/bags.md).

`frame_messages` yields, in publishing order: camera info, the raw and compressed image, the VLP-16
cloud (velodyne driver layout: x, y, z, intensity, ring, time), the keypoints, the simulated image-HMR
estimate as a `~/bodies` document (the node's `init_bodies` input) and the ground truth.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np

from msg_adapters import (
    camera_model_to_msg,
    make_pointcloud2,
    numpy_to_compressed,
    numpy_to_image,
    write_keypoints,
)
from smplify3d_ros.eval.truth import GROUND_TRUTH_TOPIC, TruthBody, TruthFrame, truth_document
from smplify3d_ros.geometry import matrix_to_quaternion
from smplify3d_ros.runtime.config import NodeConfig

HMR_TOPIC = "/hmr/bodies"
TF_STATIC_TOPIC = "/tf_static"
BASE_FRAME = "base_link"
VIEW_WIDTH_DEG = 180.0  # velodyne driver `view_width` (view_direction 0): the forward half of each scan


@dataclass(frozen=True)
class BagSpec:
    """One recording: a `simulate_sequence` scenario, its seed and length, and how it is stored."""

    name: str  # bag directory name under bags/
    scenario: str  # key of `sim.sequence.scenarios`
    seed: int
    n_frames: int
    storage: str = "mcap"  # "mcap" (zstd chunk compression) or "sqlite3" (uncompressed)
    raw_image: bool = True  # also write sensor_msgs/Image next to the CompressedImage
    track_ids: bool = True  # the keypoints carry the detector's track ids (False: person -1, anonymous)
    view_width_deg: float = VIEW_WIDTH_DEG  # the velodyne driver's `view_width` (forward, centred)
    truth_vertices: bool = True  # the ground truth holds each body's mesh (False: parameters and joints)


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
    def from_config(cls, node_config: NodeConfig) -> BagTopics:
        topics, ext = node_config.topics, node_config.extrinsic
        image = topics.image or "/camera/color/image_raw"
        compressed = topics.compressed_image or f"{image}/compressed"  # image_transport's naming
        return cls(image, compressed, topics.camera_info, topics.points, topics.keypoints, ext.lidar_frame,
                   ext.camera_frame)


def view_mask(points_lidar: np.ndarray, view_width_deg: float = VIEW_WIDTH_DEG) -> np.ndarray:
    """Points within the driver's forward view (`view_direction` 0, `view_width`)."""
    azimuth = np.degrees(np.arctan2(points_lidar[:, 1], points_lidar[:, 0]))
    return np.abs(azimuth) <= view_width_deg / 2.0


def truth_frame(sim: Any, stamp_ns: int, frame_id: str, keep: np.ndarray, vertices: bool = True) -> TruthFrame:
    """The ground truth of a simulated frame: every person, detected or not, with the returns on it in
    the published scan (`keep`: the points the cloud holds), with or without the meshes."""
    detected = {int(i) for i in sim.frame.person_ids}
    labels = np.asarray(sim.point_labels)[keep]
    return TruthFrame(stamp_ns, frame_id, [
        TruthBody(
            person_id=p.person_id, params=p.params, keypoints3d=p.keypoints3d,
            vertices=p.vertices if vertices else None,
            detected=p.person_id in detected, visible_fraction=float(sim.visible_fraction.get(p.person_id, 0.0)),
            lidar_points=int(np.count_nonzero(labels == p.person_id)),
        )
        for p in sim.people
    ])


def hmr_frame(sim: Any, model: Any, stamp_ns: int, frame_id: str) -> TruthFrame:
    """The simulated image-HMR estimate of every detected person, with its 3D keypoints."""
    ids = [int(pid) for pid in np.asarray(sim.frame.person_ids).tolist() if int(pid) in sim.hmr_init]
    params = [sim.hmr_init[pid] for pid in ids]
    posed = model.posed(params)
    return TruthFrame(stamp_ns, frame_id, [
        TruthBody(pid, p, keypoints3d=body.keypoints3d) for pid, p, body in zip(ids, params, posed, strict=True)
    ])


def stamp_msg(factory: Any, stamp_ns: int) -> Any:
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return factory.make("builtin_interfaces/msg/Time", sec=sec, nanosec=nanosec)


def tf_static_message(factory: Any, stamp_ns: int, transforms: list[tuple[str, str, np.ndarray]]) -> Any:
    """tf2_msgs/TFMessage of (parent, child, T_parent_child) transforms."""
    items = []
    for parent, child, T in transforms:
        x, y, z, w = matrix_to_quaternion(T[:3, :3])
        items.append(factory.make(
            "geometry_msgs/msg/TransformStamped",
            header=factory.header(stamp_msg(factory, stamp_ns), parent),
            child_frame_id=child,
            transform=factory.make(
                "geometry_msgs/msg/Transform",
                translation=factory.make("geometry_msgs/msg/Vector3", x=T[0, 3], y=T[1, 3], z=T[2, 3]),
                rotation=factory.make("geometry_msgs/msg/Quaternion", x=x, y=y, z=z, w=w),
            ),
        ))
    return factory.make("tf2_msgs/msg/TFMessage", transforms=items)


def velodyne_cloud(factory: Any, stamp: Any, frame_id: str, points: np.ndarray, fields: dict[str, np.ndarray]) -> Any:
    """PointCloud2 laid out like the ROS 2 velodyne driver's XYZIRT cloud: x, y, z, intensity (float32),
    ring (uint16), time (float32, s after the stamp); unorganized, 22-byte points."""
    points = np.asarray(points, dtype=np.float32)
    return make_pointcloud2(stamp, frame_id, {
        "x": points[:, 0], "y": points[:, 1], "z": points[:, 2],
        "intensity": np.asarray(fields["intensity"], dtype=np.float32),
        "ring": np.asarray(fields["ring"], dtype=np.uint16),
        "time": np.asarray(fields["time"], dtype=np.float32),
    }, factory)


def frame_messages(
    sim: Any, spec: BagSpec, topics: BagTopics, factory: Any, model: Any, stamp_ns: int
) -> Iterator[tuple[str, str, Any]]:
    """(topic, msgtype, message) of one simulated frame, in publishing order."""
    frame = sim.frame
    stamp = stamp_msg(factory, stamp_ns)
    cam = topics.camera_frame
    yield topics.camera_info, "sensor_msgs/msg/CameraInfo", camera_model_to_msg(frame.camera, stamp, cam, factory)
    if spec.raw_image:
        yield topics.image, "sensor_msgs/msg/Image", numpy_to_image(frame.image, "rgb8", stamp, cam, factory)
    yield (topics.compressed_image, "sensor_msgs/msg/CompressedImage",
           numpy_to_compressed(frame.image, stamp, cam, factory, quality=90))
    keep = view_mask(frame.points_lidar, spec.view_width_deg)
    fields = {name: values[keep] for name, values in sim.lidar_fields.items()}
    yield (topics.points, "sensor_msgs/msg/PointCloud2",
           velodyne_cloud(factory, stamp, topics.lidar_frame, frame.points_lidar[keep], fields))
    ids = frame.person_ids if spec.track_ids else np.full(len(frame.person_ids), -1, dtype=np.int64)
    yield (topics.keypoints, "sensor_msgs/msg/PointCloud2", write_keypoints(frame.keypoints, ids, stamp, cam, factory))
    string, joint_names = "std_msgs/msg/String", list(model.joint_names)
    hmr = truth_document(hmr_frame(sim, model, stamp_ns, cam), joint_names)
    yield HMR_TOPIC, string, factory.make(string, data=hmr)
    truth = truth_document(truth_frame(sim, stamp_ns, cam, keep, spec.truth_vertices), joint_names)
    yield GROUND_TRUTH_TOPIC, string, factory.make(string, data=truth)
