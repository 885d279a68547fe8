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


def front_facing(vertices: np.ndarray, faces: np.ndarray, sensor: np.ndarray, threshold: float) -> np.ndarray:
    """(F,) bool: Eq. 1 from a sensor at `sensor` (3,), same frame as the vertices. n · p < w is tested
    as (unnormalized n) · (unnormalized p) < w |n| |p|: no division, and degenerate faces (n = 0) are
    visible exactly when 0 < w, as with unit vectors."""
    if threshold <= -1.0:
        return np.ones(len(faces), dtype=bool)
    # corners gathered coordinate-major by `np.take` and products written out: the same arithmetic as
    # np.cross and einsum on (F, 3) rows, half the time on a 27k-face mesh
    v = np.ascontiguousarray(np.asarray(vertices).T)  # (3, V)
    v0, v1, v2 = (np.take(v, np.ascontiguousarray(faces[:, k]), axis=1) for k in range(3))
    a, b = v1 - v0, v2 - v0
    n = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])
    ray = (v0 + v1 + v2) * (1.0 / 3.0) - np.asarray(sensor).reshape(3, 1)
    dot = n[0] * ray[0] + n[1] * ray[1] + n[2] * ray[2]
    if threshold == 0.0:
        return dot < 0.0
    scale = np.sqrt((n[0] * n[0] + n[1] * n[1] + n[2] * n[2]) * (ray * ray).sum(0))
    return dot < threshold * np.maximum(scale, 1e-24)


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
