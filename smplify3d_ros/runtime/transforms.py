"""Where the drivers' transforms come from (TF, a bag's /tf and /tf_static, the extrinsic parameters), and
fits moved into the output frame.

Every lookup is made at the image's stamp (tf2 semantics): `lookup(target, source, stamp_ns)` gives the
(4, 4) transform taking `source` points into `target` at that time; with `source_stamp_ns` and
`fixed_frame` it is tf2's "advanced" lookup (source at its own time, through a world-fixed frame), which
moves a LiDAR scan to the image's time when TF has odometry (`extrinsic.motion_compensation`). A lookup
returns None when the frames are not known at all (the extrinsic parameters can stand in) and raises
`TransformUnavailable` when they are known but not at that time: the frame is dropped and counted.
"""

from __future__ import annotations

import bisect
import logging
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from msg_adapters.bodies import clip
from smplify3d_ros.camera import transform_points
from smplify3d_ros.geometry import invert, matrix_to_quaternion, move_body, transform_from_quaternion
from smplify3d_ros.runtime.config import ExtrinsicConfig
from smplify3d_ros.types import BodyFit

# lookup(target, source, stamp_ns, source_stamp_ns=None, fixed_frame=None) -> (4, 4) or None
TransformLookup = Callable[..., "np.ndarray | None"]

DROP_TF_TIMEOUT = "tf_timeout"  # TF knows the frames but had no transform at the stamp (within the timeout)
TF_TOPIC, TF_STATIC_TOPIC = "/tf", "/tf_static"


class TransformUnavailable(Exception):
    """TF knows the frames but not at the requested time; `reason` is the drop counted for the frame."""

    def __init__(self, message: str, reason: str = DROP_TF_TIMEOUT) -> None:
        super().__init__(message)
        self.reason = reason
        self.message = message


def transform_msg_matrix(t: Any) -> np.ndarray:
    """geometry_msgs/TransformStamped (either runtime) -> (4, 4) taking child-frame points into the parent."""
    q, p = t.transform.rotation, t.transform.translation
    return transform_from_quaternion((p.x, p.y, p.z), (q.x, q.y, q.z, q.w))


def _stamp_ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


class _Series:
    """One dynamic TF edge over time (parent -> child), interpolated like tf2: translation linearly,
    rotation by slerp; no extrapolation beyond the first and last samples."""

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.matrices: list[np.ndarray] = []

    def add(self, stamp_ns: int, T: np.ndarray) -> None:
        i = bisect.bisect_left(self.stamps, stamp_ns)
        if i < len(self.stamps) and self.stamps[i] == stamp_ns:
            self.matrices[i] = T
            return
        self.stamps.insert(i, stamp_ns)
        self.matrices.insert(i, T)

    def at(self, stamp_ns: int | None) -> np.ndarray | None:
        """Child -> parent at `stamp_ns` (None: the latest), or None outside the recorded span."""
        if stamp_ns is None:
            return self.matrices[-1]
        i = bisect.bisect_left(self.stamps, stamp_ns)
        if i < len(self.stamps) and self.stamps[i] == stamp_ns:
            return self.matrices[i]
        if i == 0 or i == len(self.stamps):
            return None
        (t0, t1), (A, B) = self.stamps[i - 1:i + 1], self.matrices[i - 1:i + 1]
        w = (stamp_ns - t0) / (t1 - t0)
        rotation = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([A[:3, :3], B[:3, :3]])))([w]).as_matrix()[0]
        out = np.eye(4)
        out[:3, :3], out[:3, 3] = rotation, (1.0 - w) * A[:3, 3] + w * B[:3, 3]
        return out

    def span(self) -> str:
        return f"[{self.stamps[0] * 1e-9:.3f}, {self.stamps[-1] * 1e-9:.3f}] s"


