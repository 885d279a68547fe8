"""Fits -> the drivers' output messages: one table of output names and types for the node and replay.

Outputs are keyed by name: the node's own (`markers`, ...) are published on `~/<name>` (replay records them
as /smplify3d/<name>); absolute names are topics of their own (REP-155's /humans/bodies/..., /tf), the
same in the node and in the replay's bag (`output_topic`, `output_type`).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from msg_adapters import (
    MessageFactory,
    fits_to_bodies_json,
    fits_to_body_points_cloud,
    fits_to_joints_cloud,
    fits_to_markers,
    fits_to_pose_array,
    stamp_to_ns,
)
from msg_adapters.hri import has_type, ids_list_msg, joint_state_msg, skeleton2d_msg
from msg_adapters.outputs import (
    body_position,
    body_transform,
    clearing_cloud,
    clearing_points,
    point_stamped,
    twist_stamped,
)
from smplify3d_ros.runtime.config import PublishConfig
from smplify3d_ros.runtime.transforms import TF_TOPIC, tf_message
from smplify3d_ros.types import BodyFit, Frame

NODE_NAME = "smplify3d"
# Output name -> message type; the node publishes each on ~/<name>, replay records it as /smplify3d/<name>.
OUTPUT_TYPES = {
    "markers": "visualization_msgs/msg/MarkerArray",
    "joints": "sensor_msgs/msg/PointCloud2",
    "body_points": "sensor_msgs/msg/PointCloud2",
    "people": "geometry_msgs/msg/PoseArray",
    "bodies": "std_msgs/msg/String",
    "clearing_points": "sensor_msgs/msg/PointCloud2",
}
OUTPUTS = tuple(OUTPUT_TYPES)
DIAGNOSTICS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
# The last token of an absolute output topic -> its type (REP-155 body topics, TF).
TOPIC_TYPES = {
    "tracked": "hri_msgs/msg/IdsList",
    "skeleton2d": "hri_msgs/msg/Skeleton2D",
    "joint_states": "sensor_msgs/msg/JointState",
    "position": "geometry_msgs/msg/PointStamped",
    "velocity": "geometry_msgs/msg/TwistStamped",
    "tf": "tf2_msgs/msg/TFMessage",
}


def output_topic(name: str, node_name: str = NODE_NAME) -> str:
    """The topic an output is recorded on: absolute names as they are, the node's own under /<node>/."""
    return name if name.startswith("/") else f"/{node_name}/{name}"


def output_type(name: str) -> str:
    return TOPIC_TYPES[name.rsplit("/", 1)[-1]] if name.startswith("/") else OUTPUT_TYPES[name]


def body_id(prefix: str, person_id: int) -> str | None:
    """REP-155 body id of a person (None for people without a track id: they get no per-body topics)."""
    return f"{prefix}{int(person_id)}" if person_id >= 0 else None


class VelocityEstimator:
    """Each body's velocity from its consecutive fits: the hip midpoint's finite difference over the stamp
    difference, restarted after a gap longer than `max_gap_s` or a change of frame. The one place where a
    tracker's own estimate takes over: a fit that already has a `velocity` keeps it."""

    def __init__(self, max_gap_s: float) -> None:
        self.max_gap_ns = round(max_gap_s * 1e9)
        self._last: dict[int, tuple[int, str, np.ndarray]] = {}  # person id -> (stamp ns, frame, position)

    def update(self, fits: list[BodyFit], stamp_ns: int, frame_id: str) -> list[BodyFit]:
        out = []
        for fit in fits:
            if fit.person_id < 0:
                out.append(fit)
                continue
            position = body_position(fit)
            last = self._last.get(fit.person_id)
            self._last[fit.person_id] = (stamp_ns, frame_id, position)
            if fit.velocity is None and last is not None and last[1] == frame_id \
                    and 0 < stamp_ns - last[0] <= self.max_gap_ns:
                fit = replace(fit, velocity=(position - last[2]) / ((stamp_ns - last[0]) * 1e-9))
            out.append(fit)
        # forget bodies gone longer than a gap (bounded memory) and every body after a jump back in time
        self._last = {pid: v for pid, v in self._last.items() if 0 <= stamp_ns - v[0] <= self.max_gap_ns}
        return out


@dataclass
class HriSettings:
    """Where and how the ROS4HRI outputs are published (topics.hri_bodies, publish.hri*)."""

    namespace: str = "/humans/bodies"
    tf_frames: bool = False  # body_<id> frames on /tf (the node turns it on when tf2_msgs is installed)


