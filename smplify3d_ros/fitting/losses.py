"""The loss terms of SMPLify-3D (thesis Eq. 3-8), as pure functions on batched tensors.

Every function takes batch-first tensors and returns one value per batch element, shape (B,), so that
all the people of a frame are optimized together and each keeps its own loss. Priors that belong to a
body model (L_θ, L_a, L_β) live on `BodyModel`; this module combines them.
"""

from __future__ import annotations

import numpy as np
import roma
import torch
from scipy.spatial import cKDTree

from smplify3d_ros.keypoints import HIP_INDICES

_FAR_M = 1e9  # where non-finite coordinates are put for the neighbour search


def geman_mcclure(residual: torch.Tensor, sigma: float) -> torch.Tensor:
    """ρ(x) = σ² x² / (σ² + x²), element-wise (Eq. 3)."""
    sq = residual**2
    return sigma**2 * sq / (sigma**2 + sq)


def project(points: torch.Tensor, K: torch.Tensor) -> torch.Tensor:
    """Pinhole projection of (B, N, 3) camera-frame points with (3, 3) or (B, 3, 3) intrinsics -> (B, N, 2).

    The fitting works on undistorted keypoints, so no distortion here (`smplify3d_ros.camera` holds the
    distorting projection used everywhere else). Depth is clamped to 1 mm to keep gradients finite.
    """
    z = points[..., 2:3].clamp(min=1e-3)
    xy = points[..., :2] / z
    K = K if K.dim() == 3 else K[None]
    return xy * torch.stack([K[:, 0, 0], K[:, 1, 1]], -1)[:, None] + K[:, :2, 2][:, None]


def hip_center(keypoints: torch.Tensor) -> torch.Tensor:
    """Midpoint of COCO hips (11, 12): the root used to align 2D keypoints (reference)."""
    return 0.5 * (keypoints[..., 11, :] + keypoints[..., 12, :])


ALIGNMENTS = ("hips", "centroid")


def alignment_shift(
    projected: torch.Tensor, target: torch.Tensor, confidence: torch.Tensor, align: str
) -> torch.Tensor:
    """(B, 2) image shift that moves the detected keypoints onto the projected ones (Eq. 11-12).

    `hips` is the reference: the hip midpoints coincide. `centroid` removes the confidence²-weighted mean
    offset over all keypoints, the least-squares 2D translation: the aligned term is just as blind to where
    the body sits in the image, but one noisy or swapped hip no longer shifts every other keypoint.
    """
    if align == "hips":
        return hip_center(projected) - hip_center(target)
    if align == "centroid":
        w = (confidence**2)[..., None]
        return ((projected - target) * w).sum(-2) / w.sum(-2).clamp(min=torch.finfo(w.dtype).tiny)
    raise ValueError(f"unknown keypoint alignment {align!r}: expected one of {ALIGNMENTS}")


def reprojection_loss(
    projected: torch.Tensor,
    target: torch.Tensor,
    confidence: torch.Tensor,
    sigma: float,
    align: str | None = None,
    scale: torch.Tensor | None = None,
) -> torch.Tensor:
    """L_J (Eq. 3): Σ_i c_i² Σ_xy ρ(s (Π(J_i) − J_est,i)), (B, K, 2) pixels and (B, K) confidences.

    With `align` (Eq. 11-12, `hips` or `centroid`, see `alignment_shift`) the detected keypoints are first
    shifted onto the projected ones: J_est^algn = J_est + shift. `scale` (B,) is s, per person (None: 1):
    the fitter passes reference size / the person's size in the image, so that σ and the weights mean
    the same for a person 80 px tall in a 640 px image and 400 px tall in a 2048 px one.
    """
    if align is not None:
        target = target + alignment_shift(projected, target, confidence, align)[:, None]
    residual = projected - target
    if scale is not None:
        residual = residual * scale[:, None, None]
    rho = geman_mcclure(residual, sigma).sum(-1)
    return (confidence**2 * rho).sum(-1)


