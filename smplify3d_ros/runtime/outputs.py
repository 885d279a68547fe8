"""Fits -> the drivers' output messages: one table of output names and types for the node and replay."""

from __future__ import annotations

from typing import Any

import numpy as np

from msg_adapters import (
    MessageFactory,
    fits_to_bodies_json,
    fits_to_body_points_cloud,
    fits_to_joints_cloud,
    fits_to_markers,
    fits_to_pose_array,
)
from smplify3d_ros.runtime.config import PublishConfig
from smplify3d_ros.types import BodyFit

NODE_NAME = "smplify3d"
# Output name -> message type; the node publishes each on ~/<name>, replay records it as /smplify3d/<name>.
OUTPUT_TYPES = {
    "markers": "visualization_msgs/msg/MarkerArray",
    "joints": "sensor_msgs/msg/PointCloud2",
    "body_points": "sensor_msgs/msg/PointCloud2",
    "people": "geometry_msgs/msg/PoseArray",
    "bodies": "std_msgs/msg/String",
}
OUTPUTS = tuple(OUTPUT_TYPES)
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"


class OutputBuilder:
    """Builds one frame's output messages; remembers which marker ids are drawn, to delete vanished ones."""

    def __init__(self, publish: PublishConfig, faces: np.ndarray, factory: MessageFactory) -> None:
        self.publish = publish
        self.faces = faces
        self.factory = factory
        self._marker_ids: set[int] = set()

    def build(self, fits: list[BodyFit], stamp: Any, frame_id: str) -> dict[str, Any]:
        """Output name -> message, for every enabled output (empty fits: empty messages, markers deleted)."""
        pub, f = self.publish, self.factory
        out: dict[str, Any] = {}
        if pub.markers:
            out["markers"], self._marker_ids = fits_to_markers(
                fits, self.faces, stamp, frame_id, self._marker_ids, f,
                max_triangles=pub.mesh_max_triangles or None, alpha=pub.marker_alpha)
        if pub.joints:
            out["joints"] = fits_to_joints_cloud(fits, stamp, frame_id, f)
        if pub.body_points:
            out["body_points"] = fits_to_body_points_cloud(fits, stamp, frame_id, f, pub.body_points_stride)
        if pub.people:
            out["people"] = fits_to_pose_array(fits, stamp, frame_id, f)
        if pub.bodies:
            out["bodies"] = f.make("std_msgs/msg/String", data=fits_to_bodies_json(fits, stamp, frame_id))
        return out
