"""BodyFit[] -> the point-cloud and pose outputs (`~/joints`, `~/body_points`, `~/people`, the ROS4HRI
position and velocity), and the clearing cloud for Nav2 (`~/clearing_points`).

All geometry is written as the fits hold it (camera frame unless the caller transformed the fits) under
the given `frame_id`; person ids are the fits' ids. A body's pose is its hip midpoint with REP-103 axes for
a person (x forward, y left, z up), as REP-155 states `body_<id>` frames.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from msg_adapters.factory import MessageFactory, resolve_factory
from msg_adapters.hri import rep103_rotation
from msg_adapters.markers import snap
from msg_adapters.pointcloud2 import make_pointcloud2
from smplify3d_ros.geometry import matrix_to_quaternion
from smplify3d_ros.keypoints import HIP_INDICES, NUM_KEYPOINTS
from smplify3d_ros.types import BodyFit, CameraModel


def _ids(fits: Sequence[BodyFit]) -> np.ndarray:
    ids = np.array([int(f.person_id) for f in fits], dtype=np.int64)
    if len(ids) and (ids.min() < -(2**31) or ids.max() >= 2**31):
        raise ValueError(f"person ids must fit int32, got {ids.tolist()}")
    return ids


def fits_to_joints_cloud(
    fits: Sequence[BodyFit], stamp: Any, frame_id: str, factory: MessageFactory | None = None
) -> Any:
    """3D COCO-17 keypoints as PointCloud2: x, y, z (float32, m), person (int32), joint (uint16, COCO-17
    index), one point per (person, joint) with finite coordinates: the mirror of the keypoint input."""
    ids = _ids(fits)
    kp = np.zeros((len(fits), NUM_KEYPOINTS, 3), dtype=np.float32)
    for i, fit in enumerate(fits):
        kp[i] = np.asarray(fit.keypoints3d, dtype=np.float32).reshape(NUM_KEYPOINTS, 3)
    person = np.repeat(ids.astype(np.int32), NUM_KEYPOINTS)
    joint = np.tile(np.arange(NUM_KEYPOINTS, dtype=np.uint16), len(fits))
    xyz = kp.reshape(-1, 3)
    ok = np.isfinite(xyz).all(axis=1)
    return make_pointcloud2(
        stamp, frame_id,
        {"x": xyz[ok, 0], "y": xyz[ok, 1], "z": xyz[ok, 2], "person": person[ok], "joint": joint[ok]},
        factory,
    )


def fits_to_body_points_cloud(
    fits: Sequence[BodyFit], stamp: Any, frame_id: str, factory: MessageFactory | None = None, stride: int = 1,
    grid_m: float = 0.0,
) -> Any:
    """Mesh vertices as PointCloud2: x, y, z (float32, m), person (int32); every `stride`-th vertex,
    non-finite ones skipped, coordinates rounded to `grid_m` when > 0 (`markers.snap`). Costmaps and
    other cloud consumers can use it without new code."""
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    ids = _ids(fits)
    chunks = [snap(np.asarray(f.vertices, dtype=np.float64).reshape(-1, 3)[::stride], grid_m).astype(np.float32)
              for f in fits]
    xyz = np.concatenate(chunks) if chunks else np.zeros((0, 3), np.float32)
    person = np.repeat(ids.astype(np.int32), [len(c) for c in chunks])
    ok = np.isfinite(xyz).all(axis=1)
    return make_pointcloud2(
        stamp, frame_id, {"x": xyz[ok, 0], "y": xyz[ok, 1], "z": xyz[ok, 2], "person": person[ok]}, factory
    )


def body_position(fit: BodyFit) -> np.ndarray:
    """(3,) the midpoint of the COCO hips (keypoints3d 11 and 12), m: a body's position (REP-155)."""
    kp = np.asarray(fit.keypoints3d, dtype=np.float64).reshape(-1, 3)
    return kp[list(HIP_INDICES)].mean(axis=0)


