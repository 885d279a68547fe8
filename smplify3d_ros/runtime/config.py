"""Settings of the drivers (the ROS node and the bag replay): the `node` section, params/base/node.yaml.

Topics, synchronization, the LiDAR-camera extrinsic, the output frame and what is published: what turns
messages into frames and fits into messages. The method's own settings are the core configuration
(`smplify3d_ros.config`). The dataclasses declare types and valid ranges only; every value, with its
meaning, lives in the YAML file. The node also exposes each value as a ROS parameter named by its key
path in the section (`sync.slop_s`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from smplify3d_ros.geometry import invert, quaternion_to_matrix, rpy_to_matrix, transform
from smplify3d_ros.settings import require, section


def _is_topic(name: str) -> bool:
    return not any(c.isspace() for c in name)


@dataclass
class TopicsConfig:
    image: str  # sensor_msgs/Image; "" with compressed_image "" too: no image input
    compressed_image: str  # sensor_msgs/CompressedImage used instead of `image` when set
    camera_info: str  # sensor_msgs/CameraInfo
    points: str  # sensor_msgs/PointCloud2 LiDAR scan
    keypoints: str  # sensor_msgs/PointCloud2 keypoint encoding
    init_bodies: str  # std_msgs/String bodies JSON; "" disables the input

    def __post_init__(self) -> None:
        for name in ("image", "compressed_image", "camera_info", "points", "keypoints", "init_bodies"):
            require(_is_topic(getattr(self, name)), f"{name} must be a topic name without spaces")
        for name in ("camera_info", "points", "keypoints"):
            require(getattr(self, name) != "", f"{name} must be set")

    @property
    def image_topic(self) -> str:
        """The image topic subscribed to ('' when the node runs without images)."""
        return self.compressed_image or self.image

    @property
    def compressed(self) -> bool:
        return bool(self.compressed_image)


@dataclass
class SyncConfig:
    slop_s: float  # largest stamp difference within one synchronized set, s
    queue_size: int  # messages kept per input while waiting for a match
    use_message_filters: bool  # message_filters when importable, else the built-in synchronizer
    time_reset_s: float  # a stamp this far behind the last frame's is a clock reset

    def __post_init__(self) -> None:
        require(0.0 < self.slop_s <= 5.0, "slop_s must be in (0, 5]")
        require(1 <= self.queue_size <= 1000, "queue_size must be in [1, 1000]")
        require(self.time_reset_s > 0.0, "time_reset_s must be > 0")


@dataclass
class ExtrinsicConfig:
    """The LiDAR-camera extrinsic as TF states it: the pose of `camera_frame` in `lidar_frame`."""

    use_tf: bool  # look the transform up in TF when tf2_ros is importable
    tf_timeout_s: float  # how long one TF lookup may wait, s
    lidar_frame: str  # TF parent of the static extrinsic
    camera_frame: str  # TF child (the camera optical frame)
    xyz: tuple[float, float, float]  # camera origin in the LiDAR frame, m
    rotation: Literal["rpy", "quaternion"]  # which of the two fields below holds the rotation
    rpy: tuple[float, float, float]  # roll, pitch, yaw (rad; fixed axes, ROS convention)
    quaternion: tuple[float, float, float, float]  # x, y, z, w

    def __post_init__(self) -> None:
        require(self.tf_timeout_s >= 0.0, "tf_timeout_s must be >= 0")
        require(self.lidar_frame != "" and self.camera_frame != "", "lidar_frame and camera_frame must be set")
        require(all(math.isfinite(v) for v in (*self.xyz, *self.rpy, *self.quaternion)),
                "xyz, rpy and quaternion must be finite")
        if self.rotation == "quaternion":
            norm = math.sqrt(sum(v * v for v in self.quaternion))
            require(abs(norm - 1.0) < 1e-3, f"quaternion must have unit norm, got {norm:.6f}")

    def T_lidar_cam(self) -> np.ndarray:
        """(4, 4) camera-frame points -> LiDAR frame (the TF transform parent lidar, child camera)."""
        R = rpy_to_matrix(self.rpy) if self.rotation == "rpy" else quaternion_to_matrix(self.quaternion)
        return transform(R, self.xyz)

    def T_cam_lidar(self) -> np.ndarray:
        """(4, 4) LiDAR-frame points -> camera frame (what `Frame.T_cam_lidar` holds)."""
        return invert(self.T_lidar_cam())


@dataclass
class PublishConfig:
    markers: bool  # ~/markers
    joints: bool  # ~/joints
    body_points: bool  # ~/body_points
    people: bool  # ~/people
    bodies: bool  # ~/bodies
    mesh_max_triangles: int  # mesh marker decimation (0: every triangle)
    body_points_stride: int  # every n-th vertex on ~/body_points
    marker_alpha: float  # mesh marker opacity

    def __post_init__(self) -> None:
        require(self.mesh_max_triangles >= 0, "mesh_max_triangles must be >= 0 (0: all)")
        require(self.body_points_stride >= 1, "body_points_stride must be >= 1")
        require(0.0 <= self.marker_alpha <= 1.0, "marker_alpha must be in [0, 1]")


@dataclass
class NodeConfig:
    topics: TopicsConfig
    keypoint_format: str  # name in msg_adapters.keypoints.KEYPOINT_FORMATS
    sync: SyncConfig
    extrinsic: ExtrinsicConfig
    output_frame: str  # frame of published geometry; "" = the camera optical frame
    worker_queue_size: int  # frames waiting for the fitting worker (latest-frame policy)
    publish: PublishConfig
    diagnostics_period_s: float  # /diagnostics period, s

    def __post_init__(self) -> None:
        from msg_adapters.keypoints import KEYPOINT_FORMATS

        require(self.keypoint_format in KEYPOINT_FORMATS,
                f"keypoint_format {self.keypoint_format!r} is not one of {sorted(KEYPOINT_FORMATS)}")
        require(_is_topic(self.output_frame), "output_frame must not contain spaces")
        require(1 <= self.worker_queue_size <= 100, "worker_queue_size must be in [1, 100]")
        require(0.05 <= self.diagnostics_period_s <= 3600.0, "diagnostics_period_s must be in [0.05, 3600]")


def load_node_config(profile=None, overrides=None) -> NodeConfig:
    """The `node` section of a profile (see `smplify3d_ros.settings.load_sections`)."""
    return section(NodeConfig, "node", profile, overrides)
