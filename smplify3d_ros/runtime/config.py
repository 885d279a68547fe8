"""Settings of the drivers (the ROS node and the bag replay): the `node` section, params/base/node.yaml.

Topics, synchronization, the LiDAR-camera extrinsic, the output frame and what is published: what turns
messages into frames and fits into messages. The method's own settings are the core configuration
(`smplify3d_ros.config`). The dataclasses declare types and valid ranges only; every value, with its
meaning, lives in the YAML file. The node also exposes each value as a ROS parameter named by its key
path in the section (`sync.slop_s`).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Literal

import numpy as np

from smplify3d_ros.geometry import invert, quaternion_to_matrix, rpy_to_matrix, transform
from smplify3d_ros.settings import require, section


def _is_topic(name: str) -> bool:
    return not any(c.isspace() for c in name)


@dataclass
class TopicsConfig:
    image: str  # sensor_msgs/Image; "" with compressed_image "" too: no image input
    compressed_image: str  # sensor_msgs/CompressedImage used instead of `image` when set
    camera_info: str  # sensor_msgs/CameraInfo
    points: str  # sensor_msgs/PointCloud2 LiDAR scan
    keypoints: str  # sensor_msgs/PointCloud2 keypoint encoding
    init_bodies: str  # std_msgs/String bodies JSON; "" disables the input
    hri_bodies: str  # REP-155 body namespace (/humans/bodies): Skeleton2D input, per-body outputs

    def __post_init__(self) -> None:
        for name in ("image", "compressed_image", "camera_info", "points", "keypoints", "init_bodies",
                     "hri_bodies"):
            require(_is_topic(getattr(self, name)), f"{name} must be a topic name without spaces")
        for name in ("camera_info", "points", "keypoints"):
            require(getattr(self, name) != "", f"{name} must be set")
        require(self.hri_bodies.startswith("/") and not self.hri_bodies.endswith("/"),
                "hri_bodies must be an absolute namespace without a trailing / (REP-155: /humans/bodies)")

    @property
    def image_topic(self) -> str:
        """The image topic subscribed to ('' when the node runs without images)."""
        return self.compressed_image or self.image

    @property
    def compressed(self) -> bool:
        return bool(self.compressed_image)


INPUTS = ("image", "camera_info", "points", "keypoints", "init_bodies")  # every subscribed input


@dataclass
class InputQos:
    """The subscription QoS of one input: a reliable subscriber matches reliable publishers only."""

    reliability: Literal["reliable", "best_effort"]
    depth: int  # keep-last history depth

    def __post_init__(self) -> None:
        require(1 <= self.depth <= 1000, "depth must be in [1, 1000]")


@dataclass
class QosConfig:
    image: InputQos
    camera_info: InputQos
    points: InputQos
    keypoints: InputQos
    init_bodies: InputQos


@dataclass
class SyncConfig:
    slop_s: float  # largest stamp difference within one synchronized set, s
    queue_size: int  # messages kept per input while waiting for a match
    use_message_filters: bool  # message_filters when importable, else the built-in synchronizer
    time_reset_s: float  # a stamp this far behind the last frame's is a clock reset
    latest_camera_info: bool  # each frame takes the latest camera info received; False: matched by stamp

    def __post_init__(self) -> None:
        require(0.0 < self.slop_s <= 5.0, "slop_s must be in (0, 5]")
        require(1 <= self.queue_size <= 1000, "queue_size must be in [1, 1000]")
        require(self.time_reset_s > 0.0, "time_reset_s must be > 0")


@dataclass
class ExtrinsicConfig:
    """The LiDAR-camera extrinsic as TF states it: the pose of `camera_frame` in `lidar_frame`."""

    use_tf: bool  # look the transform up in TF when tf2_ros is importable
    tf_timeout_s: float  # how long one TF lookup may wait, s
    lidar_frame: str  # TF parent of the static extrinsic
    camera_frame: str  # TF child (the camera optical frame)
    xyz: tuple[float, float, float]  # camera origin in the LiDAR frame, m
    rotation: Literal["rpy", "quaternion"]  # which of the two fields below holds the rotation
    rpy: tuple[float, float, float]  # roll, pitch, yaw (rad; fixed axes, ROS convention)
    quaternion: tuple[float, float, float, float]  # x, y, z, w
    publish_tf: bool  # publish the values above on /tf_static (needs tf2_msgs)
    publish_tf_wait_s: float  # with tf2_ros: how long to watch TF for a parent of camera_frame first, s
    motion_compensation: bool  # move the scan to the image's time through `fixed_frame` (TF odometry)
    fixed_frame: str  # the world-fixed frame of that compensation

    def __post_init__(self) -> None:
        require(self.tf_timeout_s >= 0.0, "tf_timeout_s must be >= 0")
        require(0.0 <= self.publish_tf_wait_s <= 60.0, "publish_tf_wait_s must be in [0, 60]")
        require(not self.motion_compensation or self.fixed_frame != "",
                "fixed_frame must be set when motion_compensation is true")
        require(self.lidar_frame != "" and self.camera_frame != "", "lidar_frame and camera_frame must be set")
        require(all(math.isfinite(v) for v in (*self.xyz, *self.rpy, *self.quaternion)),
                "xyz, rpy and quaternion must be finite")
        if self.rotation == "quaternion":
            norm = math.sqrt(sum(v * v for v in self.quaternion))
            require(abs(norm - 1.0) < 1e-3, f"quaternion must have unit norm, got {norm:.6f}")

    def T_lidar_cam(self) -> np.ndarray:
        """(4, 4) camera-frame points -> LiDAR frame (the TF transform parent lidar, child camera)."""
        R = rpy_to_matrix(self.rpy) if self.rotation == "rpy" else quaternion_to_matrix(self.quaternion)
        return transform(R, self.xyz)

    def T_cam_lidar(self) -> np.ndarray:
        """(4, 4) LiDAR-frame points -> camera frame (what `Frame.T_cam_lidar` holds)."""
        return invert(self.T_lidar_cam())


@dataclass
class PublishConfig:
    markers: bool  # ~/markers
    joints: bool  # ~/joints
    body_points: bool  # ~/body_points
    people: bool  # ~/people
    bodies: bool  # ~/bodies
    lazy: bool  # the node builds an output only while something subscribes to it
    mesh_max_triangles: int  # mesh marker decimation (0: every triangle)
    body_points_stride: int  # every n-th vertex on ~/body_points
    geometry_grid_m: float  # mesh markers and ~/body_points rounded to this grid, m (0: exact)
    marker_alpha: float  # mesh marker opacity
    clearing_points: bool  # ~/clearing_points: rays across the camera's view for Nav2's raytrace clearing
    clearing_range_m: float  # length of those rays, m
    clearing_resolution_m: float  # largest gap between ray ends (the costmap's cell size), m
    clearing_view: Literal["full", "camera"]  # rays over a whole circle, or the camera's field of view
    hri: bool  # the ROS4HRI (REP-155) outputs under topics.hri_bodies
    hri_id_prefix: str  # REP-155 body id = prefix + person id
    hri_forget_after_s: float  # per-body publishers of a body unseen this long are removed, s
    velocity_max_gap_s: float  # consecutive fits of one id further apart than this restart its velocity, s

    def __post_init__(self) -> None:
        require(self.mesh_max_triangles >= 0, "mesh_max_triangles must be >= 0 (0: all)")
        require(self.body_points_stride >= 1, "body_points_stride must be >= 1")
        require(0.0 <= self.geometry_grid_m <= 0.05, "geometry_grid_m must be in [0, 0.05] m")
        require(0.0 <= self.marker_alpha <= 1.0, "marker_alpha must be in [0, 1]")
        require(0.1 <= self.clearing_range_m <= 100.0, "clearing_range_m must be in [0.1, 100]")
        require(0.005 <= self.clearing_resolution_m <= 1.0, "clearing_resolution_m must be in [0.005, 1]")
        # a topic token must start with a letter or underscore (ROS 2 names): ids are prefix + digits
        require(re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", self.hri_id_prefix) is not None,
                "hri_id_prefix must be a letter or _ followed by letters, digits or _")
        require(0.1 <= self.hri_forget_after_s <= 3600.0, "hri_forget_after_s must be in [0.1, 3600]")
        require(0.0 < self.velocity_max_gap_s <= 10.0, "velocity_max_gap_s must be in (0, 10]")


@dataclass
class ExpectedRates:
    """Expected rate per input, Hz (0: not checked, only staleness)."""

    image: float
    camera_info: float
    points: float
    keypoints: float
    init_bodies: float

    def __post_init__(self) -> None:
        for name in INPUTS:
            require(0.0 <= getattr(self, name) <= 1000.0, f"{name} must be in [0, 1000]")


@dataclass
class DiagnosticsConfig:
    stale_after_s: float  # an input silent this long is stale, s
    rate_window_s: float  # rates are averaged over this window, s
    rate_tolerance: float  # a rate outside expected * [1 - tol, 1 + tol] is WARN
    expected_hz: ExpectedRates
    latency_window: int  # frames the latency percentiles are computed over

    def __post_init__(self) -> None:
        require(0.1 <= self.stale_after_s <= 3600.0, "stale_after_s must be in [0.1, 3600]")
        require(0.5 <= self.rate_window_s <= 600.0, "rate_window_s must be in [0.5, 600]")
        require(0.0 <= self.rate_tolerance <= 1.0, "rate_tolerance must be in [0, 1]")
        require(1 <= self.latency_window <= 100000, "latency_window must be in [1, 100000]")


@dataclass
class NodeConfig:
    topics: TopicsConfig
    keypoint_input: Literal["pointcloud2", "skeleton2d"]  # the keypoint encoding subscribed to
    keypoint_format: str  # name in msg_adapters.keypoints.KEYPOINT_FORMATS
    qos: QosConfig
    sync: SyncConfig
    extrinsic: ExtrinsicConfig
    output_frame: str  # frame of published geometry; "" = the camera optical frame
    worker_queue_size: int  # frames waiting for the fitting worker (latest-frame policy)
    publish: PublishConfig
    diagnostics_period_s: float  # /diagnostics period, s
    diagnostics: DiagnosticsConfig

    def __post_init__(self) -> None:
        from msg_adapters.keypoints import KEYPOINT_FORMATS

        require(self.keypoint_format in KEYPOINT_FORMATS,
                f"keypoint_format {self.keypoint_format!r} is not one of {sorted(KEYPOINT_FORMATS)}")
        require(_is_topic(self.output_frame), "output_frame must not contain spaces")
        require(1 <= self.worker_queue_size <= 100, "worker_queue_size must be in [1, 100]")
        require(0.05 <= self.diagnostics_period_s <= 3600.0, "diagnostics_period_s must be in [0.05, 3600]")


def load_node_config(profile=None, overrides=None) -> NodeConfig:
    """The `node` section of a profile (see `smplify3d_ros.settings.load_sections`)."""
    return section(NodeConfig, "node", profile, overrides)


# -- ROS parameter ranges --------------------------------------------------------------------------------
_INF = math.inf
# Dotted key (fnmatch pattern) -> (low, high): the closed hull of the values each numeric key accepts, for
# the node's parameter descriptors (FloatingPointRange / IntegerRange). The checks above (and the core's)
# stay the authority: an open bound (`> 0`) appears here closed, and relations between keys (`max_range_m
# > min_depth_m`) are not ranges. test_node_parameters.py checks this table against them both ways.
PARAMETER_RANGES: dict[str, tuple[float, float]] = {
    # node
    "qos.*.depth": (1, 1000), "sync.slop_s": (0, 5), "sync.queue_size": (1, 1000), "sync.time_reset_s": (0, _INF),
    "extrinsic.tf_timeout_s": (0, _INF), "extrinsic.publish_tf_wait_s": (0, 60), "worker_queue_size": (1, 100),
    "publish.mesh_max_triangles": (0, _INF), "publish.body_points_stride": (1, _INF),
    "publish.geometry_grid_m": (0.0, 0.05),
    "publish.marker_alpha": (0, 1), "publish.clearing_range_m": (0.1, 100),
    "publish.clearing_resolution_m": (0.005, 1), "publish.hri_forget_after_s": (0.1, 3600),
    "publish.velocity_max_gap_s": (0, 10), "diagnostics_period_s": (0.05, 3600),
    "diagnostics.stale_after_s": (0.1, 3600), "diagnostics.rate_window_s": (0.5, 600),
    "diagnostics.rate_tolerance": (0, 1), "diagnostics.expected_hz.*": (0, 1000),
    "diagnostics.latency_window": (1, 100000),
    # tracking
    "tracking.gate_m": (0, _INF), "tracking.gate_speed_mps": (0, _INF), "tracking.iou_weight": (0, _INF),
    "tracking.extraction_gate_m": (0, _INF), "tracking.refresh_frames": (0, _INF),
    "tracking.refresh_margin": (0, 1), "tracking.refresh_max_people": (0, _INF),
    "tracking.refresh_apply_frames": (0, _INF), "tracking.refresh_timeout_s": (0, _INF),
    "tracking.refresh_nice": (0, 19), "tracking.lost_apply_frames": (0, _INF),
    "tracking.max_unseen_s": (0, _INF), "tracking.shape_frames": (1, _INF), "tracking.shape_rate": (0, 1),
    "tracking.pose_smoothing": (0, 1),
    "tracking.accel_sigma_mps2": (0, _INF), "tracking.position_sigma_m": (0, _INF),
    "tracking.image_depth_sigma_m": (0, _INF),
    "tracking.lost_reprojection": (0, _INF), "tracking.lost_reprojection_floor_px": (0, _INF),
    "tracking.lost_points_to_mesh_m": (0, _INF),
    "tracking.lost_face_offset_m": (0, _INF),
    # people
    "people.max_people": (1, 100), "people.min_keypoints": (1, 17), "people.keypoint_margin": (0, 10),
    "people.score_level": (0, 1), "people.score_max_gain": (1, _INF),
    # fitting
    "fitting.body.smpl_num_betas": (1, _INF), "fitting.body.anny_shape_sigma": (0, _INF),
    "fitting.body.anny_keypoint_support": (0, _INF), "fitting.body.shape_bound_weight": (0, _INF),
    "fitting.profiles.*.lr": (0, _INF), "fitting.profiles.*.single_stage_iterations": (0, _INF),
    "fitting.profiles.*.early_stop_rel_tol": (0, _INF), "fitting.profiles.*.early_stop_patience": (1, _INF),
    "fitting.profiles.*.chamfer_max_vertices": (0, _INF), "fitting.profiles.*.chamfer_max_points": (0, _INF),
    "fitting.profiles.*.chamfer_vertex_weight": (0, 1), "fitting.profiles.*.weights.*": (0, _INF),
    "fitting.visibility.culling_threshold": (-1, 1), "fitting.visibility.keypoint_conf_*": (0, 1),
    "fitting.icp.max_iterations": (1, _INF), "fitting.icp.convergence_criterion": (0, _INF),
    "fitting.icp.max_correspondence_distance": (0, _INF), "fitting.icp.kernel": (0, _INF),
    "fitting.icp.voxel_size": (0, _INF), "fitting.icp.max_points_per_voxel": (1, _INF),
    "fitting.icp.min_inlier_fraction": (0, 1), "fitting.icp.max_translation": (0, _INF),
    "fitting.icp.prealign_iterations": (0, _INF),
    "fitting.init.body_height": (0, _INF), "fitting.init.torso_height": (0, _INF),
    "fitting.init.shoulder_width": (0, _INF), "fitting.init.hip_width": (0, _INF),
    "fitting.init.lidar_surface_offset": (0, _INF),
    "fitting.init.points_min_depth_ratio": (0, 1), "fitting.init.points_min_depth_cues": (1, _INF),
    "fitting.init.crouch_thigh_ratio": (0, _INF),
    "fitting.init.few_points_max_ratio": (0, _INF),
    "fitting.init.keypoint_conf": (0, 1),
    "fitting.init.refine_iterations": (0, _INF), "fitting.init.ankle_height": (0, _INF),
    "fitting.init.torso_box_pad": (0, _INF), "fitting.init.torso_depth_band": (0, _INF),
    "fitting.init.lidar_heading_min_points": (2, _INF), "fitting.init.lidar_heading_min_spread": (0, _INF),
    "fitting.init.lidar_heading_max_ratio": (0, 1), "fitting.init.heading_hypotheses": (1, _INF),
    "fitting.init.hypothesis_merge_deg": (0, _INF), "fitting.init.hypothesis_iterations": (0, _INF),
    "fitting.init.hypothesis_review_iterations": (0, _INF), "fitting.init.hypothesis_drop_ratio": (1, _INF),
    "fitting.init.final_hypotheses": (1, _INF), "fitting.init.final_hypothesis_ratio": (1, _INF),
    "fitting.init.final_hypothesis_margin": (0, 1),
    "fitting.init.limb_keypoint_conf": (0, 1), "fitting.init.limb_radius": (0, _INF),
    "fitting.init.limb_depth_band": (0, _INF), "fitting.init.limb_min_points": (1, _INF),
    "fitting.init.limb_depth_percentile": (0, 100), "fitting.init.limb_surface_offset": (0, _INF),
    "fitting.init.limb_depth_sigma": (0, _INF), "fitting.init.refine_chamfer": (0, _INF),
    "fitting.init.refine_keypoint_depth": (0, _INF), "fitting.init.refine_max_vertices": (0, _INF),
    "fitting.lidar_mismatch_m": (0, _INF), "fitting.profiles.*.lm_damping": (0, _INF),
    "fitting.profiles.*.pixel_reference_px": (0, _INF), "fitting.profiles.*.neutral_reference_px": (0, _INF),
    "fitting.profiles.*.neutral_robust_scale": (0, _INF),
    "fitting.profiles.*.chamfer_points_ref": (0, _INF), "fitting.profiles.*.chamfer_gain_max": (1, _INF),
    "fitting.profiles.*.free_space_margin_m": (0, _INF), "fitting.init.refine_free_space": (0, _INF),
    "fitting.init.start_elbow_flexion_deg": (0, 150), "fitting.init.flexed_leg_hypotheses": (0, _INF),
    "fitting.init.flexed_leg_min_px": (0, _INF), "fitting.init.head_ankle_fraction": (0, 1),
    "fitting.init.start_hip_flexion_deg": (0, 125), "fitting.init.start_knee_flexion_deg": (0, 150),
    "fitting.init.bent_trunk_hypotheses": (0, _INF), "fitting.init.start_trunk_pitch_deg": (0, 90),
    "fitting.init.image_trunk_max_pitch_deg": (0, 125), "fitting.init.image_trunk_min_pitch_deg": (0, _INF),
    "fitting.init.image_trunk_pitch_step_deg": (0, _INF),
    "fitting.init.image_trunk_min_px": (0, _INF), "fitting.init.image_trunk_short_ratio": (0, _INF),
    "fitting.init.image_trunk_points_radius": (0, _INF),
    "fitting.init.image_trunk_min_rise_m": (0, _INF),
    "fitting.init.swap_hypothesis_margin": (0, 1),
    "fitting.init.refine_lr": (0, _INF), "fitting.min_points": (0, _INF), "fitting.min_points_depth": (1, _INF),
    "fitting.min_keypoints": (0, _INF), "fitting.num_threads": (0, _INF), "fitting.divergence_factor": (1, _INF),
    # lidar
    "lidar.min_depth_m": (0, _INF), "lidar.max_range_m": (0, _INF), "lidar.keypoint_min_score": (0, 1),
    "lidar.min_keypoints": (1, _INF), "lidar.bbox_pad": (0, 1), "lidar.ground_max_range_m": (0, _INF),
    "lidar.ground_ransac_iterations": (1, _INF), "lidar.ground_ransac_sample": (3, _INF),
    "lidar.ground_ransac_seed": (0, _INF), "lidar.ground_inlier_m": (0, _INF),
    "lidar.ground_max_tilt_deg": (0, 90), "lidar.ground_camera_height_min_m": (0, _INF),
    "lidar.ground_camera_height_max_m": (0, _INF), "lidar.ground_min_support": (3, _INF),
    "lidar.ground_fallback_camera_height_m": (0, _INF), "lidar.ground_clearance_m": (0, _INF),
    "lidar.max_height_m": (0, _INF), "lidar.cluster_eps_m": (0, _INF), "lidar.cluster_voxel_m": (0, _INF),
    "lidar.vertical_resolution_deg": (0, 90), "lidar.ring_gap_factor": (1, _INF),
    "lidar.mask_radius_m": (0, _INF), "lidar.max_person_extent_m": (0, _INF),
    "lidar.mask_area_samples": (2, _INF), "lidar.context_pad": (0, _INF), "lidar.min_isolation": (0, 1),
    "lidar.core_isolation_points": (0, _INF), "lidar.core_min_isolation": (0, 1),
    "lidar.post_radius_m": (0, _INF), "lidar.post_min_points": (1, _INF), "lidar.post_min_rise": (0, _INF),
    "lidar.column_max_radius_m": (0, _INF), "lidar.column_min_radius_m": (0, _INF),
    "lidar.column_tolerance_m": (0, _INF), "lidar.column_trials": (1, _INF), "lidar.column_checked": (1, _INF),
    "lidar.column_max_foot_m": (0, _INF), "lidar.column_min_height_m": (0, _INF),
    "lidar.column_top_gap_m": (0, _INF), "lidar.column_band_m": (0, _INF), "lidar.column_band_share": (0, 1),
    "lidar.column_band_pass": (0, 1), "lidar.column_max_gap_m": (0, _INF), "lidar.column_min_bands": (1, _INF),
    "lidar.column_band_points": (1, _INF), "lidar.column_min_width": (0, _INF),
    "lidar.purity_min_room": (0, 1), "lidar.thin_refute_ratio": (0, _INF), "lidar.thin_refute_min_votes": (1, _INF),
    "lidar.surface_side_width": (0, _INF), "lidar.surface_ratio": (0, _INF), "lidar.surface_min_points": (1, _INF),
    "lidar.surface_one_side_ratio": (0, _INF),
    "lidar.shared_weight": (0, 1), "lidar.coverage_full_score": (0, 1), "lidar.share_min_exclusive": (0, 1),
    "lidar.contest_extent_power": (0, _INF),
    "lidar.core_radius_m": (0, _INF),
    "lidar.refute_min_score": (0, 1), "lidar.score_level": (0, 1), "lidar.refute_ratio": (1, _INF),
    "lidar.occluder_min_points": (0, _INF), "lidar.outshone_core_points": (0, _INF),
    "lidar.unclaimed_core_points": (0, _INF),
    "lidar.hidden_weight": (0, _INF), "lidar.second_look_min_votes": (1, _INF), "lidar.depth_tolerance_m": (0, _INF),
    "lidar.secondary_link_m": (0, _INF), "lidar.body_depth_window_m": (0, _INF),
    "lidar.depth_bound_radius_deg": (0, 90), "lidar.depth_bound_keypoint_score": (0, 1),
    "lidar.depth_bound_min_keypoints": (1, _INF), "lidar.depth_bound_margin_m": (0, _INF),
    "lidar.depth_bound_quantile": (0, 1),
}


def parameter_range(name: str) -> tuple[float, float] | None:
    """The (low, high) of PARAMETER_RANGES matching the dotted key `name`, or None."""
    from fnmatch import fnmatchcase

    for pattern, bounds in PARAMETER_RANGES.items():
        if fnmatchcase(name, pattern):
            return bounds
    return None
