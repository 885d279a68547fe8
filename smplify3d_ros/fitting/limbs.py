"""Limb depth from the LiDAR points that hit the limb: a depth target per keypoint.

One image cannot tell an arm reaching towards the camera from one hanging down, or a leg stepping
forward from one stepping back: both project alike. The points the LiDAR put on the limb can. For each
limb keypoint (elbows, wrists, knees, ankles) the points that project within `limb_radius` metres of it
(at the person's depth) and lie within `limb_depth_band` of the person's own depth are the candidates;
the nearest of them (a low percentile, robust to a stray point) is the front of the limb there, and the
limb's axis lies `limb_surface_offset` behind it. Keypoints without such points get no target (NaN).

The targets enter the built-in initializer's refinement as residuals on the keypoints' depth
(`stages.stage_loss`, `StageSpec.keypoint_depth_weight`), so that the body starts with its limbs on the
right side; the chamfer of the later stages then binds the whole surface.
"""

from __future__ import annotations

import numpy as np

from smplify3d_ros.camera import pinhole_pixels
from smplify3d_ros.fitting.config import InitConfig
from smplify3d_ros.keypoints import KP

LIMB_KEYPOINTS = tuple(KP[n] for n in ("left_elbow", "right_elbow", "left_wrist", "right_wrist",
                                        "left_knee", "right_knee", "left_ankle", "right_ankle"))


def limb_depth_targets(keypoints: np.ndarray, K: np.ndarray, points: np.ndarray, depth: float,
                       cfg: InitConfig) -> np.ndarray:
    """(17,) camera-z targets of the limb keypoints (NaN where the LiDAR saw nothing of the limb).

    keypoints (17, 3) undistorted px and score; points (M, 3) the person's points, camera frame; depth the
    person's (pelvis) depth, for the pixel radius and the band."""
    out = np.full(len(keypoints), np.nan)
    if len(points) == 0 or depth <= 0:
        return out
    z = np.maximum(points[:, 2], 1e-3)
    uv = pinhole_pixels(points, K)
    near_person = np.abs(points[:, 2] - depth) <= cfg.limb_depth_band
    radius_px = cfg.limb_radius * 0.5 * (K[0, 0] + K[1, 1]) / depth
    for k in LIMB_KEYPOINTS:
        if keypoints[k, 2] < cfg.keypoint_conf:
            continue
        hit = near_person & (np.linalg.norm(uv - keypoints[k, :2], axis=1) <= radius_px)
        if hit.sum() >= cfg.limb_min_points:
            out[k] = float(np.percentile(z[hit], cfg.limb_depth_percentile)) + cfg.limb_surface_offset
    return out