def body_transform(fit: BodyFit) -> np.ndarray:
    """(4, 4) the body frame (hip midpoint, REP-103 axes) in the fit's frame: body points -> fit frame."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rep103_rotation(fit.params.root_orient), body_position(fit)
    return T


def fits_to_pose_array(
    fits: Sequence[BodyFit], stamp: Any, frame_id: str, factory: MessageFactory | None = None
) -> Any:
    """One pose per person, in the order of `fits` (the order of `~/bodies`): the body frame of
    `body_transform` (position: the hip midpoint; orientation: x forward, y left, z up for the person)."""
    factory = resolve_factory(factory)
    poses = []
    for fit in fits:
        T = body_transform(fit)
        p, q = T[:3, 3], matrix_to_quaternion(T[:3, :3])
        poses.append(factory.make(
            "geometry_msgs/msg/Pose",
            position=factory.make("geometry_msgs/msg/Point", x=p[0], y=p[1], z=p[2]),
            orientation=factory.make("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]),
        ))
    return factory.make("geometry_msgs/msg/PoseArray", header=factory.header(stamp, frame_id), poses=poses)


def point_stamped(point: np.ndarray, stamp: Any, frame_id: str, factory: MessageFactory | None = None) -> Any:
    factory = resolve_factory(factory)
    x, y, z = (float(v) for v in point)
    return factory.make("geometry_msgs/msg/PointStamped", header=factory.header(stamp, frame_id),
                        point=factory.make("geometry_msgs/msg/Point", x=x, y=y, z=z))


def twist_stamped(linear: np.ndarray, stamp: Any, frame_id: str, factory: MessageFactory | None = None) -> Any:
    """geometry_msgs/TwistStamped with a linear velocity (m/s) and no angular one."""
    factory = resolve_factory(factory)
    x, y, z = (float(v) for v in linear)
    twist = factory.make("geometry_msgs/msg/Twist", linear=factory.make("geometry_msgs/msg/Vector3", x=x, y=y, z=z))
    return factory.make("geometry_msgs/msg/TwistStamped", header=factory.header(stamp, frame_id), twist=twist)


def clearing_points(camera: CameraModel, range_m: float, resolution_m: float, view: str = "full") -> np.ndarray:
    """(N, 3) ray ends in the camera optical frame for Nav2's raytrace clearing (params/nav2/): a fan at the
    camera's height (y = 0) over a whole circle (`view` "full") or the image's horizontal field of view
    ("camera"), for a costmap source whose raytrace_max_range is `range_m`.

    Nav2 clears every cell between the sensor and each ray end before it marks, so a people layer fed by
    ~/body_points (marking) and this cloud (clearing) holds the latest frame's people. Costmap2D raytraces
    with Bresenham to the ray end's cell: two rays whose end cells are neighbours can still leave a cell
    out between them in the far half of their length (docs/node.md "Nav2" has the counts). So the ends
    lie at twice `range_m`, half a cell (`resolution_m` / 2) apart, and Nav2 cuts each ray at
    raytrace_max_range: what is cleared is the near half, which no two rays leave a gap in."""
    if view == "camera":
        K = np.asarray(camera.K, dtype=np.float64)
        fx, cx = K[0, 0], K[0, 2]
        left, right = np.arctan2(0.0 - cx, fx), np.arctan2(float(camera.width) - cx, fx)
    else:
        left, right = -np.pi, np.pi
    radius = 2.0 * range_m
    n = int(np.ceil((right - left) * radius / (0.5 * resolution_m))) + 1
    angles = np.linspace(left, right, n)
    return np.stack([radius * np.sin(angles), np.zeros(n), radius * np.cos(angles)], axis=1).astype(np.float32)


def clearing_cloud(points: np.ndarray, stamp: Any, frame_id: str, factory: MessageFactory | None = None) -> Any:
    xyz = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    return make_pointcloud2(stamp, frame_id, {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2]}, factory)
