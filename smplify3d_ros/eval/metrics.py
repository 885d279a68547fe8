"""Evaluation metrics (thesis Sec. 4): pure numpy, errors in millimetres.

Inputs are arrays of points in metres with matching rows (predicted vs ground truth), one body
(N, 3) or a batch (B, N, 3); batched inputs return one value per body.
"""

from __future__ import annotations

import numpy as np

M_TO_MM = 1000.0


def _pair(pred: np.ndarray, gt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pred = np.asarray(pred, dtype=np.float64)
    gt = np.asarray(gt, dtype=np.float64)
    if pred.shape != gt.shape or pred.shape[-1] != 3:
        raise ValueError(f"expected matching (..., N, 3) arrays, got {pred.shape} and {gt.shape}")
    return pred, gt


def mean_distance_mm(pred: np.ndarray, gt: np.ndarray) -> np.ndarray | float:
    """Mean Euclidean distance between corresponding points, mm."""
    pred, gt = _pair(pred, gt)
    out = np.linalg.norm(pred - gt, axis=-1).mean(axis=-1) * M_TO_MM
    return float(out) if np.ndim(out) == 0 else out


def pve(pred_vertices: np.ndarray, gt_vertices: np.ndarray) -> np.ndarray | float:
    """Per-vertex error: mean vertex distance, mm."""
    return mean_distance_mm(pred_vertices, gt_vertices)


def mpjpe(pred_joints: np.ndarray, gt_joints: np.ndarray) -> np.ndarray | float:
    """Mean per-joint position error, mm (no alignment: compose with `root_aligned` if wanted)."""
    return mean_distance_mm(pred_joints, gt_joints)


def root_aligned(pred: np.ndarray, gt: np.ndarray, root: int | tuple[int, ...] | np.ndarray) -> np.ndarray:
    """`pred` translated so that its root coincides with the ground truth's.

    `root` indexes the rows that define the root (several rows: their mean, e.g. the two hips).
    """
    pred, gt = _pair(pred, gt)
    idx = np.atleast_1d(np.asarray(root))
    offset = gt[..., idx, :].mean(axis=-2, keepdims=True) - pred[..., idx, :].mean(axis=-2, keepdims=True)
    return pred + offset


def procrustes_align(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """`pred` (N, 3) after the similarity transform (rotation, translation, scale) that best maps it
    onto `gt` in the least-squares sense (Umeyama 1991)."""
    pred, gt = _pair(pred, gt)
    if pred.ndim == 3:
        return np.stack([procrustes_align(p, g) for p, g in zip(pred, gt)])
    mu_p, mu_g = pred.mean(axis=0), gt.mean(axis=0)
    p, g = pred - mu_p, gt - mu_g
    var_p = (p**2).sum()
    if var_p == 0:
        return np.broadcast_to(mu_g, pred.shape).copy()
    U, S, Vt = np.linalg.svd(g.T @ p)
    D = np.eye(3)
    D[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ D @ Vt
    scale = float(np.trace(np.diag(S) @ D)) / var_p
    return scale * p @ R.T + mu_g


def pa_mpjpe(pred_joints: np.ndarray, gt_joints: np.ndarray) -> np.ndarray | float:
    """MPJPE after Procrustes alignment (rotation, translation and scale), mm."""
    return mean_distance_mm(procrustes_align(pred_joints, gt_joints), gt_joints)


def mesh_edges(faces: np.ndarray) -> np.ndarray:
    """(E, 2) unique undirected edges of a triangle mesh."""
    faces = np.asarray(faces, dtype=np.int64)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    return np.unique(np.sort(edges, axis=1), axis=0)


def mpere(pred_vertices: np.ndarray, gt_vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | float:
    """Mean per-edge relative error (thesis Eq. 10): mean over mesh edges of
    |len_pred - len_gt| / len_gt. Dimensionless (0.05 = 5 %); it measures shape distortion
    independent of placement."""
    pred, gt = _pair(pred_vertices, gt_vertices)
    e = mesh_edges(faces)
    len_p = np.linalg.norm(pred[..., e[:, 0], :] - pred[..., e[:, 1], :], axis=-1)
    len_g = np.linalg.norm(gt[..., e[:, 0], :] - gt[..., e[:, 1], :], axis=-1)
    valid = len_g > 0
    out = (np.abs(len_p - len_g)[..., valid] / len_g[..., valid]).mean(axis=-1)
    return float(out) if np.ndim(out) == 0 else out


def projected_area(
    vertices: np.ndarray,
    faces: np.ndarray,
    view_direction: np.ndarray,
    up: np.ndarray,
    cell: float = 0.01,
) -> float:
    """Area (m²) of a mesh's orthographic projection onto the vertical plane facing `view_direction`.

    The plane's axes are `up` and the horizontal direction across the view; every triangle is
    rasterized onto a grid of `cell` metres and the covered cells counted (the union of the triangles,
    so overlapping limbs count once). Rasterization covers every cell the outline touches, which adds
    about half a cell along the outline; that band (outline length x cell / 2) is subtracted. Residual
    error: below 1 % for a body at the 1 cm default (a sphere: +0.7 %, a box: +0.01 %).
    """
    import cv2

    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    view = np.asarray(view_direction, dtype=np.float64)
    view = view - up * (view @ up)  # horizontal component: the plane is vertical
    if np.linalg.norm(view) < 1e-9:
        raise ValueError("view_direction must not be vertical")
    view = view / np.linalg.norm(view)
    across = np.cross(up, view)
    v = np.asarray(vertices, dtype=np.float64)
    uv = np.stack([v @ across, -(v @ up)], axis=1)  # image-like: rows grow downwards
    lo = uv.min(axis=0)
    px = np.round((uv - lo) / cell).astype(np.int32)
    size = px.max(axis=0) + 1
    canvas = np.zeros((int(size[1]) + 1, int(size[0]) + 1), dtype=np.uint8)
    for tri in px[np.asarray(faces, dtype=np.int64)]:
        cv2.fillConvexPoly(canvas, tri, 1)
    contours, _ = cv2.findContours(canvas, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    outline = sum(cv2.arcLength(c, closed=True) for c in contours)
    return float(canvas.sum() - 0.5 * outline) * cell * cell


def lidar_density(
    num_points: int,
    vertices: np.ndarray,
    faces: np.ndarray,
    sensor_position: np.ndarray,
    up: np.ndarray,
    cell: float = 0.01,
) -> float:
    """Thesis Eq. 9: points per m² of the body's projection onto the vertical plane facing the sensor.

    The plane faces the sensor along the horizontal line from `sensor_position` to the body's centre;
    `up` is the world's up direction in the same frame (camera frame of a level camera: (0, -1, 0)).
    """
    v = np.asarray(vertices, dtype=np.float64)
    centre = 0.5 * (v.min(axis=0) + v.max(axis=0))
    area = projected_area(v, faces, centre - np.asarray(sensor_position, dtype=np.float64), up, cell)
    return float(num_points) / area if area > 0 else 0.0
