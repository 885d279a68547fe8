"""A 2D keypoint detector model: ground-truth COCO-17 keypoints seen through a realistic error model.

What a top-down detector (ViTPose-like) does that the model reproduces:
- pixel error proportional to the person's image size, relatively larger for far (small) people:
  sigma = sqrt(floor^2 + (rel(d) * h_px * k_j)^2), rel(d) = sigma_rel_base + sigma_rel_per_m * d, h_px the
  person's image height, k_j the COCO keypoint's relative spread (OKS sigmas: the hips are the least
  precise, the eyes the most);
- occlusion lowers confidence: each keypoint is depth-tested against the rendered depth buffer and
  label image over a small patch; a keypoint behind the person's own surface by more than
  `self_occlusion_depth_m` is self-occluded (e.g. the far hip of someone seen side-on, the nose of
  someone seen from behind), one behind another person or an object is occluded; the detector still
  guesses occluded joints, with larger error;
- occasional left/right swaps (per limb group) and dropped joints; joints outside the image get
  score 0; people with too few visible pixels are not detected at all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplify3d_ros.camera import project_points
from smplify3d_ros.keypoints import KP, NUM_KEYPOINTS, SWAP_GROUPS, swapped_order
from smplify3d_ros.sim.camera import Rendering
from smplify3d_ros.sim.config import DetectorConfig
from smplify3d_ros.types import CameraModel

# COCO keypoint OKS sigmas (Lin et al., COCO keypoint evaluation), relative per-joint localisation spread.
COCO_OKS_SIGMAS = (
    np.array(
        [0.26, 0.25, 0.25, 0.35, 0.35, 0.79, 0.79, 0.72, 0.72, 0.62, 0.62, 1.07, 1.07, 0.87, 0.87, 0.89, 0.89]
    )
    / 10.0
)
JOINT_SPREAD = COCO_OKS_SIGMAS / COCO_OKS_SIGMAS.mean()


@dataclass
class KeypointVisibility:
    """Per keypoint, fractions of its image patch that show it, the person's own nearer surface, or
    another person / an object in front; they sum to 1 for keypoints inside the image."""

    visible: np.ndarray  # (17,) float64
    self_occluded: np.ndarray  # (17,) float64
    occluded: np.ndarray  # (17,) float64
    in_image: np.ndarray  # (17,) bool


@dataclass
class Detection:
    person_id: int
    keypoints: np.ndarray  # (17, 3) float64 u, v (distorted px), score
    visibility: KeypointVisibility
    sigma_px: np.ndarray  # (17,) pixel noise sigma used per keypoint
    swapped: list[int]  # indices into SWAP_GROUPS (in its order) that were swapped


def keypoint_visibility(
    keypoints3d: np.ndarray,
    uv: np.ndarray,
    person_id: int,
    rendering: Rendering,
    cfg: DetectorConfig,
) -> KeypointVisibility:
    """Depth-test each keypoint against the rendering over a (2r+1)^2 pixel patch."""
    H, W = rendering.depth.shape
    r = cfg.occlusion_patch_px
    offsets = np.arange(-r, r + 1)
    du, dv = np.meshgrid(offsets, offsets)
    inside = np.isfinite(uv).all(axis=1) & (keypoints3d[:, 2] > 0)
    with np.errstate(invalid="ignore"):
        inside &= (uv[:, 0] >= 0) & (uv[:, 0] <= W - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= H - 1)
    n = len(uv)
    visible, self_occ, occ = np.zeros(n), np.zeros(n), np.zeros(n)
    for k in np.flatnonzero(inside):
        u = np.clip(np.rint(uv[k, 0]).astype(int) + du.ravel(), 0, W - 1)
        v = np.clip(np.rint(uv[k, 1]).astype(int) + dv.ravel(), 0, H - 1)
        depth = rendering.depth[v, u]
        label = rendering.label[v, u]
        z = keypoints3d[k, 2]
        own = label == person_id
        in_front = depth < z
        is_self = own & (depth < z - cfg.self_occlusion_depth_m)
        is_other = ~own & in_front
        visible[k] = np.mean(~is_self & ~is_other)
        self_occ[k] = np.mean(is_self)
        occ[k] = np.mean(is_other)
    return KeypointVisibility(visible, self_occ, occ, inside)


def _image_height_px(vertices: np.ndarray, camera: CameraModel) -> float:
    uv = project_points(vertices, camera, distort=False)
    v = uv[np.isfinite(uv[:, 1]), 1]
    return float(v.max() - v.min()) if len(v) else 0.0


def detect_person(
    rng: np.random.Generator,
    person_id: int,
    keypoints3d: np.ndarray,
    vertices: np.ndarray,
    rendering: Rendering,
    camera: CameraModel,
    cfg: DetectorConfig,
) -> Detection | None:
    """The detector's output for one person, or None when too little of them is visible."""
    if int(np.count_nonzero(rendering.label == person_id)) < max(cfg.min_visible_pixels, 1):
        return None
    kp3d = np.asarray(keypoints3d, dtype=np.float64)
    uv = project_points(kp3d, camera)
    vis = keypoint_visibility(kp3d, uv, person_id, rendering, cfg)
    distance = float(np.linalg.norm(kp3d[[KP["left_hip"], KP["right_hip"]]].mean(axis=0)))
    rel = cfg.sigma_rel_base + cfg.sigma_rel_per_m * distance
    sigma = np.sqrt(cfg.sigma_px_floor**2 + (rel * _image_height_px(vertices, camera) * JOINT_SPREAD) ** 2)
    sigma = sigma * (1.0 + (cfg.occluded_sigma_scale - 1.0) * (1.0 - vis.visible))
    noisy = uv + rng.normal(0.0, 1.0, uv.shape) * sigma[:, None]
    noisy = np.where(np.isfinite(noisy), noisy, 0.0)

    means = np.array([cfg.score_visible[0], cfg.score_self_occluded[0], cfg.score_occluded[0]])
    stds = np.array([cfg.score_visible[1], cfg.score_self_occluded[1], cfg.score_occluded[1]])
    fractions = np.stack([vis.visible, vis.self_occluded, vis.occluded], axis=1)
    score = rng.normal(fractions @ means, fractions @ stds) - cfg.score_drop_per_m * distance
    score = np.clip(score, 0.0, 1.0)
    score[~vis.in_image] = 0.0
    score[rng.random(NUM_KEYPOINTS) < cfg.missing_prob] = 0.0

    keypoints = np.concatenate([noisy, score[:, None]], axis=1)
    swapped = []
    for g, group in enumerate(SWAP_GROUPS):  # in the dict's order: the draws stay as they were
        if rng.random() < cfg.swap_prob:
            swapped.append(g)
            keypoints = keypoints[swapped_order([group])]
    return Detection(person_id, keypoints, vis, sigma, swapped)


def detect(
    rng: np.random.Generator,
    people: list[tuple[int, np.ndarray, np.ndarray]],
    rendering: Rendering,
    camera: CameraModel,
    cfg: DetectorConfig,
) -> list[Detection]:
    """Detections of (person_id, keypoints3d, vertices) people, in order; undetected people left out."""
    detections = []
    for person_id, keypoints3d, vertices in people:
        det = detect_person(rng, person_id, keypoints3d, vertices, rendering, camera, cfg)
        if det is not None:
            detections.append(det)
    return detections