def nearest_indices(
    a: torch.Tensor, b: torch.Tensor, b_mask: torch.Tensor, a_mask: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """Index of each a (B, n, 3)'s nearest valid b (B, m, 3), (B, n), and, when `a_mask` is given, of each
    b's nearest valid a, (B, m); without gradient. A row without a valid neighbour gets index 0.

    On the CPU a k-d tree per person (scipy): a thousand points against 1,500 vertices take 0.9 ms where
    the distance matrix took 8 ms, and the matrix grows with the product of the two sizes. Elsewhere
    (CUDA) the distance matrix, which a GPU computes at once."""
    with torch.no_grad():
        if a.device.type != "cpu":
            return _nearest_dense(a, b, b_mask, a_mask)
        a_np, b_np = _finite_coordinates(a), _finite_coordinates(b)
        a_to_b = _nearest_by_tree(a_np, b_np, b_mask.numpy())
        b_to_a = None if a_mask is None else _nearest_by_tree(b_np, a_np, a_mask.numpy())
    return (torch.from_numpy(a_to_b).to(a.device),
            None if b_to_a is None else torch.from_numpy(b_to_a).to(a.device))


def _finite_coordinates(x: torch.Tensor) -> np.ndarray:
    """(B, n, 3) float64 numpy; NaN and infinities (a diverged body) far away, where no query finds them."""
    return np.nan_to_num(x.detach().to(torch.float64).numpy(), nan=_FAR_M, posinf=_FAR_M, neginf=-_FAR_M)


def _nearest_by_tree(queries: np.ndarray, targets: np.ndarray, target_mask: np.ndarray) -> np.ndarray:
    out = np.zeros(queries.shape[:2], dtype=np.int64)
    for k in range(len(queries)):
        valid = np.flatnonzero(target_mask[k])
        if len(valid) and queries.shape[1]:
            out[k] = valid[cKDTree(targets[k, valid]).query(queries[k], workers=1)[1]]
    return out


def _nearest_dense(
    a: torch.Tensor, b: torch.Tensor, b_mask: torch.Tensor, a_mask: torch.Tensor | None
) -> tuple[torch.Tensor, torch.Tensor | None]:
    d2 = (a**2).sum(-1, keepdim=True) - 2.0 * a @ b.transpose(1, 2) + (b**2).sum(-1)[:, None, :]
    a_to_b = d2.masked_fill(~b_mask[:, None, :], float("inf")).argmin(dim=-1)
    b_to_a = None if a_mask is None else d2.masked_fill_(~a_mask[:, :, None], float("inf")).argmin(dim=-2)
    return a_to_b, b_to_a


def gathered_sq_distances(source: torch.Tensor, target: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """||source_i − target_index_i||², (B, n), with gradient for both sides."""
    nearest = torch.gather(target, 1, index[..., None].expand(-1, -1, 3))
    return ((source - nearest) ** 2).sum(-1)


def nearest_sq_distances(source: torch.Tensor, target: torch.Tensor, target_mask: torch.Tensor) -> torch.Tensor:
    """Squared distance from each source point (B, n, 3) to its nearest valid target (B, m, 3): the
    neighbour is searched without gradient, the distance to it recomputed with gradient for both sides."""
    if source.shape[1] == 0 or target.shape[1] == 0:
        return source.new_zeros(source.shape[:2])
    index, _ = nearest_indices(source, target, target_mask)
    return gathered_sq_distances(source, target, index)


def chamfer_loss(
    vertices: torch.Tensor,
    vertex_mask: torch.Tensor,
    points: torch.Tensor,
    point_mask: torch.Tensor,
    vertex_weight: float = 1.0,
    indices: tuple[torch.Tensor, torch.Tensor | None] | None = None,
) -> torch.Tensor:
    """L_3D (Eq. 7): w (1/n) Σ_v min_p ||v − p||² + (1/m) Σ_p min_v ||p − v||², in m²; w = 1 is Eq. 7.

    vertices (B, n, 3) with (B, n) mask of the visible ones; points (B, m, 3) with (B, m) mask. A person
    with no valid vertex or point gets 0. `vertex_weight` < 1 discounts the vertex-to-point half, which is
    biased for a scanning LiDAR: its points lie on rings (17 cm apart at 5 m for a VLP-16), and pulling
    every visible vertex onto the nearest ring squashes the body between them. `indices`: `nearest_indices`
    of these arguments (the second None without the vertex half), when already found.
    """
    has = vertex_mask.any(-1) & point_mask.any(-1)
    if vertices.shape[1] == 0 or points.shape[1] == 0:
        return vertices.new_zeros(vertices.shape[0])
    if indices is None:
        indices = nearest_indices(points, vertices, vertex_mask, point_mask if vertex_weight > 0 else None)
    p_index, v_index = indices
    n = vertex_mask.sum(-1).clamp(min=1)
    m = point_mask.sum(-1).clamp(min=1)
    loss = (gathered_sq_distances(points, vertices, p_index) * point_mask).sum(-1) / m
    if v_index is not None:
        v_to_p = gathered_sq_distances(vertices, points, v_index)
        loss = loss + vertex_weight * (v_to_p * vertex_mask).sum(-1) / n
    return torch.where(has, loss, torch.zeros_like(loss))


def occlusion_prior(pose: torch.Tensor, init_pose: torch.Tensor, joint_mask: torch.Tensor) -> torch.Tensor:
    """L_θocc (Eq. 8): Σ_i (1 − ⟨q_i, q'_i⟩²) over the joints of occluded parts.

    pose, init_pose: (B, J, 3) axis-angle; joint_mask: (B, J) true where the joint drives an occluded
    part. Squaring the quaternion dot product makes q and −q equal.
    """
    return (held_rotation(pose, init_pose) * joint_mask).sum(-1)


def held_rotation(pose: torch.Tensor, init_pose: torch.Tensor) -> torch.Tensor:
    """(B, J) 1 − ⟨q_i, q'_i⟩² per joint: L_θocc's term before the occlusion mask picks joints."""
    q = roma.rotvec_to_unitquat(pose)
    q0 = roma.rotvec_to_unitquat(init_pose)
    return 1.0 - (q * q0).sum(-1) ** 2


def keypoint_depth_loss(keypoints: torch.Tensor, target: torch.Tensor, sigma: float) -> torch.Tensor:
    """Σ_k ρ(z_k − target_k) over the keypoints with a target (non-NaN), Geman-McClure with scale σ (m):
    the limb depths the LiDAR measured (`fitting.limbs`), robust to the one in six that is another
    limb's or the torso's. keypoints (B, 17, 3) camera frame, target (B, 17)."""
    valid = torch.isfinite(target)
    diff = torch.where(valid, keypoints[..., 2] - torch.nan_to_num(target), torch.zeros_like(target))
    return geman_mcclure(diff, sigma).sum(-1)


def motion_hold_residuals(transl: torch.Tensor, predicted: torch.Tensor, weight: float) -> torch.Tensor:
    """(B, 3) √w · (t − t_pred), zero for rows without a prediction (NaN): a tracked person's place is
    known before the frame is seen, to centimetres at 10 Hz, and a fit that jumps from it by what the image
    and a few dozen points cannot tell apart is the jitter of a per-frame fit."""
    valid = torch.isfinite(predicted)
    return weight**0.5 * torch.where(valid, transl - torch.nan_to_num(predicted), torch.zeros_like(transl))


def joint_motion_residuals(keypoints: torch.Tensor, predicted: torch.Tensor, weight: float,
                           relative: bool = False) -> torch.Tensor:
    """(B, K, 3) √(w / n) · (J_k − J_k,pred), n the person's keypoints with a prediction, zero for the others
    (NaN rows): the squares sum to w · mean_k |J_k − J_k,pred|², in m². A tracked person's joints move
    on smoothly from frame to frame; a fit whose limbs jump by what the image and a few dozen points
    cannot tell apart (how deep a forearm is, where a foot is in its swing) is the rest of a per-frame
    fit's jitter. keypoints, predicted: (B, K, 3) camera frame. `relative`: both about their hip
    midpoint (the body's place left to the translation's own hold)."""
    if relative:
        keypoints, predicted = root_relative(keypoints), root_relative(predicted)
    valid = torch.isfinite(predicted).all(-1, keepdim=True)  # (B, K, 1)
    n = valid.sum(1, keepdim=True).clamp(min=1).to(keypoints.dtype)  # (B, 1, 1)
    diff = torch.where(valid, keypoints - torch.nan_to_num(predicted), torch.zeros_like(keypoints))
    return (weight / n).sqrt() * diff


def root_relative(keypoints: torch.Tensor) -> torch.Tensor:
    """(B, K, 3) COCO keypoints (or their derivatives, (B, K, 3, P)) less their hip midpoint's."""
    return keypoints - keypoints[:, list(HIP_INDICES)].mean(1, keepdim=True)


def depth_hold_residuals(transl: torch.Tensor, init_transl: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """(B,) √w · (z − z₀) / z₀, `weight` (B,) per person (0 for people with L_3D): without enough points
    for L_3D, the image's scale gives the depth only through the assumed body size, no better than the
    start's (the initializer's, or the few points'), and a free depth drifts along that ridge."""
    z0 = init_transl[:, 2].clamp(min=0.3)
    return weight.sqrt() * (transl[:, 2] - init_transl[:, 2]) / z0


def depth_bound_residuals(transl: torch.Tensor, bound: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """(B,) √w · max(0, z − b) / b: a body fitted from the image goes no deeper than the scan's bound `b`
    (B,) (inf: none), where the LiDAR's returns along the rays of its keypoints lie."""
    b = bound.clamp(min=0.3)
    return torch.where(torch.isfinite(b), weight.sqrt() * (transl[:, 2] - b).clamp(min=0.0) / b.clamp(max=1e6),
                       torch.zeros_like(b))


def robust_residuals(residual: torch.Tensor, scale: float) -> tuple[torch.Tensor, torch.Tensor]:
    """ψ(r) = s·r / √(s² + r²), element-wise, and dψ/dr = s³ / (s² + r²)^1.5: ψ² is the Geman-McClure ρ(r)
    (`geman_mcclure`), so a prior written as residuals r becomes a robust one whose squares sum to Σ ρ(r),
    and whose Jacobian is the plain one's rows times dψ/dr (exact Gauss-Newton, no reweighting). s <= 0:
    r itself (quadratic)."""
    if scale <= 0:
        return residual, torch.ones_like(residual)
    sq = scale * scale + residual**2
    return scale * residual / sq.sqrt(), scale**3 / sq**1.5


def upright_residuals(root_orient: torch.Tensor, up: torch.Tensor) -> torch.Tensor:
    """(B, 3) the body's up axis (canonical y, turned by `root_orient`) crossed with the world's up (B, 3),
    camera frame: its norm is the sine of the body's tilt from upright. People mostly stand, sit or walk
    upright; without LiDAR a 2D fit can lay a body towards the camera and project nearly alike."""
    body_up = roma.rotvec_to_rotmat(root_orient)[..., :, 1]
    return torch.cross(body_up, up, dim=-1)