class TransformGraph:
    """The TF tree of a recording: static edges (/tf_static) and time-indexed dynamic ones (/tf).

    `lookup(target, source, stamp_ns)` composes the edges on the path between the frames, each at the
    stamp (see the module docstring for the advanced form and for None vs TransformUnavailable)."""

    def __init__(self) -> None:
        self._static: dict[tuple[str, str], np.ndarray] = {}  # (parent, child) -> child points -> parent
        self._dynamic: dict[tuple[str, str], _Series] = {}
        self._neighbours: dict[str, set[str]] = {}

    def __len__(self) -> int:
        return len(self._static) + len(self._dynamic)

    def add(self, msg: Any, static: bool = True) -> None:
        """Every transform of a tf2_msgs/TFMessage (from /tf_static, or /tf with `static` false)."""
        for t in msg.transforms:
            parent, child = str(t.header.frame_id).lstrip("/"), str(t.child_frame_id).lstrip("/")
            if not parent or not child or parent == child:
                continue
            T = transform_msg_matrix(t)
            if static:
                self._static[(parent, child)] = T
            else:
                self._dynamic.setdefault((parent, child), _Series()).add(_stamp_ns(t.header.stamp), T)
            self._neighbours.setdefault(parent, set()).add(child)
            self._neighbours.setdefault(child, set()).add(parent)

    def _path(self, target: str, source: str) -> list[str] | None:
        """Frames from `source` to `target` (breadth-first), None when they are not connected."""
        previous: dict[str, str | None] = {source: None}
        todo = deque([source])
        while todo:
            frame = todo.popleft()
            if frame == target:
                path = [frame]
                while previous[path[-1]] is not None:
                    path.append(previous[path[-1]])
                return path[::-1]
            for other in sorted(self._neighbours.get(frame, ())):
                if other not in previous:
                    previous[other] = frame
                    todo.append(other)
        return None

    def _edge(self, a: str, b: str, stamp_ns: int | None) -> np.ndarray:
        """(4, 4) taking frame-`a` points into frame `b` at the stamp (raises TransformUnavailable)."""
        for (parent, child), sign in (((b, a), 1), ((a, b), -1)):
            T = self._static.get((parent, child))
            if T is None and (parent, child) in self._dynamic:
                series = self._dynamic[(parent, child)]
                T = series.at(stamp_ns)
                if T is None:
                    raise TransformUnavailable(f"{parent} -> {child} has no transform at {stamp_ns * 1e-9:.3f} s "
                                               f"(recorded {series.span()})")
            if T is not None:
                return T if sign == 1 else invert(T)
        raise KeyError((a, b))  # not reached: the path only follows known edges

    def _at(self, target: str, source: str, stamp_ns: int | None) -> np.ndarray | None:
        if source == target:
            return np.eye(4)
        path = self._path(target, source)
        if path is None:
            return None
        T = np.eye(4)
        for a, b in zip(path, path[1:]):
            T = self._edge(a, b, stamp_ns) @ T
        return T

    def lookup(self, target: str, source: str, stamp_ns: int | None = None, source_stamp_ns: int | None = None,
               fixed_frame: str | None = None) -> np.ndarray | None:
        target, source = target.lstrip("/"), source.lstrip("/")
        if source not in self._neighbours or target not in self._neighbours:
            return None
        if not fixed_frame:
            return self._at(target, source, stamp_ns)
        fixed = fixed_frame.lstrip("/")
        to_fixed = self._at(fixed, source, source_stamp_ns if source_stamp_ns is not None else stamp_ns)
        from_fixed = self._at(target, fixed, stamp_ns)
        return None if to_fixed is None or from_fixed is None else from_fixed @ to_fixed


