"""Fitting parameters (values and their meaning in params/base/fitting.yaml)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from smplify3d_ros.keypoints import SWAP_GROUPS
from smplify3d_ros.settings import require


@dataclass
class BodyConfig:
    model: Literal["anny", "smpl"]
    smpl_model_path: str
    smpl_coco_regressor_path: str
    smpl_gmm_path: str
    smpl_num_betas: int
    anny_shape_sigma: float
    anny_shape_mean: list[float]
    anny_keypoint_support: int
    shape_bound_weight: float

    def __post_init__(self) -> None:
        require(self.smpl_num_betas > 0, "smpl_num_betas must be > 0")
        require(self.anny_shape_sigma > 0, "anny_shape_sigma must be > 0")
        require(len(self.anny_shape_mean) == 6 and all(0.0 <= float(v) <= 1.0 for v in self.anny_shape_mean),
                "anny_shape_mean must be 6 phenotypes in [0, 1] (gender, age, muscle, weight, height, proportions)")
        require(self.anny_keypoint_support >= 0, "anny_keypoint_support must be >= 0 (0 = every vertex)")
        require(self.shape_bound_weight >= 0, "shape_bound_weight must be >= 0")


@dataclass
class VisibilityConfig:
    culling_threshold: float
    keypoint_conf_image: float
    keypoint_conf_lidar: float

    def __post_init__(self) -> None:
        require(-1.0 <= self.culling_threshold <= 1.0, "culling_threshold must be in [-1, 1]")
        for name in ("keypoint_conf_image", "keypoint_conf_lidar"):
            require(0.0 <= getattr(self, name) <= 1.0, f"{name} must be in [0, 1]")


@dataclass
class IcpConfig:
    enabled: bool
    estimate_rotation: bool
    max_iterations: int
    convergence_criterion: float
    max_correspondence_distance: float
    kernel: float
    voxel_size: float
    max_points_per_voxel: int
    min_inlier_fraction: float
    max_translation: float
    prealign_iterations: int

    def __post_init__(self) -> None:
        require(self.max_iterations > 0, "max_iterations must be > 0")
        for name in ("convergence_criterion", "max_correspondence_distance", "kernel", "voxel_size",
                     "max_translation"):
            require(getattr(self, name) > 0, f"{name} must be > 0")
        require(self.max_points_per_voxel > 0, "max_points_per_voxel must be > 0")
        require(self.prealign_iterations >= 0, "prealign_iterations must be >= 0")
        require(0.0 <= self.min_inlier_fraction <= 1.0, "min_inlier_fraction must be in [0, 1]")


@dataclass
class InitConfig:
    body_height: float
    torso_height: float
    shoulder_width: float
    hip_width: float
    ankle_height: float
    lidar_surface_offset: float
    points_min_depth_ratio: float
    points_min_depth_cues: int
    crouch_thigh_ratio: float
    few_points_max_ratio: float
    keypoint_conf: float
    torso_box_pad: float
    torso_depth_band: float
    lidar_heading_min_points: int
    lidar_heading_min_spread: float
    lidar_heading_max_ratio: float
    heading_hypotheses: int
    hypothesis_merge_deg: float
    limb_keypoint_conf: float
    limb_radius: float
    limb_depth_band: float
    limb_min_points: int
    limb_depth_percentile: float
    limb_surface_offset: float
    limb_depth_sigma: float
    refine_iterations: int
    hypothesis_iterations: int
    hypothesis_review_iterations: int  # the hypotheses' visible vertices picked again after this many (0: never)
    hypothesis_drop_ratio: float  # ... where those with a loss over this x their person's best are dropped
    final_hypotheses: int
    final_hypothesis_ratio: float
    final_hypothesis_margin: float
    refine_lr: float
    refine_pose_weight: float
    refine_chamfer: float
    refine_keypoint_depth: float
    refine_free_space: float
    refine_max_vertices: int
    start_elbow_flexion_deg: float
    flexed_leg_hypotheses: int
    flexed_leg_min_px: float
    head_ankle_fraction: float
    start_hip_flexion_deg: float
    start_knee_flexion_deg: float
    bent_trunk_hypotheses: int
    start_trunk_pitch_deg: float
    image_trunk_max_pitch_deg: float
    image_trunk_min_pitch_deg: float
    image_trunk_pitch_step_deg: float
    image_trunk_min_px: float
    image_trunk_short_ratio: float
    image_trunk_points_radius: float
    image_trunk_min_rise_m: float
    swap_hypotheses: list[str]
    swap_hypothesis_margin: float

    def __post_init__(self) -> None:
        require(0.0 < self.head_ankle_fraction <= 1.0, "head_ankle_fraction must be in (0, 1]")
        for name in ("body_height", "torso_height", "shoulder_width", "hip_width", "refine_lr", "limb_radius",
                     "limb_depth_band", "limb_depth_sigma", "torso_depth_band", "lidar_heading_min_spread"):
            require(getattr(self, name) > 0, f"{name} must be > 0")
        for name in ("lidar_surface_offset", "ankle_height", "torso_box_pad",
                     "limb_surface_offset", "refine_chamfer", "refine_keypoint_depth", "hypothesis_merge_deg",
                     "refine_free_space"):
            require(getattr(self, name) >= 0, f"{name} must be >= 0")
        require(0.0 <= self.points_min_depth_ratio < 1.0, "points_min_depth_ratio must be in [0, 1)")
        require(self.points_min_depth_cues >= 1, "points_min_depth_cues must be >= 1")
        require(self.crouch_thigh_ratio >= 0.0, "crouch_thigh_ratio must be >= 0 (0: off)")
        require(self.few_points_max_ratio >= 0.0, "few_points_max_ratio must be >= 0")
        require(self.refine_iterations >= 0, "refine_iterations must be >= 0")
        require(0 <= self.start_elbow_flexion_deg <= 150, "start_elbow_flexion_deg must be in [0, 150]")
        require(self.flexed_leg_hypotheses >= 0, "flexed_leg_hypotheses must be >= 0 (0: none)")
        require(self.flexed_leg_min_px >= 0, "flexed_leg_min_px must be >= 0 (0: only with a thigh seen)")
        require(0 <= self.start_hip_flexion_deg <= 125, "start_hip_flexion_deg must be in [0, 125]")
        require(0 <= self.start_knee_flexion_deg <= 150, "start_knee_flexion_deg must be in [0, 150]")
        require(self.bent_trunk_hypotheses >= 0, "bent_trunk_hypotheses must be >= 0 (0: none)")
        require(0 <= self.start_trunk_pitch_deg <= 90, "start_trunk_pitch_deg must be in [0, 90]")
        require(0 <= self.image_trunk_max_pitch_deg <= 125, "image_trunk_max_pitch_deg must be in [0, 125] (0: off)")
        require(self.image_trunk_min_pitch_deg >= 0, "image_trunk_min_pitch_deg must be >= 0")
        require(self.image_trunk_pitch_step_deg > 0, "image_trunk_pitch_step_deg must be > 0")
        require(self.image_trunk_min_px >= 0, "image_trunk_min_px must be >= 0")
        require(self.image_trunk_short_ratio >= 0, "image_trunk_short_ratio must be >= 0 (0: never)")
        require(self.image_trunk_points_radius > 0, "image_trunk_points_radius must be > 0")
        require(self.image_trunk_min_rise_m >= 0, "image_trunk_min_rise_m must be >= 0")
        require(0.0 < self.swap_hypothesis_margin <= 1.0, "swap_hypothesis_margin must be in (0, 1]")
        unknown = sorted(set(self.swap_hypotheses) - set(SWAP_GROUPS))
        require(not unknown, f"swap_hypotheses: unknown keypoint groups {unknown}; known: {list(SWAP_GROUPS)}")
        require(self.refine_max_vertices >= 0, "refine_max_vertices must be >= 0 (0 = all)")
        require(self.hypothesis_iterations >= 0, "hypothesis_iterations must be >= 0 (at most refine_iterations run)")
        require(self.hypothesis_review_iterations >= 0, "hypothesis_review_iterations must be >= 0 (0: never)")
        require(self.hypothesis_drop_ratio >= 1, "hypothesis_drop_ratio must be >= 1")
        require(self.heading_hypotheses >= 1, "heading_hypotheses must be >= 1")
        require(self.final_hypotheses >= 1, "final_hypotheses must be >= 1")
        require(self.final_hypothesis_ratio >= 1, "final_hypothesis_ratio must be >= 1")
        require(0 < self.final_hypothesis_margin <= 1, "final_hypothesis_margin must be in (0, 1]")
        require(self.lidar_heading_min_points >= 2 and self.limb_min_points >= 1,
                "lidar_heading_min_points must be >= 2 and limb_min_points >= 1")
        require(0 < self.lidar_heading_max_ratio <= 1, "lidar_heading_max_ratio must be in (0, 1]")
        require(0 <= self.limb_depth_percentile <= 100, "limb_depth_percentile must be in [0, 100]")
        require(0 <= self.keypoint_conf <= 1 and 0 <= self.limb_keypoint_conf <= 1, "confidences must be in [0, 1]")


@dataclass
class LossWeights:
    """λ of Eq. 2 / 11-14. The reference squares them (w² · L) when `square_weights` is true."""

    pose: float  # λ_θ
    bend: float  # λ_a
    shape: float  # λ_β
    chamfer: float  # λ_3D in stage 2 (and single-stage)
    chamfer_final: float  # λ_3D in stage 3
    chamfer_scale: float  # λ_3D in stage 1, which then moves the translation too (0: Eq. 12, shape only)
    occlusion: float  # λ_θocc
    init_pose: float  # the same prior on the joints of *visible* parts (0 in the thesis)
    neutral: float  # Gaussian pose prior around the anatomical neutral, per range of motion (0 in the thesis)
    upright: float  # prior on the body's tilt from the world's up (sine of the tilt), 0: none
    image_depth: float  # holds the initial depth of people fitted without L_3D (relative error), 0: free
    points_depth: float  # that hold where few points (min_points_depth) measured the depth; the scan's depth bound's
    sigma_px: float  # Geman-McClure σ, stages 1-2 (and single-stage)
    sigma_px_final: float  # Geman-McClure σ, stage 3
    # holds the translation where an initial estimate that carries a prediction put it (a tracked person's
    # warm start: the motion filter's), per metre (w² · |t − t_pred|²); 0: free
    motion: float
    # holds the body's keypoint joints (3D, camera frame) where a prediction put them (a tracked person's
    # warm start: each joint moved on at its velocity over the last two fits), per metre, on their mean
    # (w² · mean_k |J_k − J_k,pred|²); 0: free
    joint_motion: float
    # keeps the body out of the space the LiDAR's beams crossed, in the stages with L_3D that move the
    # pose (w² · L_free: each blocked beam's shortfall², m², over the person's points; fitting/free_space.py)
    free_space: float

    def __post_init__(self) -> None:
        for name in ("pose", "bend", "shape", "chamfer", "chamfer_final", "chamfer_scale", "occlusion",
                     "init_pose", "neutral", "upright", "image_depth", "points_depth", "motion",
                     "joint_motion", "free_space"):
            require(getattr(self, name) >= 0, f"{name} must be >= 0")
        require(self.sigma_px > 0 and self.sigma_px_final > 0, "sigma_px values must be > 0")


@dataclass
class OptimizerProfile:
    scheme: Literal["three_stage", "single_stage"]
    optimizer: Literal["adam", "lm"]
    lr: float
    betas: tuple[float, float]
    iterations: tuple[int, int, int]
    single_stage_iterations: int
    early_stop_rel_tol: float
    early_stop_patience: int
    chamfer_max_vertices: int
    chamfer_max_points: int
    chamfer_vertex_weight: float
    mesh_shape: bool
    keypoint_alignment: Literal["hips", "centroid"]
    square_weights: bool
    weights: LossWeights
    lm_damping: float
    pixel_reference_px: float
    neutral_reference_px: float  # weights.neutral × max(1, this / the person's expected pixel height); 0: constant
    neutral_robust_scale: float  # Geman-McClure scale of the neutral prior (range widths); 0: quadratic
    joint_motion_relative: bool  # the joint motion hold on the joints about their hip midpoint (False: where they are)
    free_space_margin_m: float  # a beam is blocked when the body is nearer than its point less this (m)
    chamfer_points_ref: float  # λ_3D² of stages 2-3 × min(points / this, chamfer_gain_max), at least 1; 0: off
    chamfer_gain_max: float  # the largest of those factors

    def __post_init__(self) -> None:
        require(self.lr > 0, "lr must be > 0")
        require(self.chamfer_points_ref >= 0, "chamfer_points_ref must be >= 0 (0 = off)")
        require(self.chamfer_gain_max >= 1, "chamfer_gain_max must be >= 1")
        require(self.optimizer in ("adam", "lm"), "optimizer must be adam or lm")
        require(self.lm_damping > 0, "lm_damping must be > 0")
        require(self.pixel_reference_px >= 0, "pixel_reference_px must be >= 0 (0 = raw pixels)")
        require(self.neutral_reference_px >= 0, "neutral_reference_px must be >= 0 (0 = constant)")
        require(self.neutral_robust_scale >= 0, "neutral_robust_scale must be >= 0 (0 = quadratic)")
        require(all(i >= 0 for i in self.iterations), "iterations must be >= 0")
        require(self.single_stage_iterations >= 0, "single_stage_iterations must be >= 0")
        require(self.early_stop_rel_tol >= 0, "early_stop_rel_tol must be >= 0")
        require(self.early_stop_patience > 0, "early_stop_patience must be > 0")
        require(0.0 <= self.chamfer_vertex_weight <= 1.0, "chamfer_vertex_weight must be in [0, 1]")
        require(self.keypoint_alignment in ("hips", "centroid"), "keypoint_alignment must be hips or centroid")
        require(self.free_space_margin_m >= 0, "free_space_margin_m must be >= 0")
        require(self.chamfer_max_vertices >= 0 and self.chamfer_max_points >= 0,
                "chamfer_max_vertices / chamfer_max_points must be >= 0 (0 = all)")


@dataclass
class FittingConfig:
    body: BodyConfig
    profile: str
    profiles: dict[str, OptimizerProfile]
    visibility: VisibilityConfig
    icp: IcpConfig
    init: InitConfig
    min_points: int
    min_points_depth: int
    min_keypoints: int
    device: Literal["cpu", "cuda", "auto"]
    num_threads: int
    seed: int
    divergence_factor: float
    lidar_mismatch_m: float

    def __post_init__(self) -> None:
        require(self.profile in self.profiles, f"profile {self.profile!r} is not one of {sorted(self.profiles)}")
        require(self.min_points >= 0, "min_points must be >= 0")
        require(self.min_points_depth >= 1, "min_points_depth must be >= 1")
        require(self.min_keypoints >= 0, "min_keypoints must be >= 0")
        require(self.divergence_factor > 1, "divergence_factor must be > 1")
        require(self.lidar_mismatch_m > 0, "lidar_mismatch_m must be > 0")
        require(self.num_threads >= 0, "num_threads must be >= 0 (0 = leave torch's setting)")

    @property
    def optimizer(self) -> OptimizerProfile:
        return self.profiles[self.profile]
