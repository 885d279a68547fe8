"""ROS4HRI (REP-155) messages: bodies as hri_msgs and sensor_msgs/JointState, and Skeleton2D keypoints in.

hri_msgs is optional (docs/robot.md: not a rosdep key of this package). The three definitions the package
uses (IdsList, Skeleton2D, NormalizedPointOfInterest2D) are kept in msg_adapters/msg/hri_msgs and registered in
rosbags typestores (`register_hri_types`), so that replay writes them into bags without the package. The
live node publishes them only when rclpy can import hri_msgs (`has_type`).

Body frames follow REP-103 for a person (x forward, out of the body; y left; z up), as REP-155 asks for
`body_<id>`; the body models' canonical axes are x left, y up, z forward (`CANONICAL_FROM_REP103`).

Joint states: each of the model's joints (body/joints.py) is a rotation relative to its parent. Expressed
in REP-103 axes it is decomposed as REP-155's human model chains its joints, yaw about z, then pitch about
the new y, then roll about the new x (R = Rz(yaw) Ry(pitch) Rx(roll)): three JointState entries per joint,
named `<joint>_yaw_<body id>`, `<joint>_pitch_<body id>`, `<joint>_roll_<body id>`, in radians.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from msg_adapters.definitions import HRI_TYPES, MSG_DIR, register_hri_types  # noqa: F401 - re-exported
from msg_adapters.factory import MessageFactory, resolve_factory
from msg_adapters.keypoints import get_keypoint_format
from smplify3d_ros.keypoints import KP, NUM_KEYPOINTS

# columns: a person's REP-103 axes (forward, left, up) in the body models' canonical axes (x left, y up, z forward)
CANONICAL_FROM_REP103 = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
JOINT_AXES = ("yaw", "pitch", "roll")
SKELETON_JOINTS = 18
_REP155 = get_keypoint_format("rep155")  # Skeleton2D's index order; NECK (1) has no COCO-17 joint
_SHOULDERS = (KP["left_shoulder"], KP["right_shoulder"])
_NECK = 1


def has_type(factory: MessageFactory, typename: str) -> bool:
    """Whether the factory's runtime has the message type (rclpy: the package is importable)."""
    try:
        factory.message_class(typename)
    except TypeError:
        return False
    return True


def rep103_rotation(root_orient: np.ndarray) -> np.ndarray:
    """(3, 3) a person's REP-103 axes (x forward, y left, z up) in the fit's frame, from its root rotation."""
    return Rotation.from_rotvec(np.asarray(root_orient, dtype=np.float64)).as_matrix() @ CANONICAL_FROM_REP103


def joint_angles(pose: np.ndarray) -> np.ndarray:
    """(J, 3) axis-angle joint rotations (canonical axes) -> (J, 3) yaw, pitch, roll in REP-103 axes."""
    R = Rotation.from_rotvec(np.asarray(pose, dtype=np.float64).reshape(-1, 3)).as_matrix()
    C = CANONICAL_FROM_REP103
    return Rotation.from_matrix(C.T @ R @ C).as_euler("ZYX")


def joint_state_msg(joint_names: list[str], pose: np.ndarray, body_id: str, stamp: Any,
                    factory: MessageFactory | None = None) -> Any:
    """sensor_msgs/JointState of one body (module docstring for names and angles)."""
    factory = resolve_factory(factory)
    angles = joint_angles(pose)
    names = [f"{joint}_{axis}_{body_id}" for joint in joint_names for axis in JOINT_AXES]
    return factory.make("sensor_msgs/msg/JointState", header=factory.header(stamp, ""), name=names,
                        position=angles.reshape(-1))


def ids_list_msg(ids: list[str], stamp: Any, frame_id: str, factory: MessageFactory | None = None) -> Any:
    factory = resolve_factory(factory)
    return factory.make("hri_msgs/msg/IdsList", header=factory.header(stamp, frame_id), ids=list(ids))


