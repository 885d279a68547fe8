"""Simulated camera: intrinsics from a field of view, and a ray-cast image with Lambert shading.

The image is rendered by casting one ray per pixel through the (distorted) lens: each pixel centre is
undistorted to its viewing ray, so the picture, the depth buffer and the label image carry exactly the
camera's distortion, like the keypoints projected with `smplify3d_ros.camera.project_points`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplify3d_ros.camera import in_image, project_points, undistort_pixels
from smplify3d_ros.sim.config import CameraSimConfig, RenderConfig
from smplify3d_ros.sim.raycast import LABEL_GROUND, LABEL_NONE, RayScene
from smplify3d_ros.types import CameraModel


def make_camera(cfg: CameraSimConfig) -> CameraModel:
    """Pinhole intrinsics with square pixels and the principal point at the image centre."""
    f = cfg.width / 2.0 / np.tan(np.deg2rad(cfg.hfov_deg) / 2.0)
    K = np.array([[f, 0.0, (cfg.width - 1) / 2.0], [0.0, f, (cfg.height - 1) / 2.0], [0.0, 0.0, 1.0]])
    return CameraModel(
        K=K,
        width=cfg.width,
        height=cfg.height,
        distortion_model=cfg.distortion_model,
        dist_coeffs=np.asarray(cfg.dist_coeffs, dtype=np.float64),
    )


_RAY_CACHE: dict[tuple, np.ndarray] = {}


def pixel_rays(camera: CameraModel) -> np.ndarray:
    """(H*W, 3) unit viewing rays (camera frame) through every pixel centre, row-major."""
    key = (
        camera.width,
        camera.height,
        camera.K.tobytes(),
        camera.distortion_model,
        np.asarray(camera.dist_coeffs).tobytes(),
    )
    if key not in _RAY_CACHE:
        v, u = np.mgrid[0 : camera.height, 0 : camera.width]
        uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
        ideal = undistort_pixels(uv, camera)
        xy = (ideal - camera.K[:2, 2]) / np.diag(camera.K)[:2]
        rays = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
        _RAY_CACHE[key] = rays / np.linalg.norm(rays, axis=1, keepdims=True)
    return _RAY_CACHE[key]


@dataclass
class Rendering:
    """What the camera sees: colour, depth and, per pixel, which surface."""

    image: np.ndarray  # (H, W, 3) uint8 RGB
    depth: np.ndarray  # (H, W) float32 z-depth in the camera frame, m; inf where nothing was hit
    label: np.ndarray  # (H, W) int32 person id >= 0, -1 ground, -2 static object, -3 nothing

    @property
    def mask(self) -> np.ndarray:
        """(H, W) int32 person id, -1 where no person is seen."""
        return np.where(self.label >= 0, self.label, -1).astype(np.int32)


def render(
    scene: RayScene,
    camera: CameraModel,
    face_colors: np.ndarray,
    style: RenderConfig,
    T_world_cam: np.ndarray | None = None,
) -> Rendering:
    """Ray-cast `scene` (camera frame) through every pixel.

    `face_colors` (F, 3) uint8 gives each scene face its albedo. With `T_world_cam`, the ground gets a
    checkerboard in world coordinates and the light direction is read in the world frame; without it,
    the light direction is taken in the camera frame.
    """
    H, W = camera.height, camera.width
    rays = pixel_rays(camera)
    hits = scene.cast(np.zeros(3), rays)
    hit = hits.hit
    light = np.asarray(style.light_direction, dtype=np.float64)
    if T_world_cam is not None:
        light = T_world_cam[:3, :3].T @ light
    light = light / np.linalg.norm(light)
    ray_hit, distance = rays[hit], hits.distance[hit]
    n = hits.normal[hit]
    n = np.where((np.einsum("ij,ij->i", n, ray_hit) > 0)[:, None], -n, n)  # face the camera
    shade = style.ambient + (1.0 - style.ambient) * np.clip(n @ light, 0.0, None)
    albedo = face_colors[hits.face[hit]] * shade[:, None]
    if T_world_cam is not None:
        ground = hits.label[hit] == LABEL_GROUND
        if ground.any():
            p_cam = ray_hit[ground] * distance[ground, None]
            p_world = p_cam @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
            cell = np.floor(p_world[:, :2] / style.ground_checker_m).astype(np.int64).sum(axis=1) % 2
            albedo[ground] *= (1.0 + style.ground_checker_contrast * (2 * cell - 1))[:, None]
    rgb = np.empty((len(rays), 3), dtype=np.uint8)
    rgb[:] = style.sky_rgb
    rgb[hit] = np.clip(albedo, 0, 255).astype(np.uint8)
    depth = np.full(len(rays), np.inf, dtype=np.float32)
    depth[hit] = distance * ray_hit[:, 2]
    label = np.full(len(rays), LABEL_NONE, dtype=np.int32)
    label[hit] = hits.label[hit]
    return Rendering(
        image=rgb.reshape(H, W, 3),
        depth=depth.reshape(H, W),
        label=label.reshape(H, W),
    )


def visible_fraction(
    scene: RayScene,
    camera: CameraModel,
    person_id: int,
    vertices: np.ndarray,
    max_rays: int,
    max_layers: int = 8,
) -> float:
    """Fraction of a person's silhouette the camera sees: not hidden by other people or objects, and
    inside the image.

    Rays on a regular grid (pinhole directions, at most `max_rays`, never finer than a pixel) cover the
    person's projected bounding box, unbounded by the image. The silhouette is the set of rays that hit
    the person when everything else is peeled away (up to `max_layers` surfaces in front; the ground
    is never in front of a standing person); the visible part is the set whose first hit is the person
    and whose distorted projection falls inside the image.
    """
    v = np.asarray(vertices, dtype=np.float64)
    v = v[v[:, 2] > 1e-3]
    if len(v) == 0:
        return 0.0
    xy = v[:, :2] / v[:, 2:3]
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    step = max(1.0 / camera.K[0, 0], float(np.sqrt(np.prod(hi - lo) / max_rays)))
    gx = np.arange(lo[0] + step / 2, hi[0], step)
    gy = np.arange(lo[1] + step / 2, hi[1], step)
    X, Y = np.meshgrid(gx, gy)
    rays = np.stack([X.ravel(), Y.ravel(), np.ones(X.size)], axis=1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    hits = scene.cast(np.zeros(3), rays)
    first_is_person = hits.label == person_id
    on_person = first_is_person.copy()
    pending = hits.hit & ~first_is_person & (hits.label != LABEL_GROUND)
    distance = hits.distance.copy()
    for _ in range(max_layers):
        if not pending.any():
            break
        idx = np.flatnonzero(pending)
        eps = 1e-4 * np.maximum(distance[idx], 1.0)
        again = scene.cast(rays[idx] * (distance[idx] + eps)[:, None], rays[idx])
        distance[idx] = distance[idx] + eps + again.distance
        on_person[idx] = again.label == person_id
        pending[idx] = again.hit & (again.label != person_id) & (again.label != LABEL_GROUND)
    silhouette = int(on_person.sum())
    if silhouette == 0:
        return 0.0
    seen = first_is_person & in_image(project_points(rays, camera), camera)
    return float(seen.sum()) / silhouette
