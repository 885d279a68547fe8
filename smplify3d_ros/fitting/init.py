"""Initial body estimate (thesis Step 0): an external estimate when one is given, else the built-in one.

The built-in initializer works, like CLIFF, in the full frame rather than in a crop, so that the body's
position and heading are those of the real camera:
1. Pelvis depth from the person's LiDAR points (their median, pushed back by the body's half depth along
   the viewing ray); without points, from the pixel height of the torso (or of the bounding box) and the
   focal length, for an assumed body size. The pelvis is then back-projected through the hip midpoint.
2. Upright root orientation (the camera is assumed level, up = −y). Heading from the torso keypoints:
   the apparent shoulder (and hip) width against the expected width gives |cos(yaw)| and, through the
   left/right order, whether the person faces the camera; the nose's side of the shoulder midpoint gives
   the sign of the turn. When the shoulders are nearly aligned (side-on), confident face keypoints mean
   "facing the camera", ears without a face "facing away".
3. Limbs: a short 2D-only fit of pose and orientation to the keypoints with strong priors (translation
   fixed), batched over the people of the frame through the same optimizer as the main stages.
"""

from __future__ import annotations

import numpy as np

from smplify3d_ros.fitting.config import InitConfig
from smplify3d_ros.keypoints import KP
from smplify3d_ros.types import PersonObservation


def _confident(kp: np.ndarray, names: tuple[str, ...], conf: float) -> bool:
    return all(kp[KP[n], 2] >= conf for n in names)


def _mid(kp: np.ndarray, a: str, b: str) -> np.ndarray:
    return 0.5 * (kp[KP[a], :2] + kp[KP[b], :2])


def estimate_depth(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, use_points: bool) -> float:
    """Depth (m, camera z) of the pelvis."""
    if use_points and len(obs.points):
        return float(np.median(obs.points[:, 2])) + cfg.lidar_surface_offset
    kp = obs.keypoints
    f = 0.5 * (K[0, 0] + K[1, 1])
    if _confident(kp, ("left_shoulder", "right_shoulder", "left_hip", "right_hip"), cfg.keypoint_conf):
        torso_px = np.linalg.norm(_mid(kp, "left_shoulder", "right_shoulder") - _mid(kp, "left_hip", "right_hip"))
        if torso_px > 1.0:
            return float(f * cfg.torso_height / torso_px)
    height_px = max(float(obs.bbox[3] - obs.bbox[1]), 1.0)
    return float(f * cfg.body_height / height_px)


def pelvis_pixel(obs: PersonObservation, cfg: InitConfig) -> np.ndarray:
    kp = obs.keypoints
    if _confident(kp, ("left_hip", "right_hip"), cfg.keypoint_conf):
        return _mid(kp, "left_hip", "right_hip")
    if _confident(kp, ("left_shoulder", "right_shoulder"), cfg.keypoint_conf):
        # pelvis about 60% of the way from the shoulders to the bottom of the box
        top = _mid(kp, "left_shoulder", "right_shoulder")
        return np.array([top[0], top[1] + 0.6 * (obs.bbox[3] - top[1])])
    return np.array([0.5 * (obs.bbox[0] + obs.bbox[2]), 0.5 * (obs.bbox[1] + obs.bbox[3])])


def estimate_yaw(obs: PersonObservation, K: np.ndarray, depth: float, cfg: InitConfig) -> float:
    """Heading ψ (rad) about the camera's vertical; 0 = facing the camera, ±π = back to the camera."""
    kp = obs.keypoints
    f = 0.5 * (K[0, 0] + K[1, 1])
    widths = []
    for left, right, width in (
        ("left_shoulder", "right_shoulder", cfg.shoulder_width),
        ("left_hip", "right_hip", cfg.hip_width),
    ):
        if _confident(kp, (left, right), cfg.keypoint_conf):
            widths.append((kp[KP[left], 0] - kp[KP[right], 0]) / (f * width / depth))
    face_seen = _confident(kp, ("nose",), cfg.face_conf) or _confident(kp, ("left_eye", "right_eye"), cfg.face_conf)
    if not widths:
        return 0.0 if face_seen else np.pi
    cos_yaw = float(np.clip(np.mean(widths), -1.0, 1.0))
    if abs(cos_yaw) < cfg.side_on_cos:
        cos_yaw = abs(cos_yaw) if face_seen else -abs(cos_yaw)
    magnitude = float(np.arccos(cos_yaw))
    sign = 1.0
    if _confident(kp, ("nose", "left_shoulder", "right_shoulder"), cfg.keypoint_conf):
        # the nose lies forward of the shoulders: it shows on the side the person turns to
        offset = kp[KP["nose"], 0] - _mid(kp, "left_shoulder", "right_shoulder")[0]
        sign = 1.0 if offset >= 0 else -1.0
    return sign * magnitude


def upright_root_orient(yaw: float) -> np.ndarray:
    """Axis-angle of the canonical body (x left, y up, z forward) standing upright in a level camera
    frame, turned by `yaw` about the vertical (0: facing the camera)."""
    up = np.array([0.0, -1.0, 0.0])
    forward = np.array([np.sin(yaw), 0.0, -np.cos(yaw)])
    left = np.cross(up, forward)
    R = np.stack([left, up, forward], axis=1)
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def builtin_root(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, use_points: bool):
    """(root_orient (3,), pelvis position (3,)) of the built-in initializer, before the limb refinement."""
    depth = estimate_depth(obs, K, cfg, use_points)
    u, v = pelvis_pixel(obs, cfg)
    pelvis = np.array([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth])
    yaw = estimate_yaw(obs, K, depth, cfg)
    return upright_root_orient(yaw), pelvis
