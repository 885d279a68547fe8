"""Person point extraction: each person's LiDAR points in a full scan.

`extract_people` reads like the method, one module per step:
  1. visible points: finite, in front of the camera, within range, projecting into the image;
  2. skeletons and frusta (`associate.person_skeleton`): each person's confident keypoints, padded bbox
     and, around it, a context region (its points are clustered but never assigned);
  3. ground removal (`ground.fit_ground`): one plane per frame, shared by all people;
  4. clustering (`cluster.euclidean_clusters`) of the non-ground points inside any frustum or context;
  5. and 6. association (`associate.associate`): which clusters are whose, and one owner per point.
  7. posts (`without_posts`): the points of a post a person leans on, which rises above them, are not theirs;
     nor are those of a column standing among their points (`columns.column_mask`), seen from near;
  8. how far each person can be (`depth_bounds`): the farthest returns along their confident keypoints' rays.

Keypoints must be UNDISTORTED pixels (the caller undistorts detections with
`camera.undistort_pixels`): points are projected with the ideal pinhole model of the same K
(`project_points(..., distort=False)`), so both live in one image space. "Inside the image" is tested in
that space too; for a distorted lens its border differs slightly from the real image's, which matters
only for points that no keypoint bbox reaches anyway.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from smplify3d_ros.camera import in_image, project_points
from smplify3d_ros.lidar.associate import Skeleton, associate, in_bbox, person_skeleton, score_scale
from smplify3d_ros.lidar.cluster import euclidean_clusters, ground_aligned, scaled_coordinates
from smplify3d_ros.lidar.columns import column_mask
from smplify3d_ros.lidar.config import ExtractionConfig
from smplify3d_ros.lidar.ground import CAMERA_UP, GroundPlane, fit_ground
from smplify3d_ros.types import CameraModel


@dataclass
class PersonPoints:
    """One person's LiDAR points, in the order of the keypoint sets given to `extract_people`."""

    indices: np.ndarray  # (M,) int64 indices into the scan given to `extract_people`
    points: np.ndarray  # (M, 3) float32 the points, camera frame, m
    bbox: np.ndarray  # (4,) float64 x_min, y_min, x_max, y_max (px, undistorted): the padded keypoint
    #                   bbox clipped to the image, i.e. an estimate of the full-body box; zeros without one
    depth_bound: float = float("nan")  # m, the depth the person cannot lie beyond (`depth_bounds`; NaN: none)

    @property
    def num_points(self) -> int:
        return len(self.indices)


@dataclass
class ExtractionResult:
    people: list[PersonPoints]  # one per keypoint set, same order
    labels: np.ndarray  # (N,) int32 per scan point: index of the person it belongs to, or -1
    ground: GroundPlane  # the frame's ground plane (or the fallback height band), camera frame


def depth_range(n_people: int, expected_depth: np.ndarray | None, min_depth: np.ndarray | None) -> np.ndarray | None:
    """(P, 2) nearest and farthest depth of each person's main cluster (NaN: unbounded), from an expected
    depth and tolerance (P, 2) and a nearest depth (P,), either optional; None when neither is given."""
    if expected_depth is None and min_depth is None:
        return None
    out = np.full((n_people, 2), np.nan)
    if expected_depth is not None:
        expected = np.asarray(expected_depth, np.float64).reshape(n_people, 2)
        out[:, 0], out[:, 1] = expected[:, 0] - expected[:, 1], expected[:, 0] + expected[:, 1]
    if min_depth is not None:
        out[:, 0] = np.fmax(out[:, 0], np.asarray(min_depth, np.float64).reshape(n_people))
    return out


