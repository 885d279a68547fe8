"""Tracking parameters (values and their meaning in params/base/tracking.yaml)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from smplify3d_ros.settings import require


@dataclass(frozen=True)
class TrackingConfig:
    enabled: bool  # track people across frames (False: every frame fitted from scratch)
    gate_m: float  # largest distance between a track's predicted pelvis and an anonymous detection's
    gate_speed_mps: float  # the gate grows by this speed times the time since the track was seen
    extraction_gate_m: float  # a detector-tracked person's points: within this depth of where the track expects them
    iou_weight: float  # weight of (1 - 2D box overlap) in the association cost, in metres
    max_unseen_s: float  # a track not seen for this long ends; an id that returns then starts fresh
    shape_frames: int  # frames whose shapes are averaged (weighted by their LiDAR points), then held
    shape_rate: float  # after that, weight of each new frame's shape in the held shape (0: held)
    accel_sigma_mps2: float  # the constant-velocity filter's process noise: unmodelled acceleration
    position_sigma_m: float  # the filter's measurement noise: the fitted pelvis position
    image_depth_sigma_m: float  # ... and of an image-only fit's depth (along the camera ray)
    pose_smoothing: float  # weight of a new fit's rotations in the output (1: none; the rest: the last output's)
    filter_position: bool  # the output's pelvis is the motion filter's estimate, not the fit's alone
    warm_start: bool  # fit tracked people from their predicted last fit with the short warm solve
    warm_profile: str  # the fitting.profiles entry of the warm solve
    warm_icp: bool  # the rigid LiDAR alignment before a warm solve (the prediction is usually close already)
    # where the warm solve's joint motion hold expects the joints (`Tracker.predicted_joints`)
    joint_prediction: Literal["constant_velocity", "filtered", "last_pose"]
    refresh_frames: int  # every n-th frame of a track: the cold start, the warm start one of its hypotheses (0: never)
    refresh_max_people: int  # people refreshed in one frame at most, the longest unrefreshed first (0: no limit)
    refresh_margin: float  # a refresh's cold fit replaces the warm fit when its final loss is below this fraction
    refresh_compete_first: bool  # a refresh fits cold only when a built-in hypothesis beats the warm start first
    refresh_background: bool  # a refresh's cold fit runs in a helper process; its frame is output warm
    refresh_apply_frames: int  # ... and is taken this many fitted frames of its track later (waited for)
    refresh_second_start: bool  # ... as a second start of that frame's warm solve (the lower loss wins)
    refresh_timeout_s: float  # longest wait for a background refresh (its process starting included)
    refresh_nice: int  # scheduling niceness of the helper process (0-19: higher yields the CPU sooner)
    lost_reprojection: float  # a warm fit reprojecting worse than this (fraction of the person's image height) is lost
    lost_reprojection_floor_px: float  # px, added in quadrature to that limit: a detector's own pixel noise
    lost_points_to_mesh_m: float  # ... or whose points lie farther than this from its mesh (mean)
    lost_face_offset_m: float  # ... or whose face points the other way from the detected face by this much (0: no test)
    lost_background: bool  # a lost warm fit is output (flagged) while its cold refit runs in the helper process
    lost_apply_frames: int  # ... which becomes the track's last fit this many fitted frames later (waited for)

    def __post_init__(self) -> None:
        require(self.gate_m > 0 and self.gate_speed_mps >= 0, "gate_m must be > 0, gate_speed_mps >= 0")
        require(self.extraction_gate_m >= 0, "extraction_gate_m must be >= 0 (0: no gate)")
        require(self.iou_weight >= 0, "iou_weight must be >= 0")
        require(self.max_unseen_s > 0, "max_unseen_s must be > 0")
        require(self.shape_frames >= 1, "shape_frames must be >= 1")
        require(self.refresh_frames >= 0, "refresh_frames must be >= 0 (0: never)")
        require(self.refresh_max_people >= 0, "refresh_max_people must be >= 0 (0: no limit)")
        require(0.0 < self.refresh_margin <= 1.0, "refresh_margin must be in (0, 1]")
        require(self.refresh_apply_frames >= 0, "refresh_apply_frames must be >= 0")
        require(self.lost_apply_frames >= 0, "lost_apply_frames must be >= 0")
        require(self.refresh_timeout_s > 0, "refresh_timeout_s must be > 0")
        require(0 <= self.refresh_nice <= 19, "refresh_nice must be in [0, 19]")
        require(0.0 < self.pose_smoothing <= 1.0, "pose_smoothing must be in (0, 1]")
        require(0.0 <= self.shape_rate <= 1.0, "shape_rate must be in [0, 1]")
        require(self.accel_sigma_mps2 > 0 and self.position_sigma_m > 0 and self.image_depth_sigma_m > 0,
                "accel_sigma_mps2, position_sigma_m and image_depth_sigma_m must be > 0")
        require(self.lost_reprojection > 0 and self.lost_points_to_mesh_m > 0,
                "lost_reprojection and lost_points_to_mesh_m must be > 0")
        require(self.lost_reprojection_floor_px >= 0, "lost_reprojection_floor_px must be >= 0")
        require(self.lost_face_offset_m >= 0, "lost_face_offset_m must be >= 0 (0: no test)")