class OutputBuilder:
    """Builds one frame's output messages; remembers which marker ids are drawn, to delete vanished ones."""

    def __init__(self, publish: PublishConfig, faces: np.ndarray, factory: MessageFactory,
                 hri: HriSettings | None = None) -> None:
        self.publish = publish
        self.faces = faces
        self.factory = factory
        self.hri = hri or HriSettings()
        self.hri_msgs = has_type(factory, "hri_msgs/msg/IdsList")  # optional package: its outputs only then
        self.velocities = VelocityEstimator(publish.velocity_max_gap_s)
        self._marker_ids: set[int] = set()

    def build(self, fits: list[BodyFit], stamp: Any, frame_id: str, frame: Frame | None = None,
              skip: Collection[str] = ()) -> dict[str, Any]:
        """Output name -> message, for every enabled output not in `skip` (outputs nobody subscribes to;
        empty fits: empty messages, markers deleted). `frame` (the input frame, camera frame) gives the
        clearing fan and the 2D skeletons."""
        pub, f = self.publish, self.factory
        out: dict[str, Any] = {}

        def wanted(name: str) -> bool:
            return getattr(pub, name) and name not in skip

        if wanted("markers"):
            out["markers"], self._marker_ids = fits_to_markers(
                fits, self.faces, stamp, frame_id, self._marker_ids, f,
                max_triangles=pub.mesh_max_triangles or None, alpha=pub.marker_alpha, grid_m=pub.geometry_grid_m)
        if wanted("joints"):
            out["joints"] = fits_to_joints_cloud(fits, stamp, frame_id, f)
        if wanted("body_points"):
            out["body_points"] = fits_to_body_points_cloud(fits, stamp, frame_id, f, pub.body_points_stride,
                                                           pub.geometry_grid_m)
        if wanted("people"):
            out["people"] = fits_to_pose_array(fits, stamp, frame_id, f)
        if wanted("bodies"):
            out["bodies"] = f.make("std_msgs/msg/String", data=fits_to_bodies_json(fits, stamp, frame_id))
        if wanted("clearing_points") and frame is not None:
            fan = clearing_points(frame.camera, pub.clearing_range_m, pub.clearing_resolution_m, pub.clearing_view)
            out["clearing_points"] = clearing_cloud(fan, stamp, frame.frame_id, f)
        if pub.hri:
            out.update(self._hri(self.velocities.update(fits, stamp_to_ns(stamp), frame_id), stamp, frame_id, frame))
        return out

    def _hri(self, fits: list[BodyFit], stamp: Any, frame_id: str, frame: Frame | None) -> dict[str, Any]:
        """REP-155 per-body topics, the tracked list and the body frames."""
        f, ns = self.factory, self.hri.namespace
        out: dict[str, Any] = {}
        frames, tracked = [], []
        skeletons = _keypoints_by_id(frame) if frame is not None and self.hri_msgs else {}
        for fit in fits:
            bid = body_id(self.publish.hri_id_prefix, fit.person_id)
            if bid is None:
                continue
            tracked.append(bid)
            out[f"{ns}/{bid}/joint_states"] = joint_state_msg(list(fit.joint_names), fit.params.pose, bid, stamp, f)
            out[f"{ns}/{bid}/position"] = point_stamped(body_position(fit), stamp, frame_id, f)
            if fit.velocity is not None:
                out[f"{ns}/{bid}/velocity"] = twist_stamped(fit.velocity, stamp, frame_id, f)
            if fit.person_id in skeletons:
                out[f"{ns}/{bid}/skeleton2d"] = skeleton2d_msg(skeletons[fit.person_id], frame.camera.width,
                                                               frame.camera.height, stamp, frame.frame_id, f)
            frames.append((frame_id, f"body_{bid}", body_transform(fit)))
        if self.hri_msgs:
            out[f"{ns}/tracked"] = ids_list_msg(tracked, stamp, frame_id, f)
        if self.hri.tf_frames and frames:
            out[TF_TOPIC] = tf_message(frames, stamp, f)
        return out


def _keypoints_by_id(frame: Frame) -> dict[int, np.ndarray]:
    """The frame's detected (17, 3) keypoints by track id (people without an id left out)."""
    return {int(pid): kp for pid, kp in zip(frame.person_ids, frame.keypoints, strict=False) if pid >= 0}
