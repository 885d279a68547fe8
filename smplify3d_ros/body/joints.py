"""The body joints every model optimizes, and their anatomical frames and ranges of motion.

Both body models expose the same 19 joints (SMPL's body joints without feet and hands; fingers and toes
stay at rest). A pose row is an axis-angle rotation in the canonical body axes (x: body left, y: up,
z: forward). For priors and for authoring poses, each joint also has an anatomical frame built from the
model's rest geometry: flexion axis, twist axis (along the bone), abduction axis, so that one range table
serves every model.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplify3d_ros.geometry import unit

BODY_JOINTS: tuple[str, ...] = (
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
)
JOINT_INDEX = {name: i for i, name in enumerate(BODY_JOINTS)}

# Parent of each joint in this reduced tree (None: the root/pelvis).
JOINT_PARENT: dict[str, str | None] = {
    "left_hip": None, "right_hip": None, "spine1": None,
    "left_knee": "left_hip", "right_knee": "right_hip", "spine2": "spine1",
    "left_ankle": "left_knee", "right_ankle": "right_knee", "spine3": "spine2",
    "neck": "spine3", "left_collar": "spine3", "right_collar": "spine3", "head": "neck",
    "left_shoulder": "left_collar", "right_shoulder": "right_collar",
    "left_elbow": "left_shoulder", "right_elbow": "right_shoulder",
    "left_wrist": "left_elbow", "right_wrist": "right_elbow",
}

# The joint whose rest position gives each joint's bone direction (twist axis). None: use `_FALLBACK`.
JOINT_CHILD: dict[str, str | None] = {
    "left_hip": "left_knee", "right_hip": "right_knee", "spine1": "spine2",
    "left_knee": "left_ankle", "right_knee": "right_ankle", "spine2": "spine3",
    "left_ankle": None, "right_ankle": None, "spine3": "neck",
    "neck": "head", "left_collar": "left_shoulder", "right_collar": "right_shoulder", "head": None,
    "left_shoulder": "left_elbow", "right_shoulder": "right_elbow",
    "left_elbow": "left_wrist", "right_elbow": "right_wrist",
    "left_wrist": None, "right_wrist": None,
}

_UP = np.array([0.0, 1.0, 0.0])
_FORWARD = np.array([0.0, 0.0, 1.0])
_LEFT = np.array([1.0, 0.0, 0.0])


@dataclass(frozen=True)
class JointSpec:
    flexion_direction: np.ndarray  # where flexion moves the child bone (canonical axes)
    side: int  # +1 body left, -1 body right, 0 midline
    # Anatomical range of motion, degrees, for [flexion, twist, abduction], measured from the anatomical
    # neutral (limbs straight and hanging, spine upright). Abduction > 0 moves away from the midline.
    range_deg: tuple[tuple[float, float], tuple[float, float], tuple[float, float]]
    neutral_direction: np.ndarray | None = None  # child bone direction at anatomical neutral, if fixed


def _side(name: str) -> int:
    return 1 if name.startswith("left_") else -1 if name.startswith("right_") else 0


_DOWN = -_UP
# Range-of-motion table (approximate clinical values, degrees).
_RANGES = {
    "hip": ((-30, 125), (-40, 40), (-25, 45)),
    "knee": ((-5, 150), (-15, 15), (-8, 8)),
    "ankle": ((-45, 30), (-20, 20), (-20, 20)),
    "spine": ((-15, 35), (-20, 20), (-15, 15)),
    "neck": ((-40, 50), (-50, 50), (-30, 30)),
    "head": ((-30, 35), (-40, 40), (-25, 25)),
    "collar": ((-10, 30), (-20, 20), (-20, 20)),
    "shoulder": ((-50, 170), (-90, 90), (-20, 170)),
    "elbow": ((-5, 150), (-80, 80), (-10, 10)),
    "wrist": ((-70, 70), (-30, 30), (-30, 30)),
}


def joint_spec(name: str) -> JointSpec:
    kind = name.replace("left_", "").replace("right_", "").rstrip("123")
    side = _side(name)
    if kind in ("hip", "shoulder"):
        return JointSpec(_FORWARD, side, _RANGES[kind], neutral_direction=_DOWN)
    if kind == "knee":
        return JointSpec(-_FORWARD, side, _RANGES[kind])
    if kind == "collar":
        return JointSpec(_UP, side, _RANGES[kind])
    # spine, neck, head, ankle, elbow, wrist: flexion moves the child forward
    return JointSpec(_FORWARD, side, _RANGES[kind])


# Joints that have a bending (hyper-extension) prior, L_a (Eq. 5).
BENDING_JOINTS: tuple[str, ...] = ("left_elbow", "right_elbow", "left_knee", "right_knee")
# Hinge joints whose rest flexion is measured from the rest geometry (the angle between the parent bone
# and this bone), so that their range is anatomical whatever the model's rest pose.
HINGE_JOINTS: tuple[str, ...] = BENDING_JOINTS


@dataclass(frozen=True)
class AnatomicalFrames:
    """Per-joint anatomical frames and ranges, derived from one model's rest joint positions."""

    frames: np.ndarray  # (J, 3, 3): rows are the flexion, twist and abduction axes (canonical axes)
    rest_offset: np.ndarray  # (J, 3) rad: anatomical angles of the model's rest pose
    ranges: np.ndarray  # (J, 3, 2) rad: [min, max] of anatomical angles *relative to the rest pose*


def _signed_angle(a: np.ndarray, b: np.ndarray, axis: np.ndarray) -> float:
    """Angle (rad) rotating unit vector a to b about `axis` (components off the axis plane ignored)."""
    a = unit(a - axis * (a @ axis))
    b = unit(b - axis * (b @ axis))
    return float(np.arctan2(axis @ np.cross(a, b), a @ b))


def anatomical_frames(rest_joints: np.ndarray) -> AnatomicalFrames:
    """Build frames from (J, 3) rest joint positions in canonical axes (x left, y up, z forward)."""
    J = len(BODY_JOINTS)
    frames = np.zeros((J, 3, 3))
    rest_offset = np.zeros((J, 3))
    ranges = np.zeros((J, 3, 2))
    pos = {name: rest_joints[i] for i, name in enumerate(BODY_JOINTS)}
    for i, name in enumerate(BODY_JOINTS):
        spec = joint_spec(name)
        child = JOINT_CHILD[name]
        parent = JOINT_PARENT[name]
        if child is not None:
            u = unit(pos[child] - pos[name])
        elif parent is not None:  # end joints (ankle, wrist, head) continue their parent bone
            u = unit(pos[name] - pos[parent])
        else:
            u = _UP
        a = np.cross(u, spec.flexion_direction)
        if np.linalg.norm(a) < 1e-6:  # bone along the flexion direction: fall back to the lateral axis
            a = _LEFT.copy()
        a = unit(a)
        b = unit(np.cross(a, u))
        lateral = _LEFT if spec.side >= 0 else -_LEFT
        if np.cross(b, u) @ lateral < 0:
            b = -b
        frames[i] = np.stack([a, u, b])
        if name in HINGE_JOINTS and parent is not None:
            parent_dir = unit(pos[name] - pos[parent])
            rest_offset[i, 0] = _signed_angle(parent_dir, u, a)
        elif spec.neutral_direction is not None:
            rest_offset[i, 0] = _signed_angle(spec.neutral_direction, u, a)
            rest_offset[i, 2] = _signed_angle(spec.neutral_direction, u, b)
        ranges[i] = np.deg2rad(np.asarray(spec.range_deg, dtype=float)) - rest_offset[i][:, None]
    return AnatomicalFrames(frames, rest_offset, ranges)