def without_posts(horizontal: np.ndarray, uv: np.ndarray, clusters: np.ndarray, owner: np.ndarray,
                  skeletons: list[Skeleton | None], config: ExtractionConfig) -> np.ndarray:
    """`owner` (M,) with the points of a post a person leans on taken from them (-1). A post (a pole, a
    pillar, a sign) is one cluster with the body touching it, and it rises above the person: its points
    above the bbox, within the bbox's width and in one of the person's clusters (at least
    `post_min_points`, the highest `post_min_rise` of the bbox's height above it), mark where it stands,
    and the person's points within `post_radius_m` of them across (in the ground plane) are the post's,
    down to the ground. A body has little above its padded keypoint box:
    the back of a person crouching 2.2 m out rose 3 % of the box's height above it, and without the rise
    65 of their 332 points would have gone with it. `post_radius_m` 0: off. horizontal: (M, 2) the
    candidates' coordinates in the ground plane (the clustering's, `cluster.scaled_coordinates`); uv:
    (M, 2) their pixels; clusters: (M,) their cluster labels."""
    if config.post_radius_m <= 0.0 or not (owner >= 0).any():
        return owner
    out = owner.copy()
    for k, skeleton in enumerate(skeletons):
        mine = owner == k
        if skeleton is None or not mine.any():
            continue
        x_min, y_min, x_max, y_max = skeleton.bbox
        above = (np.isin(clusters, np.unique(clusters[mine])) & (uv[:, 1] < y_min)
                 & (uv[:, 0] >= x_min) & (uv[:, 0] <= x_max))
        if above.sum() < config.post_min_points or y_min - uv[above, 1].min() < config.post_min_rise * (y_max - y_min):
            continue
        dist, _ = cKDTree(horizontal[above]).query(horizontal[mine], k=1)
        out[np.flatnonzero(mine)[dist < config.post_radius_m]] = -1
    return out


def without_columns(points: np.ndarray, ground: GroundPlane, owner: np.ndarray, n_people: int,
                    config: ExtractionConfig) -> np.ndarray:
    """`owner` (M,) with the points of a column standing among a person's points (a post they lean on,
    seen from near, where nothing of it shows above them: `columns.column_mask`) taken from them (-1).
    points: (M, 3) the candidates (camera frame)."""
    if config.column_max_radius_m <= 0.0:
        return owner
    out = owner.copy()
    for k in range(n_people):
        mine = np.flatnonzero(owner == k)
        if len(mine) == 0:
            continue
        horizontal, height = ground_aligned(points[mine], ground)
        out[mine[column_mask(horizontal, height, config)]] = -1
    return out


def depth_bounds(points: np.ndarray, uv: np.ndarray, keypoints: np.ndarray, camera: CameraModel,
                 config: ExtractionConfig) -> np.ndarray:
    """(P,) depth (m, camera z) beyond which each person cannot lie, NaN where the scan does not say.

    Where the camera sees a body part (a keypoint scored `depth_bound_keypoint_score` or more), nothing
    stands in front of it, so the LiDAR's returns along that ray (within `depth_bound_radius_deg`) hit the
    body or what lies behind it; the farthest of them is no nearer than the body there. The bound is the
    `depth_bound_quantile` of those farthest returns over the keypoints that have any (at least
    `depth_bound_min_keypoints`) plus `depth_bound_margin_m`. At 1, the farthest: it holds as long as one
    of the keypoints is truly seen, whatever the others' scores say. The median it was before let a
    detector that scores hidden joints as seen (a projected body, a pose network's guesses) set the bound
    on an occluder: a person 7 m out behind a pillar, their keypoints mostly on it, was fitted 2.6 m off
    (MPJPE); with the simulator's own scores, a runner 10.7 m out, mostly behind a wall whose face took
    some of their keypoints, 6.7 m off (docs/benchmarks.md, "The scan's bound from the farthest
    return"). It holds for a person the extraction left without points: a size cue alone put a
    crouching person 14 m out, their hips hidden, at 30 m, and their own returns were there
    (docs/benchmarks.md, "A depth bound from the scan").

    points: (M, 3) non-ground points (camera frame) and uv: (M, 2) their undistorted pixels;
    keypoints: (P, 17, 3) undistorted u, v (px) and score.
    """
    bounds = np.full(len(keypoints), np.nan)
    if config.depth_bound_radius_deg <= 0.0 or len(points) == 0 or len(keypoints) == 0:
        return bounds
    K = camera.K
    radius = 0.5 * float(K[0, 0] + K[1, 1]) * np.tan(np.radians(config.depth_bound_radius_deg))
    tree = cKDTree(uv)
    depth = np.asarray(points[:, 2], np.float64)
    for k, kp in enumerate(np.asarray(keypoints, np.float64)):
        seen = (kp[:, 2] >= config.depth_bound_keypoint_score) & np.isfinite(kp[:, :2]).all(axis=1)
        if np.count_nonzero(seen) < config.depth_bound_min_keypoints:
            continue
        farthest = [depth[near].max() for near in tree.query_ball_point(kp[seen, :2], radius) if near]
        if len(farthest) >= config.depth_bound_min_keypoints:
            bounds[k] = float(np.quantile(farthest, config.depth_bound_quantile)) + config.depth_bound_margin_m
    return bounds


