"""ROS messages <-> numpy arrays and the project's dataclasses, for rclpy and rosbags messages alike.

Readers take any object with the message's field names (rclpy messages, rosbags messages). Writers build
messages through a `MessageFactory` (`RclpyFactory` or `RosbagsFactory`; default: rclpy when installed).
No algorithm lives here, and nothing imports rclpy at import time.
"""

from msg_adapters.bodies import BodiesError, bodies_json_to_params, clip, fits_to_bodies_json
from msg_adapters.camera_info import CameraInfoError, camera_info_to_model, camera_model_to_msg
from msg_adapters.diagnostics import diagnostics_array
from msg_adapters.factory import (
    MessageFactory,
    RclpyFactory,
    RosbagsFactory,
    default_factory,
    split_stamp,
    stamp_to_ns,
    stamp_to_sec,
    to_plain,
)
from msg_adapters.image import (
    ImageError,
    compressed_to_numpy,
    image_to_numpy,
    numpy_to_compressed,
    numpy_to_image,
    to_rgb8,
)
from msg_adapters.keypoints import (
    KEYPOINT_FORMATS,
    KeypointError,
    KeypointFormat,
    KeypointSet,
    get_keypoint_format,
    read_keypoints,
    write_keypoints,
)
from msg_adapters.markers import fits_to_markers
from msg_adapters.outputs import fits_to_body_points_cloud, fits_to_joints_cloud, fits_to_pose_array
from msg_adapters.pointcloud2 import (
    CloudData,
    PointCloudError,
    field_names,
    make_pointcloud2,
    read_fields,
    read_points,
)

__all__ = [
    "KEYPOINT_FORMATS",
    "BodiesError",
    "CameraInfoError",
    "CloudData",
    "ImageError",
    "KeypointError",
    "KeypointFormat",
    "KeypointSet",
    "MessageFactory",
    "PointCloudError",
    "RclpyFactory",
    "RosbagsFactory",
    "bodies_json_to_params",
    "camera_info_to_model",
    "camera_model_to_msg",
    "clip",
    "compressed_to_numpy",
    "default_factory",
    "diagnostics_array",
    "field_names",
    "fits_to_bodies_json",
    "fits_to_body_points_cloud",
    "fits_to_joints_cloud",
    "fits_to_markers",
    "fits_to_pose_array",
    "get_keypoint_format",
    "image_to_numpy",
    "make_pointcloud2",
    "numpy_to_compressed",
    "numpy_to_image",
    "read_fields",
    "read_keypoints",
    "read_points",
    "split_stamp",
    "stamp_to_ns",
    "stamp_to_sec",
    "to_plain",
    "to_rgb8",
    "write_keypoints",
]
