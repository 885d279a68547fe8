"""Step 4 of person point extraction: Euclidean clustering with a range-adaptive vertical distance.

Why this method. The input is an unorganized cloud already in the camera frame (no ring or azimuth
index survives the extrinsic transform reliably, and the camera is offset from the LiDAR), so a range
image would have to be rebuilt approximately; a 3D density method needs nothing but the points. The
difficulty of a 16-ring sensor is anisotropy: points within a ring are 0.2 deg apart (3.5 cm at 10 m) but
rings are 2 deg apart (35 cm at 10 m), so an isotropic radius that links rings on a far person would
also merge a near person with the wall behind. We therefore cluster in a ground-aligned frame whose
vertical axis is compressed per point by eps / max(eps, factor * r * tan(ring spacing)), r the point's
horizontal range: horizontally two points link within `cluster_eps_m` at every range, vertically within
one ring gap (times a margin) at that range. Depth separation, which is what keeps a person apart from
an occluder or the background, stays `cluster_eps_m` everywhere.

How it is fast. Points are first merged into voxels of `cluster_voxel_m` (in the scaled space; close
people have thousands of points, their voxels a few hundred), voxel centroids are linked with
`scipy.spatial.cKDTree.query_pairs`, and connected components of that graph are the clusters. Two
points therefore link when their voxel centroids are within eps, i.e. the linking distance is eps up to
a voxel diagonal.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from smplify3d_ros.lidar.config import ExtractionConfig
from smplify3d_ros.lidar.ground import GroundPlane


def ground_aligned(points: np.ndarray, ground: GroundPlane) -> tuple[np.ndarray, np.ndarray]:
    """(N, 2) horizontal coordinates in the ground plane and (N,) heights above it, m."""
    normal = ground.normal
    # Any horizontal direction works as the first axis; the camera's x axis is never parallel to up.
    e1 = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    points = np.asarray(points, dtype=np.float64)
    return points @ np.stack([e1, e2], axis=1), ground.height(points)


def scaled_coordinates(points: np.ndarray, ground: GroundPlane, config: ExtractionConfig) -> np.ndarray:
    """(N, 3) coordinates in which Euclidean distance `cluster_eps_m` means "same object"."""
    horizontal, height = ground_aligned(points, ground)
    r = np.linalg.norm(horizontal, axis=1)
    eps = config.cluster_eps_m
    ring_gap = r * np.tan(np.radians(config.vertical_resolution_deg))
    vertical_link = np.maximum(eps, config.ring_gap_factor * ring_gap)
    return np.column_stack([horizontal, height * (eps / vertical_link)])


def euclidean_clusters(coords: np.ndarray, config: ExtractionConfig) -> np.ndarray:
    """(N,) int64 cluster label, 0..C-1 (no noise label), of points in `scaled_coordinates`."""
    if len(coords) == 0:
        return np.zeros(0, dtype=np.int64)
    cells = np.floor((coords - coords.min(axis=0)) / config.cluster_voxel_m).astype(np.int64)
    dims = cells.max(axis=0) + 1
    keys = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    _, voxel_of_point, counts = np.unique(keys, return_inverse=True, return_counts=True)
    voxel_of_point = voxel_of_point.ravel()
    centroids = np.stack(
        [np.bincount(voxel_of_point, weights=coords[:, i]) for i in range(3)], axis=1
    ) / counts[:, None]
    pairs = cKDTree(centroids).query_pairs(config.cluster_eps_m, output_type="ndarray")
    n = len(centroids)
    graph = coo_matrix((np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, voxel_label = connected_components(graph, directed=False)
    return voxel_label[voxel_of_point].astype(np.int64)
