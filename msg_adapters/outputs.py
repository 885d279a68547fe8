"""BodyFit[] -> the point-cloud and pose outputs (`~/joints`, `~/body_points`, `~/people`).

All geometry is written as the fits hold it (camera frame unless the caller transformed the fits) under
the given `frame_id`; person ids are the fits' ids.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from msg_adapters.factory import MessageFactory, resolve_factory
from msg_adapters.pointcloud2 import make_pointcloud2
from smplify3d_ros.geometry import rotvec_to_quaternion
from smplify3d_ros.keypoints import HIP_INDICES, NUM_KEYPOINTS
from smplify3d_ros.types import BodyFit


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
    fits: Sequence[BodyFit], stamp: Any, frame_id: str, factory: MessageFactory | None = None, stride: int = 1
) -> Any:
    """Mesh vertices as PointCloud2: x, y, z (float32, m), person (int32); every `stride`-th vertex,
    non-finite ones skipped. Costmaps and other cloud consumers can use it without new code."""
    if stride < 1:
        raise ValueError(f"stride must be >= 1, got {stride}")
    ids = _ids(fits)
    chunks = [np.asarray(f.vertices, dtype=np.float32).reshape(-1, 3)[::stride] for f in fits]
    xyz = np.concatenate(chunks) if chunks else np.zeros((0, 3), np.float32)
    person = np.repeat(ids.astype(np.int32), [len(c) for c in chunks])
    ok = np.isfinite(xyz).all(axis=1)
    return make_pointcloud2(
        stamp, frame_id, {"x": xyz[ok, 0], "y": xyz[ok, 1], "z": xyz[ok, 2], "person": person[ok]}, factory
    )


def fits_to_pose_array(
    fits: Sequence[BodyFit], stamp: Any, frame_id: str, factory: MessageFactory | None = None
) -> Any:
    """One root pose per person, in the order of `fits` (the order of `~/bodies`).

    Position: the midpoint of the COCO hips (keypoints3d 11 and 12), m. Orientation: `params.root_orient`
    as a quaternion, i.e. the pose's axes are the body's canonical axes (x: body left, y: up,
    z: forward) expressed in `frame_id`.
    """
    factory = resolve_factory(factory)
    poses = []
    for fit in fits:
        kp = np.asarray(fit.keypoints3d, dtype=np.float64).reshape(-1, 3)
        pelvis = kp[list(HIP_INDICES)].mean(axis=0)
        q = rotvec_to_quaternion(fit.params.root_orient)
        poses.append(factory.make(
            "geometry_msgs/msg/Pose",
            position=factory.make("geometry_msgs/msg/Point", x=pelvis[0], y=pelvis[1], z=pelvis[2]),
            orientation=factory.make("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]),
        ))
    return factory.make("geometry_msgs/msg/PoseArray", header=factory.header(stamp, frame_id), poses=poses)
