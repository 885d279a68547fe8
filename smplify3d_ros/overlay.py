"""The picture of a fit: meshes and keypoints of the fitted bodies drawn over the camera image."""

from __future__ import annotations

import cv2
import numpy as np

from msg_adapters.markers import person_color
from smplify3d_ros.camera import project_points
from smplify3d_ros.keypoints import COCO17_SKELETON
from smplify3d_ros.types import BodyFit, Frame


def overlay_image(frame: Frame, fits: list[BodyFit], faces: np.ndarray, alpha: float = 0.6) -> np.ndarray:
    """The frame's image (RGB) with each fit's mesh drawn over it (shaded, painter's order) and its
    projected 3D keypoints; fits must be in the camera frame."""
    cam = frame.camera
    image = frame.image if frame.image is not None else np.full((cam.height, cam.width, 3), 64, np.uint8)
    canvas = np.ascontiguousarray(image.copy())
    tris, colors, depths = [], [], []
    for fit in fits:
        v = np.asarray(fit.vertices, np.float64)
        tri = v[faces]
        normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
        centre = tri.mean(axis=1)
        view = -centre / (np.linalg.norm(centre, axis=1, keepdims=True) + 1e-12)
        facing = np.abs((normal * view).sum(axis=1))  # winding-agnostic; depth order hides back faces
        front = centre[:, 2] > 0.1
        uv = project_points(v, cam)
        base = np.array(person_color(fit.person_id)) * 255.0
        shade = 0.35 + 0.65 * facing[front]
        tris.append(uv[faces[front]])
        colors.append(shade[:, None] * base[None])
        depths.append(centre[front, 2])
    if tris:
        tris_all, colors_all, depths_all = np.concatenate(tris), np.concatenate(colors), np.concatenate(depths)
        ok = np.isfinite(tris_all).all(axis=(1, 2))
        order = np.argsort(-depths_all[ok])
        layer = canvas.copy()
        mask = np.zeros(canvas.shape[:2], np.uint8)
        for poly, color in zip(tris_all[ok][order], colors_all[ok][order]):
            fixed = np.round(poly * 4).astype(np.int32)  # 2 fractional bits (shift=2): sub-pixel edges
            cv2.fillConvexPoly(layer, fixed, color.tolist(), cv2.LINE_AA, 2)
            cv2.fillConvexPoly(mask, fixed, 255, cv2.LINE_8, 2)
        covered = mask > 0
        canvas[covered] = (alpha * layer[covered] + (1 - alpha) * canvas[covered]).astype(np.uint8)
    for fit in fits:
        uv = project_points(np.asarray(fit.keypoints3d, np.float64), cam)
        color = tuple(int(c * 255) for c in person_color(fit.person_id))
        for a, b in COCO17_SKELETON:
            if np.isfinite(uv[[a, b]]).all():
                cv2.line(canvas, tuple(np.round(uv[a]).astype(int)), tuple(np.round(uv[b]).astype(int)),
                         (255, 255, 255), 1, cv2.LINE_AA)
        for p in uv[np.isfinite(uv).all(axis=1)]:
            cv2.circle(canvas, tuple(np.round(p).astype(int)), 3, color, -1, cv2.LINE_AA)
        finite = uv[np.isfinite(uv).all(axis=1)]
        if len(finite):
            x, y = np.round(finite.min(axis=0)).astype(int)
            cv2.putText(canvas, f"id {fit.person_id}", (int(x), max(int(y) - 6, 12)), cv2.FONT_HERSHEY_SIMPLEX,
                        0.5, (255, 255, 255), 1, cv2.LINE_AA)
    return canvas


def top_view(frame: Frame, fits: list[BodyFit], height: int, margin_m: float = 1.5, min_depth_m: float = 4.0,
             ground_clearance_m: float = 0.15) -> np.ndarray:
    """A bird's-eye view (camera frame, x right, z forward; square, `height` px) of the fitted bodies
    (their colours) and the LiDAR scan above the ground (white), with the camera's field of view."""
    from smplify3d_ros.camera import transform_points

    size = height
    canvas = np.full((size, size, 3), 30, np.uint8)
    depth = max([float(np.asarray(f.vertices)[:, 2].max()) for f in fits] + [min_depth_m]) + margin_m
    scale = size / depth  # pixels per metre

    def to_px(x: np.ndarray, z: np.ndarray) -> np.ndarray:
        return np.stack([size / 2 + x * scale, size - 1 - z * scale], axis=1).round().astype(np.int32)

    cam = frame.camera
    half_fov = np.arctan2(cam.width / 2, cam.K[0, 0])
    for sign in (-1, 1):
        end = to_px(np.array([sign * depth * np.tan(half_fov)]), np.array([depth]))[0]
        cv2.line(canvas, (size // 2, size - 1), tuple(int(c) for c in end), (90, 90, 90), 1, cv2.LINE_AA)
    points = transform_points(np.asarray(frame.points_lidar, np.float64), frame.T_cam_lidar)
    ground_y = max([float(np.asarray(f.vertices)[:, 1].max()) for f in fits], default=np.inf)
    keep = (points[:, 2] > 0) & (points[:, 2] < depth) & (points[:, 1] < ground_y - ground_clearance_m)
    for fit in fits:
        verts = np.asarray(fit.vertices, np.float64)[::4]
        color = tuple(int(c * 255) for c in person_color(fit.person_id))
        for u, v in to_px(verts[:, 0], verts[:, 2]):
            if 0 <= u < size and 0 <= v < size:
                canvas[v, u] = color
    for u, v in to_px(points[keep, 0], points[keep, 2]):  # the scan on top, so the bodies' points show
        cv2.circle(canvas, (int(u), int(v)), 1, (235, 235, 235), -1)
    cv2.putText(canvas, f"top view, {depth:.0f} m", (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (220, 220, 220), 1,
                cv2.LINE_AA)
    return canvas
