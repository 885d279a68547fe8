"""Step 3 of person point extraction: the ground plane, shared by all people of a frame.

The ground is found by RANSAC with a prior: its normal is within `ground_max_tilt_deg` of the expected
up direction (`ground_up`: the LiDAR's z axis, for a LiDAR mounted level, or the camera's -y, for a
level camera) and the camera is between `ground_camera_height_min_m` and `..._max_m` above it. The
prior rejects walls (vertical) and table tops (above the camera). All hypotheses are drawn and scored
at once (a hypotheses x points matrix), then the best one is refined by a least-squares fit to its
inliers. A plane's support is its inliers minus the points below it, since nothing the LiDAR sees lies
under the ground: a 16-ring sensor puts hundreds of points on a slanted line across a wall, and a
tilted plane through them would otherwise pass when the floor is out of view. When no plane has
`ground_min_support` support, a height band stands in for the plane: a floor across the expected up
direction, `ground_fallback_camera_height_m` below the camera. (The extraction fits the points the
camera sees first, then, if they hold no plane, the whole scan: `extract.extract_people`, step 3.)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplify3d_ros.geometry import unit
from smplify3d_ros.lidar.config import ExtractionConfig

CAMERA_UP = np.array([0.0, -1.0, 0.0])  # up in the camera optical frame (y points down)


@dataclass
class GroundPlane:
    """Plane n . p + d = 0 in the camera frame; n (unit) points up, so n . p + d is height above it."""

    normal: np.ndarray  # (3,) float64 unit normal, pointing up
    offset: float  # d, m: the camera's height above the plane
    num_inliers: int  # points that support the plane (0 for the height band)
    fitted: bool  # True: fitted to LiDAR points; False: the fallback height band

    def height(self, points: np.ndarray) -> np.ndarray:
        """(N,) float64 height of camera-frame points above the ground, m."""
        return np.asarray(points, dtype=np.float64) @ self.normal + self.offset


def fallback_ground(config: ExtractionConfig, up: np.ndarray = CAMERA_UP) -> GroundPlane:
    """The height band: a flat floor across `up` (camera frame), the configured height below the camera."""
    return GroundPlane(unit(np.asarray(up, np.float64).reshape(3)), config.ground_fallback_camera_height_m, 0, False)


def _plausible(normals: np.ndarray, offsets: np.ndarray, config: ExtractionConfig, up: np.ndarray) -> np.ndarray:
    cos_tilt = normals @ up
    return (
        (cos_tilt >= np.cos(np.radians(config.ground_max_tilt_deg)))
        & (offsets >= config.ground_camera_height_min_m)
        & (offsets <= config.ground_camera_height_max_m)
    )


def _refine(points: np.ndarray, up: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane through points: the direction of least variance, oriented up."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[2]
    if normal @ up < 0:
        normal = -normal
    return normal, float(-normal @ centroid)


def _support(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray, threshold: float) -> np.ndarray:
    """(H,) inliers minus points below each plane: nothing the LiDAR sees lies under the ground."""
    height = points @ normals.T + offsets  # (N, H)
    return (np.abs(height) < threshold).sum(axis=0) - (height <= -threshold).sum(axis=0)


def fit_ground(points: np.ndarray, config: ExtractionConfig, up: np.ndarray = CAMERA_UP) -> GroundPlane:
    """Ground plane of (N, 3) camera-frame points, its normal within `ground_max_tilt_deg` of `up` (the
    camera frame's expected up direction), or the fallback band when none is supported."""
    up = unit(np.asarray(up, np.float64).reshape(3))
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    horizontal = np.hypot(points[:, 0], points[:, 2])
    points = points[horizontal <= config.ground_max_range_m]
    if len(points) < max(3, config.ground_min_support):
        return fallback_ground(config, up)
    rng = np.random.default_rng(config.ground_ransac_seed)
    if len(points) > config.ground_ransac_sample:
        sample = points[rng.choice(len(points), config.ground_ransac_sample, replace=False)]
    else:
        sample = points
    triplets = sample[rng.integers(0, len(sample), size=(config.ground_ransac_iterations, 3))]
    normals = np.cross(triplets[:, 1] - triplets[:, 0], triplets[:, 2] - triplets[:, 0])
    norms = np.linalg.norm(normals, axis=1)
    valid = norms > 1e-9  # collinear or repeated samples give no plane
    normals = normals[valid] / norms[valid, None]
    normals *= np.where(normals @ up < 0, -1.0, 1.0)[:, None]
    offsets = -np.einsum("hj,hj->h", normals, triplets[valid, 0])
    keep = _plausible(normals, offsets, config, up)
    if not keep.any():
        return fallback_ground(config, up)
    normals, offsets = normals[keep], offsets[keep]
    support = _support(sample, normals, offsets, config.ground_inlier_m)
    best = int(np.argmax(support))
    normal, offset = normals[best], float(offsets[best])
    for _ in range(2):  # refit on all inliers; a second pass picks up points the refit brought in
        inliers = np.abs(points @ normal + offset) < config.ground_inlier_m
        if inliers.sum() < max(3, config.ground_min_support):
            return fallback_ground(config, up)
        refined, refined_offset = _refine(points[inliers], up)
        if not _plausible(refined[None], np.array([refined_offset]), config, up)[0]:
            break
        normal, offset = refined, refined_offset
    support = int(_support(points, normal[None], np.array([offset]), config.ground_inlier_m)[0])
    if support < config.ground_min_support:
        return fallback_ground(config, up)
    inliers = np.abs(points @ normal + offset) < config.ground_inlier_m
    return GroundPlane(normal, offset, int(inliers.sum()), True)
