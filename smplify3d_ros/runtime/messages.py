"""One synchronized set of input messages, and the `Frame` it says: the drivers' input side.

Every reason a set cannot become a frame is a `FrameDrop` with one of the DROP_* keys, which the
processor counts and logs.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

from msg_adapters import (
    CameraInfoError,
    ImageError,
    KeypointError,
    PointCloudError,
    camera_info_to_model,
    compressed_to_numpy,
    image_to_numpy,
    read_keypoints,
    read_points,
    stamp_to_ns,
    to_rgb8,
)
from smplify3d_ros.runtime.transforms import Transforms
from smplify3d_ros.types import Frame

# Frames that are not published, by reason (`ProcessorStats.drops` keys).
DROP_BAD_IMAGE = "bad_image"  # undecodable, zero-size or truncated image
DROP_IMAGE_SIZE = "image_size_mismatch"  # image size differs from the camera info's
DROP_BAD_CAMERA_INFO = "bad_camera_info"  # uncalibrated or malformed camera info
DROP_BAD_POINTS = "bad_points"  # malformed LiDAR cloud (truncated data, missing x/y/z, ...)
DROP_EMPTY_CLOUD = "empty_cloud"  # LiDAR cloud without points
DROP_NO_FINITE_POINTS = "no_finite_points"  # LiDAR cloud whose points are all NaN / inf
DROP_BAD_KEYPOINTS = "bad_keypoints"  # keypoint cloud that cannot be read
DROP_BAD_STAMP = "bad_stamp"  # a message without a usable header stamp
DROP_TIME_BACKWARDS = "time_backwards"  # stamp older than the last frame's (within time_reset_s)
DROP_DUPLICATE = "duplicate_stamp"  # same stamp as the last frame
DROP_NO_TRANSFORM = "no_transform"  # no transform to the output frame
DROP_FIT_ERROR = "fit_error"  # the fitting raised (a bug): logged with its traceback
DROP_INTERNAL = "internal_error"  # anything else raised while handling the frame (a bug): logged
DROP_QUEUE = "stale"  # (node) replaced in the worker queue by a newer frame before it was fitted

# Keypoint points ignored in a frame that was used (`counts` of `to_frame`, `keypoints_ignored.*` values).
IGNORED_OUT_OF_FORMAT = "out_of_format"  # joint index outside the keypoint format (e.g. 99 for COCO-17)
IGNORED_NON_FINITE = "non_finite"  # NaN / inf u or v: the joint reads as missing
IGNORED_BAD_SCORE = "bad_score"  # NaN / inf score: the joint reads as missing
IGNORED_DUPLICATE = "duplicate"  # a (person, joint) given twice: the higher score is kept


class FrameDrop(Exception):
    """The frame cannot be used; `reason` is one of the DROP_* keys."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(f"{reason}: {message}")
        self.reason = reason
        self.message = message


@dataclass
class FrameMessages:
    """The messages of one synchronized frame, of either runtime (rclpy or rosbags)."""

    camera_info: Any  # sensor_msgs/CameraInfo
    points: Any  # sensor_msgs/PointCloud2, LiDAR frame
    keypoints: Any  # sensor_msgs/PointCloud2, keypoint encoding
    image: Any | None = None  # sensor_msgs/Image or CompressedImage; None: run without the image
    compressed: bool = False  # `image` is a CompressedImage
    received_s: float = 0.0  # time.monotonic() when the set was complete (queue latency)
    arrival_s: float | None = None  # node clock minus the stamp when the set was complete (None: unknown)

    @property
    def stamp(self) -> Any:
        """The frame's stamp message: the image's, else the keypoints' (equal by the encoding's contract)."""
        return (self.image if self.image is not None else self.keypoints).header.stamp

    @property
    def stamp_ns(self) -> int:
        return stamp_to_ns(self.stamp)


def to_frame(msgs: FrameMessages, keypoint_format: str, transforms: Transforms, default_camera_frame: str,
             counts: Counter | None = None) -> Frame:
    """Messages -> Frame (all people, as detected). Raises FrameDrop. Keypoint points it ignores are added
    to `counts` by IGNORED_* reason."""
    try:
        camera = camera_info_to_model(msgs.camera_info)
    except (CameraInfoError, ValueError, TypeError) as e:
        raise FrameDrop(DROP_BAD_CAMERA_INFO, str(e)) from None
    image = None
    frame_id = str(msgs.camera_info.header.frame_id)
    if msgs.image is not None:
        try:
            image = compressed_to_numpy(msgs.image) if msgs.compressed else image_to_numpy(msgs.image)
            image = to_rgb8(image)
        except (ImageError, ValueError, TypeError) as e:
            raise FrameDrop(DROP_BAD_IMAGE, str(e)) from None
        if image.shape[:2] != (camera.height, camera.width):
            raise FrameDrop(DROP_IMAGE_SIZE, f"image is {image.shape[1]}x{image.shape[0]}, camera info says "
                            f"{camera.width}x{camera.height}")
        frame_id = str(msgs.image.header.frame_id) or frame_id
    frame_id = frame_id or default_camera_frame
    try:
        cloud = read_points(msgs.points)
    except (PointCloudError, ValueError, TypeError) as e:
        raise FrameDrop(DROP_BAD_POINTS, str(e)) from None
    if len(cloud) == 0:
        total = int(msgs.points.width) * int(msgs.points.height)
        if total == 0:
            raise FrameDrop(DROP_EMPTY_CLOUD, "the LiDAR cloud has no points")
        raise FrameDrop(DROP_NO_FINITE_POINTS, f"all {total} LiDAR points are NaN, inf or at the origin")
    try:
        kps = read_keypoints(msgs.keypoints, keypoint_format)
    except (KeypointError, PointCloudError, ValueError, TypeError) as e:
        raise FrameDrop(DROP_BAD_KEYPOINTS, str(e)) from None
    if counts is not None:
        for reason, n in ((IGNORED_OUT_OF_FORMAT, kps.dropped_joints), (IGNORED_NON_FINITE, kps.nan_points),
                          (IGNORED_BAD_SCORE, kps.bad_scores), (IGNORED_DUPLICATE, kps.duplicate_joints)):
            if n:
                counts[reason] += n
    stamp_ns = msgs.stamp_ns
    T = transforms.cam_from_lidar(frame_id, cloud.frame_id, stamp_ns)
    return Frame(
        stamp_ns=stamp_ns, camera=camera, keypoints=kps.keypoints, person_ids=kps.person_ids,
        points_lidar=cloud.xyz, T_cam_lidar=T, image=image, frame_id=frame_id,
    )
