"""Data that crosses module boundaries: plain dataclasses of numpy arrays, with units and frames.

Frames: "camera" is the camera optical frame (REP-103: x right, y down, z forward); "lidar" is the
sensor frame of the LiDAR driver. Units: metres, radians, seconds; pixels for image coordinates.
Rotations are axis-angle vectors (radians) unless named otherwise. Stamps are integer nanoseconds
(ROS time: sec * 10^9 + nanosec), exact from the message to the output.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class CameraModel:
    """Pinhole camera with optional lens distortion (ROS CameraInfo conventions)."""

    K: np.ndarray  # (3, 3) float64 intrinsics, pixels
    width: int  # image width, pixels
    height: int  # image height, pixels
    distortion_model: str = ""  # "", "plumb_bob", "rational_polynomial" or "equidistant"
    dist_coeffs: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (n,) float64, ROS D

    @property
    def has_distortion(self) -> bool:
        return bool(self.distortion_model) and bool(np.any(self.dist_coeffs != 0.0))


@dataclass
class BodyParams:
    """Parameters of one body in the camera frame, in one body model's convention.

    `pose` rows follow `BodyModel.joint_names`; each row is an axis-angle rotation (rad) of that joint
    relative to its parent, expressed in the model's canonical axes (x: body left, y: up, z: forward).
    `root_orient` rotates the canonical body into the camera frame and `transl` (m) places it there.
    """

    model: str  # body model name, e.g. "anny" or "smpl"
    shape: np.ndarray  # (S,) float64: Anny phenotypes in [0, 1], or SMPL betas
    pose: np.ndarray  # (J, 3) float64 axis-angle per optimized joint, rad
    root_orient: np.ndarray  # (3,) float64 axis-angle, canonical body -> camera, rad
    transl: np.ndarray  # (3,) float64, m, camera frame

    def copy(self) -> BodyParams:
        return BodyParams(
            self.model, self.shape.copy(), self.pose.copy(), self.root_orient.copy(), self.transl.copy()
        )


@dataclass
class Frame:
    """Everything one synchronized set of sensor messages says, before any per-person processing."""

    stamp_ns: int  # the image's stamp, integer ns
    camera: CameraModel
    keypoints: np.ndarray  # (P, 17, 3) float64: u, v (px, as detected, i.e. distorted), score in [0, 1]
    person_ids: np.ndarray  # (P,) int64 track ids, -1 when the detector has none
    points_lidar: np.ndarray  # (N, 3) float32 LiDAR points in the LiDAR frame, m
    T_cam_lidar: np.ndarray  # (4, 4) float64 transform taking LiDAR-frame points into the camera frame
    image: np.ndarray | None = None  # (H, W, 3) uint8 RGB, optional
    frame_id: str = "camera"  # the camera optical frame's name
    init_bodies: dict[int, BodyParams] = field(default_factory=dict)  # external estimates by person id
    # (Q, 17, 3) keypoints (as detected) of people seen but not fitted (beyond `people.max_people`): the
    # point extraction still gives them their own points, so that their bodies are not taken for a wall
    bystanders: np.ndarray | None = None


@dataclass
class PersonObservation:
    """One person as the fitting engine sees them: 2D keypoints and their own LiDAR points."""

    person_id: int
    keypoints: np.ndarray  # (17, 3) float64: undistorted u, v (px) and score
    bbox: np.ndarray  # (4,) float64 x_min, y_min, x_max, y_max (px, undistorted)
    points: np.ndarray  # (M, 3) float32 the person's LiDAR points in the camera frame, m
    init: BodyParams | None = None  # external initial estimate, if any
    # (4,) float64 the frame's ground plane n·p + d = 0 in the camera frame (n unit, pointing up; d the
    # camera's height above it), None when no plane was fitted to the scan
    ground: np.ndarray | None = None
    # (V, 3) float32 the mesh of `init` when it is already known (a warm start: the last fit's, moved with
    # it), which spares the fitter the forward pass that ICP would otherwise need; None: computed
    init_vertices: np.ndarray | None = None
    # one more start that the built-in initializer weighs against its own heading hypotheses by the same
    # objective (a track's last fit, moved to the new stamp); its `transl` is the hip midpoint, as theirs
    hypothesis: BodyParams | None = None
    # (3,) float64 where a tracker predicts this person's hip midpoint now (camera frame, m), None: no
    # prediction. A start placed there (`init`: a warm start) is held there by the profile's
    # `weights.motion`; a built-in start without points for the depth takes the depth from it
    predicted_pelvis: np.ndarray | None = None
    # (17, 3) float64 where a tracker predicts this person's keypoint joints now (camera frame, m; NaN rows:
    # none), None: no prediction. A warm start (`init` at `predicted_pelvis`) is held near them by the
    # profile's `weights.joint_motion`
    predicted_keypoints: np.ndarray | None = None
    # (m, camera z) the depth the scan says this person cannot lie beyond: the LiDAR's returns along the rays
    # of their confident keypoints lie there (`lidar.extract.depth_bounds`); None: no such bound. The
    # built-in start of a person without points is placed no farther
    depth_bound: float | None = None


@dataclass
class FitQuality:
    reprojection_px: float  # mean confidence-weighted 2D keypoint error of the final fit, px
    chamfer_m: float  # mean symmetric nearest-neighbour distance visible mesh <-> points, m (nan if none)
    num_points: int  # LiDAR points used by the 3D term
    visible_parts: list[str]  # body parts considered visible to the camera
    icp_converged: bool  # whether the rigid LiDAR alignment converged
    final_loss: float  # the last stage's total loss
    # mean distance from each of the person's points to the nearest visible vertex, m (nan if none): the
    # half of `chamfer_m` that a ring-scanning LiDAR does not inflate (vertices between its rings have no
    # point near them however well the body fits); `FLAG_LIDAR_MISMATCH` is set from it
    points_to_mesh_m: float = float("nan")


# Flags a BodyFit may carry.
FLAG_IMAGE_ONLY = "image_only"  # too few LiDAR points, or no part scored for L_3D: fitted from the keypoints alone
FLAG_DIVERGED = "diverged"  # a stage produced NaN or an exploding loss: best finite state returned
FLAG_ICP_NOT_CONVERGED = "icp_not_converged"
FLAG_EXTERNAL_INIT = "external_init"  # initialized from an upstream estimate
FLAG_FEW_KEYPOINTS = "few_keypoints"  # too few confident keypoints for a reliable image term
FLAG_WARM_START = "warm_start"  # a tracked person, fitted from their previous fit with the short warm solve
FLAG_POINTS_TOO_NEAR = "points_too_near"  # the person's points lay far nearer than their image size allows: dropped
FLAG_LOST = "lost"  # a warm fit that lost its person, output while its cold refit runs (tracking.lost_background)
FLAG_SWAPPED_KEYPOINTS = "swapped_keypoints"  # fitted reading a limb's left/right keypoints swapped (a detector's swap)
FLAG_LIDAR_MISMATCH = "lidar_mismatch"  # the fit missed its points (points_to_mesh_m above fitting.lidar_mismatch_m)


@dataclass
class BodyFit:
    """The fitted body of one person in one frame (camera frame)."""

    person_id: int
    params: BodyParams
    joint_names: list[str]  # names of params.pose rows and of `joints`
    vertices: np.ndarray  # (V, 3) float32 mesh vertices, m, camera frame
    keypoints3d: np.ndarray  # (17, 3) float32 COCO-17 3D keypoints, m, camera frame
    joints: np.ndarray  # (J, 3) float32 model joint positions, m, camera frame
    quality: FitQuality
    flags: set[str] = field(default_factory=set)
    # (3,) float64 the point `params.root_orient` rotates the body about (m); None: `params.transl`, which
    # is where Anny's convention puts it (the fitter always sets it; SMPL's is its root joint)
    rotation_center: np.ndarray | None = None
    # (3,) float64 velocity of the body (its hip midpoint), m/s, in the fit's frame; None: not estimated
    # (a tracker fills it; until then the drivers derive it from consecutive fits of the same id)
    velocity: np.ndarray | None = None

    @property
    def center(self) -> np.ndarray:
        """The rotation center (see `rotation_center`)."""
        return self.params.transl if self.rotation_center is None else self.rotation_center

    @property
    def model(self) -> str:
        return self.params.model