def extract_people(
    points_cam: np.ndarray, keypoints: np.ndarray, camera: CameraModel, config: ExtractionConfig,
    expected_depth: np.ndarray | None = None,
    min_depth: Callable[[GroundPlane, np.ndarray], np.ndarray] | None = None,
    up: np.ndarray = CAMERA_UP,
) -> ExtractionResult:
    """Each person's points in a full scan.

    points_cam: (N, 3) float32 scan in the camera optical frame (x right, y down, z forward), m.
    keypoints: (P, 17, 3) COCO-17 undistorted u, v (px) and score, one set per person.
    expected_depth: optional (P, 2) depth (m) where each person is expected and its tolerance (m), e.g.
    a track's prediction; a person's main cluster must lie within it (NaN rows: anywhere).
    min_depth: optional, given the frame's ground plane (step 3) and each person's padded keypoint bbox
    ((P, 4), NaN rows for people without a skeleton), the (P,) depth (m) nearer than which each person's
    main cluster cannot lie, e.g. what their size in the image allows (NaN: no bound).
    up: (3,) the expected up direction in the camera frame, around which the ground plane is looked for
    (default: the camera's -y, a level camera).
    """
    points = np.asarray(points_cam, dtype=np.float32).reshape(-1, 3)
    keypoints = np.asarray(keypoints, dtype=np.float64).reshape(-1, 17, 3)
    labels = np.full(len(points), -1, dtype=np.int32)

    # 1. Visible points (the depth test first: it halves a 360 deg scan cheaply, and drops NaN depths).
    with np.errstate(invalid="ignore"):
        visible = np.flatnonzero(points[:, 2] > config.min_depth_m)
        ahead = points[visible]
        ok = np.all(np.isfinite(ahead), axis=1)
        ok &= np.einsum("ij,ij->i", ahead, ahead) <= config.max_range_m**2
    visible = visible[ok]
    uv = project_points(points[visible], camera, distort=False)
    inside = in_image(uv, camera)
    visible, uv = visible[inside], uv[inside]

    # 2. Skeletons and their frusta.
    skeletons = [person_skeleton(kp, camera, config) for kp in keypoints]
    frustum = np.zeros(len(visible), dtype=bool)
    for skeleton in skeletons:
        if skeleton is not None:
            frustum |= in_bbox(uv, skeleton.context)

    # 3. Ground removal, with a plane fitted to everything the camera sees; when that shows too little
    # floor (walls ahead, a camera mounted high: a VLP-16 1.35 m up first meets the floor 5 m out), to
    # the whole scan, whose floor beside and behind the robot is the same plane on flat ground.
    ground = fit_ground(points[visible], config, up)
    if not ground.fitted:
        ground = fit_ground(points, config, up)
    if frustum.any():
        height = ground.height(points[visible[frustum]])
        keep = (height > config.ground_clearance_m) & (height <= config.max_height_m)
        frustum[np.flatnonzero(frustum)[~keep]] = False
    candidates, cand_uv = visible[frustum], uv[frustum]

    # 4. Clusters; 5 and 6. Association, one owner per point.
    coords = scaled_coordinates(points[candidates], ground, config)
    clusters = euclidean_clusters(coords, config)
    boxes = np.array([s.bbox if s is not None else np.full(4, np.nan) for s in skeletons]).reshape(-1, 4)
    nearest = None if min_depth is None else min_depth(ground, boxes)
    owner = associate(points[candidates], cand_uv, coords, clusters, skeletons, camera, config,
                      depth_range(len(keypoints), expected_depth, nearest),
                      refute_scale=score_scale(keypoints[..., 2], config))  # the detector's confidence level
    owner = without_posts(coords[:, :2], cand_uv, clusters, owner, skeletons, config)
    owner = without_columns(points[candidates], ground, owner, len(skeletons), config)
    labels[candidates] = owner.astype(np.int32)

    # 8. How far each person can be.
    bounds = depth_bounds(points[candidates], cand_uv, keypoints, camera, config)
    people = []
    for k, skeleton in enumerate(skeletons):
        indices = candidates[owner == k].astype(np.int64)
        bbox = skeleton.bbox if skeleton is not None else np.zeros(4)
        people.append(PersonPoints(indices=indices, points=points[indices], bbox=bbox, depth_bound=float(bounds[k])))
    return ExtractionResult(people=people, labels=labels, ground=ground)
