"""Body-part visibility (thesis Sec. 3.2): back-face culling (Eq. 1) and the keypoint-confidence rule.

A face with unit normal n is visible from a sensor when n · p < w, p the unit ray from the sensor to the
face and w the culling threshold; w = −1 disables culling (every face is kept), as in the reference's
HumanM3 setting. A body part is occluded when any keypoint that bounds it is below the confidence
threshold; its faces are removed. The rule runs separately for the image and for the LiDAR.
"""

from __future__ import annotations

import numpy as np

from smplify3d_ros.keypoints import BODY_PARTS, PART_NAMES


def occluded_parts(scores: np.ndarray, threshold: float) -> np.ndarray:
    """(17,) keypoint confidences -> (num_parts,) bool, true for occluded parts."""
    return np.array([bool((scores[list(BODY_PARTS[p])] < threshold).any()) for p in PART_NAMES])


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals and centres of the faces, (F, 3) each."""
    tri = vertices[faces]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    return normals, tri.mean(axis=1)


def front_facing(vertices: np.ndarray, faces: np.ndarray, sensor: np.ndarray, threshold: float) -> np.ndarray:
    """(F,) bool: Eq. 1 from a sensor at `sensor` (3,), same frame as the vertices."""
    if threshold <= -1.0:
        return np.ones(len(faces), dtype=bool)
    normals, centres = face_normals(vertices, faces)
    rays = centres - sensor
    rays /= np.maximum(np.linalg.norm(rays, axis=1, keepdims=True), 1e-12)
    return (normals * rays).sum(axis=1) < threshold


def visible_vertices(
    vertices: np.ndarray,
    faces: np.ndarray,
    part_of_face: np.ndarray,
    sensor: np.ndarray,
    culling_threshold: float,
    occluded: np.ndarray,
) -> np.ndarray:
    """(V,) bool: vertices of faces that face the sensor and belong to a visible part.

    part_of_face: (F,) part index, −1 for faces never used (e.g. internal cavities).
    occluded: (num_parts,) bool from `occluded_parts`.
    """
    keep = front_facing(vertices, faces, sensor, culling_threshold) & (part_of_face >= 0)
    keep &= ~occluded[np.clip(part_of_face, 0, None)]
    mask = np.zeros(len(vertices), dtype=bool)
    mask[faces[keep].ravel()] = True
    return mask
