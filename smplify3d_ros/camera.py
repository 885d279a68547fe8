"""Camera projection: the one place that maps camera-frame points to pixels and back.

Distortion follows ROS CameraInfo: "plumb_bob" / "rational_polynomial" are OpenCV's radial-tangential
model (D = k1, k2, p1, p2, k3[, k4, k5, k6]); "equidistant" is OpenCV's fisheye model (D = k1..k4).
"""

from __future__ import annotations

import cv2
import numpy as np

from smplify3d_ros.types import CameraModel

_RADTAN = ("plumb_bob", "rational_polynomial")
_FISHEYE = ("equidistant", "fisheye")


def _check_model(camera: CameraModel) -> None:
    if camera.has_distortion and camera.distortion_model not in _RADTAN + _FISHEYE:
        raise ValueError(
            f"unsupported distortion model {camera.distortion_model!r}; "
            f"supported: {', '.join(_RADTAN + _FISHEYE)}"
        )


def project_points(points: np.ndarray, camera: CameraModel, distort: bool = True) -> np.ndarray:
    """(N, 3) camera-frame points -> (N, 2) pixels. Points at z <= 0 come back as NaN."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    uv = np.full((len(points), 2), np.nan)
    front = points[:, 2] > 0
    if not front.any():
        return uv
    _check_model(camera)
    if not (distort and camera.has_distortion):
        p = points[front]
        uv[front] = (p[:, :2] / p[:, 2:3]) @ camera.K[:2, :2].T + camera.K[:2, 2]
        return uv
    zero = np.zeros(3)
    obj = points[front].reshape(-1, 1, 3)
    if camera.distortion_model in _FISHEYE:
        d = np.zeros(4)
        d[: min(4, len(camera.dist_coeffs))] = camera.dist_coeffs[:4]
        img, _ = cv2.fisheye.projectPoints(obj, zero, zero, camera.K, d)
    else:
        img, _ = cv2.projectPoints(obj, zero, zero, camera.K, np.asarray(camera.dist_coeffs, float))
    uv[front] = img.reshape(-1, 2)
    return uv


def pinhole_pixels(points: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 3) camera-frame points -> (N, 2) pixels of the ideal pinhole camera `K` (undistorted image),
    depths clamped to 1 mm: for the fitting core, which works in that image and is given K alone."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    z = np.maximum(points[:, 2], 1e-3)
    return np.stack([K[0, 0] * points[:, 0] / z + K[0, 2], K[1, 1] * points[:, 1] / z + K[1, 2]], axis=1)


def undistort_pixels(uv: np.ndarray, camera: CameraModel) -> np.ndarray:
    """(N, 2) distorted pixels -> (N, 2) pixels of the ideal pinhole camera with the same K."""
    uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
    if not camera.has_distortion or len(uv) == 0:
        return uv.copy()
    _check_model(camera)
    # contiguous: cv2.fisheye.undistortPoints reads a strided view (a keypoint array's u, v columns) as if
    # it were packed, and returned other keypoints' scores as coordinates
    src = np.ascontiguousarray(uv).reshape(-1, 1, 2)
    if camera.distortion_model in _FISHEYE:
        d = np.zeros(4)
        d[: min(4, len(camera.dist_coeffs))] = camera.dist_coeffs[:4]
        out = cv2.fisheye.undistortPoints(src, camera.K, d, P=camera.K)
    else:
        out = cv2.undistortPoints(
            src, camera.K, np.asarray(camera.dist_coeffs, float), P=camera.K,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-6),
        )
    return out.reshape(-1, 2)


def in_image(uv: np.ndarray, camera: CameraModel, margin: float = 0.0) -> np.ndarray:
    """(N,) bool: pixel inside the image, shrunk by `margin` px (NaN is outside)."""
    u, v = uv[:, 0], uv[:, 1]
    with np.errstate(invalid="ignore"):
        return (
            (u >= margin) & (u <= camera.width - 1 - margin)
            & (v >= margin) & (v <= camera.height - 1 - margin)
        )


def transform_points(points: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Apply a 4x4 rigid transform to (N, 3) points; keeps the input's float dtype."""
    points = np.asarray(points)
    dtype = points.dtype if np.issubdtype(points.dtype, np.floating) else np.float64
    out = points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    return out.astype(dtype, copy=False)
