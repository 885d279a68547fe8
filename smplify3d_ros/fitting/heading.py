"""Which way a person faces, from any viewpoint: heading hypotheses for the built-in initializer.

Headings are measured about the camera's vertical relative to the viewing ray through the pelvis
(ψ_rel = 0: facing the camera, ±π: back to it; positive: the person's left shoulder farther from the
camera than the right), and converted to the camera frame at the end.

Evidence, none of it from the face (detectors give the nose 0.85-0.98 confidence on people seen from
behind, so a confident face does not mean "facing the camera"):
- 2D left/right order and foreshortening of the shoulders and hips: their image separation, against
  the separation of a body of typical width at the person's distance, is cos ψ_rel, signed: a person
  facing the camera has the left shoulder on the image's right. It says nothing about the sign of sin ψ_rel
  (the mirror image about the viewing ray projects alike), and the order flips when the detector swaps
  left and right.
- LiDAR: the horizontal principal direction of the torso's points is the shoulder line, ψ_rel mod π
  (the visible front or back of the chest is a flat arc across it). Its slope says which shoulder is
  nearer, the sign the image cannot give; it needs points spread across the torso and fades for
  side-on people, whose visible torso is as deep as it is wide.
The estimate is the fusion of both; the hypotheses are the estimate, its mirror about the ray, and the
two readings of a left/right swap (ψ + π and π − ψ), duplicates merged. A facing, back or side-on
estimate merges them into two opposite headings; the slots it frees go to the middle of the widest gaps
(the two side views of a facing estimate), so that no heading is more than 45° from a hypothesis: the
foreshortening misreads kneeling, crouching and leaning people, whose hips and shoulders spread in the
image for reasons other than the heading. The fitter refines all of them a few iterations and keeps
the one the full objective prefers (`fitter.Fitter._refine_builtin`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplify3d_ros.camera import pinhole_pixels
from smplify3d_ros.fitting.config import InitConfig
from smplify3d_ros.keypoints import KP

PAIRS = (("left_shoulder", "right_shoulder"), ("left_hip", "right_hip"))
TORSO = ("left_shoulder", "right_shoulder", "left_hip", "right_hip")


@dataclass
class HeadingEstimate:
    cos_rel: float | None  # cos ψ_rel from the 2D widths (None: no confident pair)
    slope_angle: float | None  # ψ_rel mod π from the torso points (None: too few or too narrow)
    yaw_rel: float  # fused ψ_rel, rad
    ray_azimuth: float  # α, rad: azimuth of the viewing ray (camera x over z)
    hypotheses: list[float]  # camera-frame yaws to try (`init.upright_root_orient`), best guess first


def _confident(kp: np.ndarray, names, conf: float) -> bool:
    return all(kp[KP[n], 2] >= conf for n in names)


def foreshortening(kp: np.ndarray, K: np.ndarray, pelvis: np.ndarray, cfg: InitConfig) -> float | None:
    """cos ψ_rel from the image separation of shoulders and hips (confidence-weighted mean)."""
    # a width w across the ray at azimuth α and depth z spans f·w / (z·cos α) pixels
    cos_a = pelvis[2] / max(float(np.hypot(pelvis[0], pelvis[2])), 1e-6)
    values, weights = [], []
    for (left, right), width in zip(PAIRS, (cfg.shoulder_width, cfg.hip_width)):
        if _confident(kp, (left, right), cfg.keypoint_conf):
            du = kp[KP[left], 0] - kp[KP[right], 0]
            values.append(du * pelvis[2] * cos_a / (K[0, 0] * width))
            weights.append(kp[KP[left], 2] * kp[KP[right], 2] * width)  # the wider pair is the surer one
    if not values:
        return None
    return float(np.clip(np.average(values, weights=weights), -1.0, 1.0))


def torso_points(kp: np.ndarray, K: np.ndarray, points: np.ndarray, cfg: InitConfig) -> np.ndarray:
    """The person's points that project inside the torso's keypoint box (padded) and lie near its median
    depth: the chest or back, without most of the arms' and legs' points."""
    if len(points) == 0 or not _confident(kp, TORSO, cfg.keypoint_conf):
        return points[:0]
    torso = np.array([kp[KP[n], :2] for n in TORSO])
    lo, hi = torso.min(0), torso.max(0)
    pad = cfg.torso_box_pad * (hi - lo)
    uv = pinhole_pixels(points, K)
    inside = np.all((uv >= lo - pad) & (uv <= hi + pad), axis=1)
    chest = points[inside]
    if len(chest) == 0:
        return chest
    near = np.abs(chest[:, 2] - np.median(chest[:, 2])) <= cfg.torso_depth_band
    return chest[near]


def lidar_slope(chest: np.ndarray, azimuth: float, cfg: InitConfig) -> float | None:
    """ψ_rel mod π, in (−π/2, π/2]: the horizontal principal direction of the torso points in the frame
    of the viewing ray (lateral, along the ray); None when they are too few or span too little."""
    if len(chest) < cfg.lidar_heading_min_points:
        return None
    c, s = np.cos(azimuth), np.sin(azimuth)
    lateral = chest[:, 0] * c - chest[:, 2] * s
    along = chest[:, 0] * s + chest[:, 2] * c
    xy = np.stack([lateral, along], 1) - np.stack([lateral, along], 1).mean(0)
    cov = xy.T @ xy / len(xy)
    evals, evecs = np.linalg.eigh(cov)
    if np.sqrt(evals[1]) < cfg.lidar_heading_min_spread or evals[0] > cfg.lidar_heading_max_ratio * evals[1]:
        return None  # too narrow, or no dominant direction (side-on)
    d = evecs[:, 1]
    if d[0] < 0:
        d = -d
    # the left shoulder lies along (cos ψ_rel, sin ψ_rel) in (lateral, along-ray) axes: the line's angle
    # with cos >= 0 is ψ_rel mod π
    return float(np.arctan2(d[1], d[0]))


def fuse(cos_rel: float | None, slope: float | None) -> float:
    """ψ_rel from cos ψ_rel (signed) and the shoulder-line angle (mod π)."""
    if slope is None:
        return float(np.arccos(cos_rel)) if cos_rel is not None else 0.0
    if cos_rel is None:
        return slope
    # the slope fixes the line; the 2D order picks the end that is the left shoulder
    candidates = (slope, slope + np.pi if slope <= 0 else slope - np.pi)
    return float(min(candidates, key=lambda a: abs(np.cos(a) - cos_rel)))


def _wrap(a: float) -> float:
    return float((a + np.pi) % (2 * np.pi) - np.pi)


def hypotheses(yaw_rel: float, merge: float, count: int = 4) -> list[float]:
    """ψ, its mirror about the ray −ψ, and the left/right-swap readings ψ + π and π − ψ, in that order,
    duplicates (closer than `merge` rad) left out, then headings in the middle of the widest gaps
    between them until there are `count`."""
    out: list[float] = []
    for a in (yaw_rel, -yaw_rel, yaw_rel + np.pi, np.pi - yaw_rel):
        a = _wrap(a)
        if all(abs(_wrap(a - b)) >= merge for b in out):
            out.append(a)
    while len(out) < count:  # a facing, back or side-on estimate leaves two: the widest gaps get the rest
        ring = np.sort(np.mod(out, 2 * np.pi))
        gaps = np.diff(np.r_[ring, ring[0] + 2 * np.pi])
        widest = int(np.argmax(gaps))
        out.append(_wrap(ring[widest] + 0.5 * gaps[widest]))
    return out


def estimate_heading(kp: np.ndarray, K: np.ndarray, pelvis: np.ndarray, points: np.ndarray,
                     cfg: InitConfig) -> HeadingEstimate:
    """Heading evidence and hypotheses of one person (module docstring). `pelvis` (3,): camera frame."""
    azimuth = float(np.arctan2(pelvis[0], pelvis[2]))
    cos_rel = foreshortening(kp, K, pelvis, cfg)
    slope = lidar_slope(torso_points(kp, K, points, cfg), azimuth, cfg) if len(points) else None
    yaw_rel = fuse(cos_rel, slope)
    # camera-frame yaw: facing along the ray's reverse is ψ = −α (see init.upright_root_orient)
    count = max(1, cfg.heading_hypotheses)
    candidates = [_wrap(a - azimuth) for a in hypotheses(yaw_rel, np.deg2rad(cfg.hypothesis_merge_deg), count)]
    return HeadingEstimate(cos_rel, slope, yaw_rel, azimuth, candidates[:count])
