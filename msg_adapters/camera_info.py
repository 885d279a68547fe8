"""sensor_msgs/CameraInfo <-> smplify3d_ros.types.CameraModel.

The model describes the image as published: with binning or a region of interest set, K and the image
size are reduced the way image_geometry's PinholeCameraModel does it (cx' = (cx - x_offset) / binning_x,
fx' = fx / binning_x, ...). Distortion coefficients are unchanged by both, since they act on normalized
coordinates.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from msg_adapters.factory import MessageFactory, resolve_factory
from smplify3d_ros.types import CameraModel


class CameraInfoError(ValueError):
    """A CameraInfo message that does not describe a usable camera; the message says why."""


# Distortion models and the numbers of coefficients OpenCV accepts for each (0: no distortion).
DISTORTION_MODELS: dict[str, tuple[int, ...]] = {
    "": (0,),
    "plumb_bob": (0, 4, 5, 8, 12, 14),
    "rational_polynomial": (0, 8, 12, 14),
    "equidistant": (0, 4),
    "fisheye": (0, 4),
}


def camera_info_to_model(msg: Any) -> CameraModel:
    """CameraInfo -> CameraModel, validated.

    Raises CameraInfoError for: K without 9 finite values, fx or fy <= 0 (an uncalibrated camera
    publishes K = 0), a zero image size, non-finite distortion coefficients, an unknown distortion model
    with non-zero coefficients, or a coefficient count the model does not have.
    """
    k = np.asarray(msg.k, dtype=np.float64).reshape(-1)
    if k.size != 9 or not np.isfinite(k).all():
        raise CameraInfoError(f"K must hold 9 finite values, got {k.tolist()}")
    K = k.reshape(3, 3).copy()
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CameraInfoError(
            f"fx = {K[0, 0]}, fy = {K[1, 1]} must be > 0 (is the camera calibrated?)"
        )
    width, height = int(msg.width), int(msg.height)
    if width <= 0 or height <= 0:
        raise CameraInfoError(f"image size {width}x{height} must be > 0")
    d = np.asarray(msg.d, dtype=np.float64).reshape(-1).copy()
    if not np.isfinite(d).all():
        raise CameraInfoError(f"distortion coefficients must be finite, got {d.tolist()}")
    model = str(msg.distortion_model)
    counts = DISTORTION_MODELS.get(model)
    if counts is None:
        if np.any(d != 0):
            raise CameraInfoError(
                f"unsupported distortion model {model!r}; supported: "
                + ", ".join(repr(m) for m in DISTORTION_MODELS if m)
            )
    elif len(d) not in counts and np.any(d != 0):
        raise CameraInfoError(f"distortion model {model!r} takes {counts[1:]} coefficients, got {len(d)}")
    K, width, height = _apply_binning_and_roi(msg, K, width, height)
    return CameraModel(K=K, width=width, height=height, distortion_model=model, dist_coeffs=d)


def _apply_binning_and_roi(msg: Any, K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, int, int]:
    bx = max(int(getattr(msg, "binning_x", 0)), 1)
    by = max(int(getattr(msg, "binning_y", 0)), 1)
    roi = getattr(msg, "roi", None)
    x0 = y0 = 0
    if roi is not None and int(roi.width) > 0 and int(roi.height) > 0:
        x0, y0 = int(roi.x_offset), int(roi.y_offset)
        if x0 + int(roi.width) > width or y0 + int(roi.height) > height:
            raise CameraInfoError(
                f"roi {roi.width}x{roi.height}+{x0}+{y0} lies outside the {width}x{height} image"
            )
        width, height = int(roi.width), int(roi.height)
    if bx == 1 and by == 1 and x0 == 0 and y0 == 0:
        return K, width, height
    K = K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    K[0] /= bx
    K[1] /= by
    return K, width // bx, height // by


def camera_model_to_msg(
    camera: CameraModel, stamp: Any, frame_id: str, factory: MessageFactory | None = None
) -> Any:
    """CameraModel -> CameraInfo (no binning, no ROI; R = identity, P = [K | 0])."""
    factory = resolve_factory(factory)
    K = np.asarray(camera.K, dtype=np.float64).reshape(3, 3)
    P = np.zeros((3, 4))
    P[:, :3] = K
    return factory.make(
        "sensor_msgs/msg/CameraInfo",
        header=factory.header(stamp, frame_id),
        height=int(camera.height),
        width=int(camera.width),
        distortion_model=str(camera.distortion_model),
        d=np.asarray(camera.dist_coeffs, dtype=np.float64).reshape(-1),
        k=K.reshape(-1),
        r=np.eye(3).reshape(-1),
        p=P.reshape(-1),
    )
