"""Person point extraction parameters (values in params/base/lidar.yaml).

The dataclass declares types and valid ranges only; every value lives in the YAML file with a comment.
"""

from __future__ import annotations

from dataclasses import dataclass

from smplify3d_ros.keypoints import PART_NAMES
from smplify3d_ros.settings import require


@dataclass
class ExtractionConfig:
    """Parameters of `smplify3d_ros.lidar.extract.extract_people` (metres, degrees, pixels)."""

    # Step 1: points the camera can see.
    min_depth_m: float  # points closer than this along the optical axis are dropped
    max_range_m: float  # points farther than this from the camera are dropped
    # Step 2: per-person frustum.
    keypoint_min_score: float  # keypoints below this confidence are ignored
    min_keypoints: int  # a person with fewer confident keypoints gets no points
    bbox_pad: float  # keypoint bbox padding on each side, fraction of its larger side
    # Step 3: ground removal.
    ground_max_range_m: float  # only points this close (horizontally) vote for the ground plane
    ground_ransac_iterations: int  # plane hypotheses per frame
    ground_ransac_sample: int  # at most this many points score each hypothesis
    ground_ransac_seed: int  # seed of the hypothesis sampler (results are deterministic)
    ground_inlier_m: float  # distance to the plane under which a point is a ground inlier
    ground_up: str  # expected up: "lidar" (the LiDAR's z axis, a level LiDAR) or "camera" (the camera's -y)
    ground_max_tilt_deg: float  # largest angle between the ground normal and the expected up
    ground_camera_height_min_m: float  # the camera is at least this high above a valid ground plane
    ground_camera_height_max_m: float  # ... and at most this high
    ground_min_support: int  # less support (inliers - points below): no ground visible, use the height band
    ground_fallback_camera_height_m: float  # camera height above ground assumed by the height band
    ground_clearance_m: float  # points lower than this above the ground are ground
    max_height_m: float  # points higher than this above the ground are not people (ceilings, canopies)
    # Step 4: clustering.
    cluster_eps_m: float  # linking distance between points of one cluster (horizontal)
    cluster_voxel_m: float  # voxel edge of the downsampling that precedes linking
    vertical_resolution_deg: float  # angle between adjacent LiDAR rings
    ring_gap_factor: float  # vertical linking distance = max(eps, factor * range * tan(resolution))
    # Step 5: association of clusters with keypoint sets.
    mask_radius_m: float  # a point belongs to a body if it projects this close to its skeleton
    max_person_extent_m: float  # largest plausible distance between two keypoints of one person
    mask_area_samples: int  # grid side (pixels sampled) for the fraction of the bbox the mask covers
    context_pad: float  # the bbox's surroundings: this fraction of its larger side further out
    min_isolation: float  # how much a body stands out from a surface (0: like a wall, 1: fully)
    core_isolation_points: int  # a cluster with this many core points needs only `core_min_isolation` (0: off)
    core_min_isolation: float  # ...the isolation such a cluster needs (a person merged with what they lean on)
    purity_min_room: float  # purity is rescaled by no less than this share of the bbox the mask leaves uncovered
    surface_side_width: float  # bands beside the bbox, in bbox widths, where a surface would go on
    surface_ratio: float  # a cluster is a surface if both bands hold this fraction of the bbox's points at its depth
    surface_one_side_ratio: float  # ... or one band this many times them
    surface_min_points: int  # ... and at least this many each
    coverage_full_score: float  # a covered part counts 1 when its keypoints score this, in proportion below
    shared_weight: float  # weight of mask points another skeleton also covers, in the cluster score
    share_min_exclusive: float  # fraction of exclusive mask points for two people to share a cluster
    core_tie_break: bool  # among equal scores, more points in the confident segments' core first (false: mask points)
    contest_extent_power: float  # a cluster several people claim: score x (extent / largest claimant's)^this (0: off)
    core_radius_m: float  # points this close to a skeleton are its body or an occluder, not background
    refuting_parts: list[str]  # body parts (keypoints.BODY_PARTS) wide enough to refute a cluster
    refute_min_score: float  # only segments whose keypoints score at least this refute a cluster
    score_level: float  # a plainly seen joint's score; a less confident frame scales refute_min_score down (0: never)
    refute_ratio: float  # a part refutes a cluster when its core holds this many times more points behind it
    thin_refute_ratio: float  # ...and a part not among them (a shin, a forearm) when this many times (0: never)
    thin_refute_min_votes: int  # ...with at least this many points behind the cluster
    # a cluster with this many mask points, none in a confident segment's core, hides the body (0: off)
    occluder_min_points: int
    # a cluster with no point in a person's core is not their main cluster when another has this many there (0: off)
    outshone_core_points: int
    # a main cluster with no core point gives way to one nobody holds with this many there (0: off)
    unclaimed_core_points: int
    hidden_parts: list[str]  # body parts (keypoints.BODY_PARTS) that count as hidden by points in front
    hidden_weight: float  # score lost per hidden part whose core shows that many times more points in front of it
    second_look: bool  # people left without points are scored again once the others' bodies are placed
    second_look_min_votes: int  # ...and there a part refutes or is hidden only by at least this many points
    depth_tolerance_m: float  # depth spread of one body: farther is behind it, nearer may join it
    secondary_link_m: float  # extra clusters join a body across gaps up to this (clustering space)
    body_depth_window_m: float  # a person's points lie within this depth of its median depth
    post_radius_m: float  # points this close across to their cluster's points above the bbox are a post's (0: off)
    post_min_points: int  # ... when at least this many of that cluster's points rise above the bbox
    post_min_rise: float  # ... the highest of them this fraction of the bbox's height above it
    # Step 7 too: a column standing among a person's points is a post's (`columns.column_mask`).
    column_max_radius_m: float  # largest column radius looked for (0: off)
    column_min_radius_m: float  # smallest column radius looked for (a leg is thinner)
    column_tolerance_m: float  # points this close to the circle are on it
    column_trials: int  # circles tried through three of the person's points
    column_checked: int  # ... of which at most this many, those with the most points on them, are tested in full
    column_max_foot_m: float  # the column's lowest point lies at most this high
    column_min_height_m: float  # ... and its points rise at least this far
    column_top_gap_m: float  # ... to within this of the person's highest point
    column_band_m: float  # height bands of this size
    column_band_share: float  # a band holds it when this share of its points within the column's bearings are on it
    column_band_pass: float  # ... and this share of the bands do
    column_max_gap_m: float  # ... a band's points on it leave no gap wider than this across the line of sight
    column_min_bands: int  # ... at least this many
    column_band_points: int  # the column has this many points per band, on average
    column_min_width: float  # ... spanning this many radii across the line of sight (median band)
    # Step 8: how far each person can be (`extract.depth_bounds`).
    depth_bound_radius_deg: float  # returns this close to a seen keypoint's ray are on or past the body (0: none)
    depth_bound_keypoint_score: float  # ... keypoints scored at least this (the camera sees the body there)
    depth_bound_min_keypoints: int  # ... a bound needs at least this many keypoints with such returns
    depth_bound_quantile: float  # ... over those keypoints, this quantile of their farthest returns (1: the farthest)
    depth_bound_margin_m: float  # ... and the bound lies this far behind it

    def __post_init__(self) -> None:
        require(self.min_depth_m >= 0.0, "min_depth_m must be >= 0")
        require(self.max_range_m > self.min_depth_m, "max_range_m must be > min_depth_m")
        require(0.0 <= self.keypoint_min_score <= 1.0, "keypoint_min_score must be in [0, 1]")
        require(self.min_keypoints >= 1, "min_keypoints must be >= 1")
        require(0.0 <= self.bbox_pad <= 1.0, "bbox_pad must be in [0, 1]")
        require(self.ground_max_range_m > 0.0, "ground_max_range_m must be > 0")
        require(self.ground_ransac_iterations >= 1, "ground_ransac_iterations must be >= 1")
        require(self.ground_ransac_sample >= 3, "ground_ransac_sample must be >= 3")
        require(self.ground_ransac_seed >= 0, "ground_ransac_seed must be >= 0")
        require(self.ground_inlier_m > 0.0, "ground_inlier_m must be > 0")
        require(self.ground_up in ("lidar", "camera"), f"ground_up must be 'lidar' or 'camera', not {self.ground_up!r}")
        require(0.0 < self.ground_max_tilt_deg < 90.0, "ground_max_tilt_deg must be in (0, 90)")
        require(
            0.0 <= self.ground_camera_height_min_m < self.ground_camera_height_max_m,
            "need 0 <= ground_camera_height_min_m < ground_camera_height_max_m",
        )
        require(self.ground_min_support >= 3, "ground_min_support must be >= 3")
        require(self.ground_fallback_camera_height_m > 0.0, "ground_fallback_camera_height_m must be > 0")
        require(self.ground_clearance_m >= 0.0, "ground_clearance_m must be >= 0")
        require(self.max_height_m > self.ground_clearance_m, "max_height_m must be > ground_clearance_m")
        require(self.cluster_eps_m > 0.0, "cluster_eps_m must be > 0")
        require(
            0.0 < self.cluster_voxel_m <= self.cluster_eps_m, "cluster_voxel_m must be in (0, cluster_eps_m]"
        )
        require(0.0 < self.vertical_resolution_deg < 90.0, "vertical_resolution_deg must be in (0, 90)")
        require(self.ring_gap_factor >= 1.0, "ring_gap_factor must be >= 1")
        require(self.mask_radius_m > 0.0, "mask_radius_m must be > 0")
        require(0.0 < self.core_radius_m <= self.mask_radius_m, "core_radius_m must be in (0, mask_radius_m]")
        require(self.max_person_extent_m > 0.0, "max_person_extent_m must be > 0")
        require(self.mask_area_samples >= 2, "mask_area_samples must be >= 2")
        require(self.context_pad > 0.0, "context_pad must be > 0")
        require(0.0 <= self.min_isolation <= 1.0, "min_isolation must be in [0, 1]")
        require(0.0 <= self.core_min_isolation <= 1.0, "core_min_isolation must be in [0, 1]")
        require(self.core_isolation_points >= 0, "core_isolation_points must be >= 0")
        require(self.surface_side_width > 0.0, "surface_side_width must be > 0")
        require(self.surface_ratio > 0.0, "surface_ratio must be > 0")
        require(self.surface_one_side_ratio > 0.0, "surface_one_side_ratio must be > 0")
        require(self.surface_min_points >= 1, "surface_min_points must be >= 1")
        require(0.0 < self.coverage_full_score <= 1.0, "coverage_full_score must be in (0, 1]")
        require(0.0 <= self.shared_weight <= 1.0, "shared_weight must be in [0, 1]")
        require(0.0 <= self.share_min_exclusive <= 1.0, "share_min_exclusive must be in [0, 1]")
        require(self.contest_extent_power >= 0.0, "contest_extent_power must be >= 0")
        for name in ("refuting_parts", "hidden_parts"):
            unknown = sorted(set(getattr(self, name)) - set(PART_NAMES))
            require(not unknown, f"{name}: unknown body parts {unknown}; known: {list(PART_NAMES)}")
        require(0.0 <= self.refute_min_score <= 1.0, "refute_min_score must be in [0, 1]")
        require(0.0 <= self.score_level <= 1.0, "score_level must be in [0, 1]")
        require(self.refute_ratio >= 1.0, "refute_ratio must be >= 1")
        require(self.thin_refute_ratio == 0.0 or self.thin_refute_ratio >= 1.0, "thin_refute_ratio must be 0 or >= 1")
        require(self.thin_refute_min_votes >= 1, "thin_refute_min_votes must be >= 1")
        require(0.0 < self.purity_min_room <= 1.0, "purity_min_room must be in (0, 1]")
        require(self.hidden_weight >= 0.0, "hidden_weight must be >= 0")
        require(self.second_look_min_votes >= 1, "second_look_min_votes must be >= 1")
        require(self.occluder_min_points >= 0, "occluder_min_points must be >= 0")
        require(self.outshone_core_points >= 0, "outshone_core_points must be >= 0")
        require(self.unclaimed_core_points >= 0, "unclaimed_core_points must be >= 0")
        require(self.depth_tolerance_m >= 0.0, "depth_tolerance_m must be >= 0")
        require(self.secondary_link_m >= 0.0, "secondary_link_m must be >= 0")
        require(self.body_depth_window_m > 0.0, "body_depth_window_m must be > 0")
        require(self.post_radius_m >= 0.0, "post_radius_m must be >= 0 (0: off)")
        require(self.post_min_points >= 1, "post_min_points must be >= 1")
        require(self.post_min_rise >= 0.0, "post_min_rise must be >= 0")
        require(self.column_max_radius_m >= 0.0, "column_max_radius_m must be >= 0 (0: off)")
        require(self.column_min_radius_m >= 0.0, "column_min_radius_m must be >= 0")
        require(self.column_tolerance_m > 0.0, "column_tolerance_m must be > 0")
        require(self.column_trials >= 1, "column_trials must be >= 1")
        require(self.column_checked >= 1, "column_checked must be >= 1")
        require(self.column_max_foot_m >= 0.0, "column_max_foot_m must be >= 0")
        require(self.column_min_height_m >= 0.0, "column_min_height_m must be >= 0")
        require(self.column_top_gap_m >= 0.0, "column_top_gap_m must be >= 0")
        require(self.column_band_m > 0.0, "column_band_m must be > 0")
        require(0.0 <= self.column_band_share <= 1.0, "column_band_share must be in [0, 1]")
        require(0.0 <= self.column_band_pass <= 1.0, "column_band_pass must be in [0, 1]")
        require(self.column_max_gap_m > 0.0, "column_max_gap_m must be > 0")
        require(self.column_min_bands >= 1, "column_min_bands must be >= 1")
        require(self.column_band_points >= 1, "column_band_points must be >= 1")
        require(self.column_min_width >= 0.0, "column_min_width must be >= 0")
        require(0.0 <= self.depth_bound_radius_deg < 90.0, "depth_bound_radius_deg must be in [0, 90) (0: off)")
        require(0.0 <= self.depth_bound_keypoint_score <= 1.0, "depth_bound_keypoint_score must be in [0, 1]")
        require(self.depth_bound_min_keypoints >= 1, "depth_bound_min_keypoints must be >= 1")
        require(0.0 <= self.depth_bound_quantile <= 1.0, "depth_bound_quantile must be in [0, 1]")
        require(self.depth_bound_margin_m >= 0.0, "depth_bound_margin_m must be >= 0")