class Transforms:
    """Transforms of one driver: `lookup` (TF, a bag's /tf and /tf_static) first, else the extrinsic
    parameters; moving the scan to the image's time when `extrinsic.motion_compensation` is on."""

    def __init__(self, extrinsic: ExtrinsicConfig, lookup: TransformLookup | None = None, log: Any = None) -> None:
        self.extrinsic = extrinsic
        self.lookup = lookup
        self.log = log or logging.getLogger(__name__)
        self._static = extrinsic.T_cam_lidar()
        self._warned: set[tuple[str, str]] = set()

    @property
    def compensates_motion(self) -> bool:
        return self.extrinsic.motion_compensation and self.lookup is not None

    def _warn_once(self, key: tuple[str, str], text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.log.warning(text)

    def cam_from_lidar(self, camera_frame: str, lidar_frame: str, stamp_ns: int,
                       cloud_stamp_ns: int | None = None) -> np.ndarray:
        """(4, 4) taking the cloud's points into the camera frame at the image's stamp; with a
        `cloud_stamp_ns` and motion compensation on, the scan's points as they were at its own stamp,
        seen from where the camera is at the image's stamp (through `extrinsic.fixed_frame`)."""
        if camera_frame and camera_frame == lidar_frame:
            return np.eye(4)
        if self.lookup is not None and camera_frame and lidar_frame:
            if cloud_stamp_ns is not None and self.compensates_motion:
                fixed = self.extrinsic.fixed_frame
                T = self.lookup(camera_frame, lidar_frame, stamp_ns, cloud_stamp_ns, fixed)
                if T is not None:
                    return T
                self._warn_once(("fixed", fixed), f"extrinsic.motion_compensation: TF does not connect "
                                f"{clip(lidar_frame)!r} and {clip(camera_frame)!r} through {clip(fixed)!r}; "
                                "the scan is not moved to the image's time")
            T = self.lookup(camera_frame, lidar_frame, stamp_ns)
            if T is not None:
                return T
            self._warn_once((camera_frame, lidar_frame),
                            f"no transform {clip(lidar_frame)!r} -> {clip(camera_frame)!r} available; using the "
                            "extrinsic parameters (extrinsic.*)")
        ext = self.extrinsic
        if (lidar_frame and lidar_frame != ext.lidar_frame) or (camera_frame and camera_frame != ext.camera_frame):
            self._warn_once(("names", f"{lidar_frame}>{camera_frame}"),
                            f"the extrinsic parameters relate {ext.lidar_frame!r} -> {ext.camera_frame!r} but "
                            f"the messages are in {clip(lidar_frame)!r} -> {clip(camera_frame)!r}; applying them "
                            "anyway")
        return self._static

    def out_from_cam(self, output_frame: str, camera_frame: str, lidar_frame: str, stamp_ns: int) -> np.ndarray | None:
        """(4, 4) taking camera-frame geometry into `output_frame` at the stamp; None when no transform
        is known (raises TransformUnavailable when TF knows the frames but not at the stamp)."""
        if not output_frame or output_frame == camera_frame:
            return np.eye(4)
        if self.lookup is not None:
            T = self.lookup(output_frame, camera_frame, stamp_ns)
            if T is not None:
                return T
        if output_frame in (lidar_frame, self.extrinsic.lidar_frame):
            return invert(self.cam_from_lidar(camera_frame, lidar_frame, stamp_ns))
        return None


def extrinsic_tf_message(extrinsic: ExtrinsicConfig, stamp: Any, factory: Any) -> Any:
    """tf2_msgs/TFMessage stating the extrinsic parameters as TF does: `camera_frame` posed in `lidar_frame`."""
    T = extrinsic.T_lidar_cam()
    return tf_message([(extrinsic.lidar_frame, extrinsic.camera_frame, T)], stamp, factory)


def tf_message(transforms: list[tuple[str, str, np.ndarray]], stamp: Any, factory: Any) -> Any:
    """tf2_msgs/TFMessage of (parent, child, (4, 4) child points -> parent) transforms, all at `stamp`."""
    items = []
    for parent, child, T in transforms:
        q, t = matrix_to_quaternion(T[:3, :3]), T[:3, 3]
        items.append(factory.make(
            "geometry_msgs/msg/TransformStamped", header=factory.header(stamp, parent), child_frame_id=child,
            transform=factory.make(
                "geometry_msgs/msg/Transform",
                translation=factory.make("geometry_msgs/msg/Vector3", x=t[0], y=t[1], z=t[2]),
                rotation=factory.make("geometry_msgs/msg/Quaternion", x=q[0], y=q[1], z=q[2], w=q[3]))))
    return factory.make("tf2_msgs/msg/TFMessage", transforms=items)


def transform_fit(fit: BodyFit, T: np.ndarray) -> BodyFit:
    """The same body expressed in another frame: geometry moved, root rotation and translation composed."""
    params = fit.params.copy()
    params.root_orient, params.transl, center = move_body(fit.params.root_orient, fit.params.transl,
                                                          fit.center, T)
    velocity = None if fit.velocity is None else T[:3, :3] @ np.asarray(fit.velocity, dtype=np.float64)
    return replace(
        fit, params=params, rotation_center=center,
        vertices=transform_points(fit.vertices, T), keypoints3d=transform_points(fit.keypoints3d, T),
        joints=transform_points(fit.joints, T), velocity=velocity,
    )