def skeleton2d_msg(keypoints: np.ndarray, width: int, height: int, stamp: Any, frame_id: str,
                   factory: MessageFactory | None = None) -> Any:
    """hri_msgs/Skeleton2D from (17, 3) COCO-17 keypoints (u, v in pixels, score): normalized by the image
    size; the neck, which COCO-17 lacks, is the shoulders' midpoint with the lower of their scores."""
    factory = resolve_factory(factory)
    kp = np.asarray(keypoints, dtype=np.float64).reshape(NUM_KEYPOINTS, 3)
    points = np.zeros((SKELETON_JOINTS, 3))
    have = _REP155.to_coco >= 0
    points[have] = kp[_REP155.to_coco[have]]
    shoulders = kp[list(_SHOULDERS)]
    points[_NECK] = (*shoulders[:, :2].mean(axis=0), shoulders[:, 2].min())
    points[points[:, 2] <= 0] = 0.0  # a missing joint: (0, 0) with confidence 0
    points[:, 0] /= float(width)
    points[:, 1] /= float(height)
    poi = [factory.make("hri_msgs/msg/NormalizedPointOfInterest2D", x=x, y=y, c=c) for x, y, c in points.tolist()]
    return factory.make("hri_msgs/msg/Skeleton2D", header=factory.header(stamp, frame_id), skeleton=poi)


def read_skeleton2d(msg: Any, width: int, height: int) -> np.ndarray:
    """hri_msgs/Skeleton2D -> (17, 3) COCO-17 keypoints in pixels (u, v, score); the neck is not used.
    Non-finite coordinates read as missing (score 0); scores are clipped to [0, 1]."""
    points = np.array([(p.x, p.y, p.c) for p in msg.skeleton], dtype=np.float64).reshape(-1, 3)
    if len(points) != SKELETON_JOINTS:
        raise ValueError(f"Skeleton2D has {len(points)} points, expected {SKELETON_JOINTS}")
    out = np.zeros((NUM_KEYPOINTS, 3))
    have = _REP155.to_coco >= 0
    out[_REP155.to_coco[have]] = points[have]
    bad = ~np.isfinite(out).all(axis=1)
    out[bad] = 0.0
    out[:, 0] *= float(width)
    out[:, 1] *= float(height)
    out[:, 2] = np.clip(out[:, 2], 0.0, 1.0)
    return out


class BodyIds:
    """REP-155 body ids (strings) <-> the integer person ids of the keypoint encoding: `<prefix><n>` reads
    as n (the ids this package publishes); any other id gets a number of its own from 2^30 up, kept for the
    last `capacity` ids seen."""

    FIRST_OTHER = 2**30

    def __init__(self, prefix: str, capacity: int = 1000) -> None:
        self.prefix = prefix
        self.capacity = capacity
        self._others: dict[str, int] = {}
        self._next = self.FIRST_OTHER

    def person_id(self, body_id: str) -> int:
        rest = body_id[len(self.prefix):] if body_id.startswith(self.prefix) else ""
        if rest.isdigit() and int(rest) < self.FIRST_OTHER:
            return int(rest)
        if body_id not in self._others:
            if len(self._others) >= self.capacity:
                del self._others[next(iter(self._others))]
            self._others[body_id] = self._next
            self._next = self.FIRST_OTHER + (self._next - self.FIRST_OTHER + 1) % (2**31 - 1 - self.FIRST_OTHER)
        return self._others[body_id]


def skeletons_to_keypoints(skeletons: dict[str, Any], width: int, height: int,
                           ids: BodyIds) -> tuple[np.ndarray, np.ndarray]:
    """Skeleton2D messages by body id -> (P, 17, 3) COCO-17 keypoints in pixels and (P,) person ids."""
    order = sorted(skeletons)
    kp = np.array([read_skeleton2d(skeletons[b], width, height) for b in order]).reshape(-1, NUM_KEYPOINTS, 3)
    return kp, np.array([ids.person_id(b) for b in order], dtype=np.int64)
