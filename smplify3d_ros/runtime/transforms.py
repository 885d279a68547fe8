"""Where the drivers' transforms come from (TF, a bag's /tf_static, the extrinsic parameters), and fits
moved into the output frame."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np

from smplify3d_ros.camera import transform_points
from smplify3d_ros.geometry import invert, move_body, transform_from_quaternion
from smplify3d_ros.runtime.config import ExtrinsicConfig
from smplify3d_ros.types import BodyFit

# lookup(target_frame, source_frame, stamp_ns) -> (4, 4) taking source points into target, or None
TransformLookup = Callable[[str, str, int], "np.ndarray | None"]


def transform_msg_matrix(t: Any) -> np.ndarray:
    """geometry_msgs/TransformStamped (either runtime) -> (4, 4) taking child-frame points into the parent."""
    q, p = t.transform.rotation, t.transform.translation
    return transform_from_quaternion((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


class TransformGraph:
    """A tree of static transforms (a bag's /tf_static): `lookup(target, source)` composes the edges."""

    def __init__(self) -> None:
        self._edges: dict[str, dict[str, np.ndarray]] = {}

    def __len__(self) -> int:
        return sum(len(v) for v in self._edges.values()) // 2

    def add(self, msg: Any) -> None:
        """Every transform of a tf2_msgs/TFMessage."""
        for t in msg.transforms:
            T = transform_msg_matrix(t)
            parent, child = str(t.header.frame_id).lstrip("/"), str(t.child_frame_id).lstrip("/")
            # edges[a][b] takes points in frame a into frame b; T takes child points into the parent frame
            self._edges.setdefault(child, {})[parent] = T
            self._edges.setdefault(parent, {})[child] = invert(T)

    def lookup(self, target: str, source: str, stamp_ns: int | None = None) -> np.ndarray | None:
        target, source = target.lstrip("/"), source.lstrip("/")
        if source not in self._edges or target not in self._edges:
            return None
        best: dict[str, np.ndarray] = {source: np.eye(4)}  # frame -> (source points -> frame)
        todo = deque([source])
        while todo:
            frame = todo.popleft()
            if frame == target:
                return best[frame]
            for other, T in self._edges[frame].items():
                if other not in best:
                    best[other] = T @ best[frame]  # source -> frame -> other
                    todo.append(other)
        return None


class Transforms:
    """Transforms of one driver: `lookup` (TF, a bag's /tf_static) first, else the extrinsic parameters."""

    def __init__(self, extrinsic: ExtrinsicConfig, lookup: TransformLookup | None = None, log: Any = None) -> None:
        self.extrinsic = extrinsic
        self.lookup = lookup
        self.log = log or logging.getLogger(__name__)
        self._static = extrinsic.T_cam_lidar()
        self._warned: set[tuple[str, str]] = set()

    def _warn_once(self, key: tuple[str, str], text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.log.warning(text)

    def cam_from_lidar(self, camera_frame: str, lidar_frame: str, stamp_ns: int) -> np.ndarray:
        """(4, 4) taking the cloud's points into the camera frame."""
        if camera_frame and camera_frame == lidar_frame:
            return np.eye(4)
        if self.lookup is not None and camera_frame and lidar_frame:
            T = self.lookup(camera_frame, lidar_frame, stamp_ns)
            if T is not None:
                return T
            self._warn_once((camera_frame, lidar_frame),
                            f"no transform {lidar_frame!r} -> {camera_frame!r} available; using the "
                            "extrinsic parameters (extrinsic.*)")
        ext = self.extrinsic
        if (lidar_frame and lidar_frame != ext.lidar_frame) or (camera_frame and camera_frame != ext.camera_frame):
            self._warn_once(("names", f"{lidar_frame}>{camera_frame}"),
                            f"the extrinsic parameters relate {ext.lidar_frame!r} -> {ext.camera_frame!r} but "
                            f"the messages are in {lidar_frame!r} -> {camera_frame!r}; applying them anyway")
        return self._static

    def out_from_cam(self, output_frame: str, camera_frame: str, lidar_frame: str, stamp_ns: int) -> np.ndarray | None:
        """(4, 4) taking camera-frame geometry into `output_frame`; None when no transform is known."""
        if not output_frame or output_frame == camera_frame:
            return np.eye(4)
        if self.lookup is not None:
            T = self.lookup(output_frame, camera_frame, stamp_ns)
            if T is not None:
                return T
        if output_frame in (lidar_frame, self.extrinsic.lidar_frame):
            return invert(self.cam_from_lidar(camera_frame, lidar_frame, stamp_ns))
        return None


def transform_fit(fit: BodyFit, T: np.ndarray) -> BodyFit:
    """The same body expressed in another frame: geometry moved, root rotation and translation composed."""
    params = fit.params.copy()
    params.root_orient, params.transl, center = move_body(fit.params.root_orient, fit.params.transl,
                                                          fit.center, T)
    return replace(
        fit, params=params, rotation_center=center,
        vertices=transform_points(fit.vertices, T), keypoints3d=transform_points(fit.keypoints3d, T),
        joints=transform_points(fit.joints, T),
    )
