"""Rigid transforms and rotations in numpy: the one place quaternions and matrices are converted.

Conventions: a transform `T` is a (4, 4) float64 matrix taking points of its source frame into its
target frame (`p_target = T @ p_source`); quaternions are in ROS order (x, y, z, w); rotation vectors
are axis-angle (rad). Rotations in numpy go through scipy's `Rotation`; torch code uses roma.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def quaternion_to_matrix(xyzw) -> np.ndarray:
    """(4,) quaternion x, y, z, w (any norm > 0) -> (3, 3) rotation matrix."""
    return Rotation.from_quat(np.asarray(xyzw, dtype=np.float64)).as_matrix()


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> (4,) unit quaternion x, y, z, w with w >= 0."""
    q = Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_quat()
    return -q if q[3] < 0 else q


def rotvec_to_quaternion(rotvec) -> np.ndarray:
    """(3,) axis-angle (rad) -> (4,) unit quaternion x, y, z, w with w >= 0."""
    q = Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_quat()
    return -q if q[3] < 0 else q


def rpy_to_matrix(rpy) -> np.ndarray:
    """Roll, pitch, yaw (rad; fixed axes x, y, z: the ROS / URDF convention) -> (3, 3)."""
    return Rotation.from_euler("xyz", np.asarray(rpy, dtype=np.float64)).as_matrix()


def rotvec_to_matrix(rotvec) -> np.ndarray:
    return Rotation.from_rotvec(np.asarray(rotvec, dtype=np.float64)).as_matrix()


def matrix_to_rotvec(R: np.ndarray) -> np.ndarray:
    return Rotation.from_matrix(np.asarray(R, dtype=np.float64)).as_rotvec()


def transform(R: np.ndarray | None = None, t=None) -> np.ndarray:
    """(4, 4) from a rotation matrix and a translation (either may be omitted)."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if t is not None:
        T[:3, 3] = t
    return T


def transform_from_quaternion(xyz, xyzw) -> np.ndarray:
    """(4, 4) from a translation and a quaternion x, y, z, w (a TF / geometry_msgs Transform)."""
    return transform(quaternion_to_matrix(xyzw), xyz)


def unit(v) -> np.ndarray:
    """`v` scaled to length 1 (zeros where it has no direction, below 1e-12)."""
    v = np.asarray(v)
    n = float(np.linalg.norm(v))
    return v / n if n > 1e-12 else np.zeros_like(v)


def invert(T: np.ndarray) -> np.ndarray:
    """The inverse of a rigid (4, 4) transform, without a general matrix inverse."""
    R, t = T[:3, :3], T[:3, 3]
    return transform(R.T, -R.T @ t)


def move_body(root_orient: np.ndarray, transl: np.ndarray, center: np.ndarray,
              T: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A body moved rigidly by T: (root_orient, transl, rotation center) afterwards.

    Every body model rotates its canonical body by `root_orient` about a rotation center (Anny: the
    pelvis, at `transl`; SMPL: its root joint j0(β) + `transl`) and then translates it, so the moved body
    has root rotation R·R_root and its center at R·c + t: `transl` shifts by R·c + t − c.
    """
    R, t = T[:3, :3], T[:3, 3]
    new_center = R @ center + t
    root = matrix_to_rotvec(R @ rotvec_to_matrix(root_orient))
    return root, np.asarray(transl, np.float64) + new_center - center, new_center
