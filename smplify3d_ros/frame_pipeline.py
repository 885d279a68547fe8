"""One synchronized set of messages -> `Frame` -> fits -> output messages: the path the node and replay share.

    convert (msg_adapters) -> select people -> extract (LiDAR person points) -> fit -> outputs (msg_adapters)

`FramePipeline.process` never raises for bad input: a frame it cannot use (malformed or empty cloud,
zero-size image, unusable camera info, keypoints it cannot read, a stamp going back, a missing transform)
is dropped, counted by reason in `stats.drops` and logged (rate-limited per reason). People it cannot fit
(too few usable keypoints, keypoints far outside the image, more than `max_people`) are counted in
`stats.people_dropped`. A frame without people is not a drop: its outputs are published empty, so that
markers of people who left are deleted.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from msg_adapters import (
    BodiesError,
    CameraInfoError,
    ImageError,
    KeypointError,
    MessageFactory,
    PointCloudError,
    bodies_json_to_params,
    camera_info_to_model,
    compressed_to_numpy,
    diagnostics_array,
    fits_to_bodies_json,
    fits_to_body_points_cloud,
    fits_to_joints_cloud,
    fits_to_markers,
    fits_to_pose_array,
    image_to_numpy,
    read_keypoints,
    read_points,
    stamp_to_ns,
    to_rgb8,
)
from msg_adapters.factory import resolve_factory
from smplify3d_ros.camera import transform_points
from smplify3d_ros.config import Config
from smplify3d_ros.node_config import ExtrinsicConfig
from smplify3d_ros.types import BodyFit, BodyParams, Frame

# Frames that are not published, by reason (stats.drops keys).
DROP_BAD_IMAGE = "bad_image"  # undecodable, zero-size or truncated image
DROP_IMAGE_SIZE = "image_size_mismatch"  # image size differs from the camera info's
DROP_BAD_CAMERA_INFO = "bad_camera_info"  # uncalibrated or malformed camera info
DROP_BAD_POINTS = "bad_points"  # malformed LiDAR cloud (truncated data, missing x/y/z, ...)
DROP_EMPTY_CLOUD = "empty_cloud"  # LiDAR cloud without points
DROP_NO_FINITE_POINTS = "no_finite_points"  # LiDAR cloud whose points are all NaN / inf
DROP_BAD_KEYPOINTS = "bad_keypoints"  # keypoint cloud that cannot be read
DROP_TIME_BACKWARDS = "time_backwards"  # stamp older than the last frame's (within time_reset_s)
DROP_DUPLICATE = "duplicate_stamp"  # same stamp as the last frame
DROP_NO_TRANSFORM = "no_transform"  # no transform to the output frame
DROP_FIT_ERROR = "fit_error"  # the fitting raised (a bug): logged with its traceback
DROP_INTERNAL = "internal_error"  # anything else raised while handling the frame (a bug): logged
DROP_QUEUE = "stale"  # (node) replaced in the worker queue by a newer frame before it was fitted

# People that are not fitted, by reason (stats.people_dropped keys).
PERSON_FEW_KEYPOINTS = "few_keypoints"
PERSON_OUT_OF_IMAGE = "out_of_image"
PERSON_MAX_PEOPLE = "max_people"

STAGES = ("convert", "extract", "fit", "outputs", "total")
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
_LOG_EVERY_S = 5.0  # each drop reason is logged at most this often (with the count in between)


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

    @property
    def stamp(self) -> Any:
        """The frame's stamp message: the image's, else the keypoints' (equal by the encoding's contract)."""
        return (self.image if self.image is not None else self.keypoints).header.stamp


@dataclass
class FrameResult:
    stamp: Any  # stamp message of the frame (outputs carry it exactly)
    stamp_ns: int
    frame_id: str  # frame of the outputs
    fits: list[BodyFit] = field(default_factory=list)
    outputs: dict[str, Any] = field(default_factory=dict)  # output name (OUTPUTS) -> message
    latency: dict[str, float] = field(default_factory=dict)  # stage -> seconds
    frame: Frame | None = None
    drop: str | None = None  # DROP_* reason when the frame was dropped
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.drop is None


class LatencyStats:
    """Per-stage latency: the last `window` values (mean, max) and totals since start."""

    def __init__(self, window: int = 100) -> None:
        self.recent: deque[float] = deque(maxlen=window)
        self.count = 0
        self.total = 0.0

    def add(self, seconds: float) -> None:
        self.recent.append(seconds)
        self.count += 1
        self.total += seconds

    @property
    def mean(self) -> float:
        return float(np.mean(self.recent)) if self.recent else float("nan")

    @property
    def max(self) -> float:
        return float(np.max(self.recent)) if self.recent else float("nan")

    @property
    def overall_mean(self) -> float:
        return self.total / self.count if self.count else float("nan")


@dataclass
class PipelineStats:
    frames_in: int = 0  # frames offered to `process`
    frames_published: int = 0  # frames whose outputs were produced (including frames without people)
    frames_empty: int = 0  # ... of which had nobody to fit
    people_fitted: int = 0
    time_resets: int = 0  # clock resets (stamp jumped back by more than sync.time_reset_s)
    init_bodies_used: int = 0  # people seeded from an init_bodies document
    drops: Counter = field(default_factory=Counter)  # frames not published, by DROP_* reason
    people_dropped: Counter = field(default_factory=Counter)  # people not fitted, by PERSON_* reason
    init_bodies_dropped: Counter = field(default_factory=Counter)  # init_bodies documents ignored, by reason
    flags: Counter = field(default_factory=Counter)  # fit flags (image_only, diverged, ...)
    latency: dict[str, LatencyStats] = field(default_factory=lambda: {s: LatencyStats() for s in STAGES})
    people_per_frame: deque = field(default_factory=lambda: deque(maxlen=100))

    def record(self, stage: str, seconds: float) -> None:
        if stage not in self.latency:
            self.latency[stage] = LatencyStats()
        self.latency[stage].add(seconds)


# -- transforms -------------------------------------------------------------------------------------------
TransformLookup = Callable[[str, str, Any], "np.ndarray | None"]


class Transforms:
    """Where the pipeline's transforms come from: `lookup(target, source, stamp) -> (4, 4) | None` (TF, a
    bag's /tf_static) first, else the static extrinsic parameters."""

    def __init__(self, extrinsic: ExtrinsicConfig, lookup: TransformLookup | None = None,
                 log: Any = None) -> None:
        self.extrinsic = extrinsic
        self.lookup = lookup
        self.log = log or logging.getLogger(__name__)
        self._static = extrinsic.T_cam_lidar()
        self._warned: set[tuple[str, str]] = set()

    def _warn_once(self, key: tuple[str, str], text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            self.log.warning(text)

    def cam_from_lidar(self, camera_frame: str, lidar_frame: str, stamp: Any) -> np.ndarray:
        """(4, 4) taking the cloud's points into the camera frame."""
        if camera_frame and camera_frame == lidar_frame:
            return np.eye(4)
        if self.lookup is not None and camera_frame and lidar_frame:
            T = self.lookup(camera_frame, lidar_frame, stamp)
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

    def out_from_cam(self, output_frame: str, camera_frame: str, lidar_frame: str, stamp: Any) -> np.ndarray:
        """(4, 4) taking camera-frame geometry into `output_frame`; FrameDrop when unknown."""
        if not output_frame or output_frame == camera_frame:
            return np.eye(4)
        if self.lookup is not None:
            T = self.lookup(output_frame, camera_frame, stamp)
            if T is not None:
                return T
        if output_frame in (lidar_frame, self.extrinsic.lidar_frame):
            return np.linalg.inv(self.cam_from_lidar(camera_frame, lidar_frame, stamp))
        raise FrameDrop(DROP_NO_TRANSFORM, f"no transform from {camera_frame!r} to output_frame {output_frame!r}")


def transform_fit(fit: BodyFit, T: np.ndarray, rotation_center: Callable[[BodyParams], np.ndarray]) -> BodyFit:
    """The same body expressed in another frame: points moved, root rotation and translation composed."""
    from scipy.spatial.transform import Rotation

    R, t = T[:3, :3], T[:3, 3]
    params = fit.params.copy()
    center = rotation_center(fit.params)
    params.root_orient = (Rotation.from_matrix(R) * Rotation.from_rotvec(fit.params.root_orient)).as_rotvec()
    params.transl = fit.params.transl + (R @ center + t - center)
    return replace(
        fit, params=params,
        vertices=transform_points(fit.vertices, T), keypoints3d=transform_points(fit.keypoints3d, T),
        joints=transform_points(fit.joints, T),
    )


# -- the pipeline -----------------------------------------------------------------------------------------
class FramePipeline:
    """Holds the fitter, the output state (marker ids, last stamp) and the counters."""

    def __init__(
        self,
        config: Config,
        factory: MessageFactory | None = None,
        *,
        fitter: Any = None,
        transforms: Transforms | None = None,
        log: Any = None,
        keep_frames: bool = False,
    ) -> None:
        from smplify3d_ros.fitting.pipeline import Fitter

        self.config = config
        self.node = config.node
        self.factory = resolve_factory(factory)
        self.log = log or logging.getLogger(__name__)
        self.fitter = fitter if fitter is not None else Fitter(config.fitting)
        self.transforms = transforms or Transforms(self.node.extrinsic, log=self.log)
        self.keep_frames = keep_frames
        self.stats = PipelineStats()
        self._marker_ids: set[int] = set()
        self._last_stamp_ns: int | None = None
        self._init_docs: deque[tuple[int, str, dict[int, BodyParams]]] = deque(maxlen=50)
        self._lock = threading.Lock()
        self._log_times: dict[str, tuple[float, int]] = {}

    # -- logging -------------------------------------------------------------------------------------
    def _log_limited(self, key: str, text: str, level: str = "warning") -> None:
        """Log `text` unless `key` was logged less than _LOG_EVERY_S ago (then count it for the next one)."""
        now = time.monotonic()
        last, skipped = self._log_times.get(key, (-1e9, 0))
        if now - last < _LOG_EVERY_S:
            self._log_times[key] = (last, skipped + 1)
            return
        self._log_times[key] = (now, 0)
        text += f" ({skipped} more since the last report)" if skipped else ""
        # one call site per severity: rclpy's logger refuses two severities from one call site
        if level == "info":
            self.log.info(text)
        elif level == "error":
            self.log.error(text)
        else:
            self.log.warning(text)

    # -- init bodies ---------------------------------------------------------------------------------
    def add_init_bodies(self, msg: Any) -> bool:
        """Keep one `init_bodies` document (std_msgs/String or str) for the frame with its stamp."""
        text = msg if isinstance(msg, (str, bytes)) else msg.data
        try:
            stamp, frame_id, bodies = bodies_json_to_params(text, self.fitter.model.joint_names)
        except BodiesError as e:
            self.stats.init_bodies_dropped["bad_document"] += 1
            self._log_limited("init_bodies", f"init_bodies: ignored a document: {e}")
            return False
        with self._lock:
            self._init_docs.append((stamp_to_ns(stamp), frame_id, bodies))
        return True

    def _init_bodies_for(self, stamp_ns: int, camera_frame: str) -> dict[int, BodyParams]:
        slop = round(self.node.sync.slop_s * 1e9)
        with self._lock:
            docs = [d for d in self._init_docs if abs(d[0] - stamp_ns) <= slop]
        if not docs:
            return {}
        _, frame_id, bodies = min(docs, key=lambda d: abs(d[0] - stamp_ns))
        if frame_id and frame_id != camera_frame:
            self.stats.init_bodies_dropped["wrong_frame"] += 1
            self._log_limited("init_frame", f"init_bodies: document in frame {frame_id!r}, the camera is "
                              f"{camera_frame!r}; ignored")
            return {}
        model = self.fitter.model.name
        usable = {pid: p for pid, p in bodies.items() if p.model == model}
        if len(usable) < len(bodies):
            self.stats.init_bodies_dropped["wrong_model"] += len(bodies) - len(usable)
        return usable

    # -- stages --------------------------------------------------------------------------------------
    def to_frame(self, msgs: FrameMessages) -> Frame:
        """Messages -> Frame (all people, as detected). Raises FrameDrop."""
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
        frame_id = frame_id or self.node.extrinsic.camera_frame
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
            kps = read_keypoints(msgs.keypoints, self.node.keypoint_format)
        except (KeypointError, PointCloudError, ValueError, TypeError) as e:
            raise FrameDrop(DROP_BAD_KEYPOINTS, str(e)) from None
        T = self.transforms.cam_from_lidar(frame_id, cloud.frame_id, msgs.stamp)
        return Frame(
            stamp=stamp_to_ns(msgs.stamp) * 1e-9, camera=camera, keypoints=kps.keypoints,
            person_ids=kps.person_ids, points_lidar=cloud.xyz, T_cam_lidar=T, image=image, frame_id=frame_id,
        )

    def select_people(self, frame: Frame) -> Frame:
        """Usable people only: far out-of-image keypoints become missing, people with too few keypoints
        and beyond `max_people` (smallest boxes) are dropped and counted, anonymous people get ids."""
        kp = frame.keypoints.copy()
        if len(kp) == 0:
            return frame
        cam, node = frame.camera, self.node
        conf = self.config.fitting.init.keypoint_conf
        mx, my = node.keypoint_margin * cam.width, node.keypoint_margin * cam.height
        u, v = kp[..., 0], kp[..., 1]
        outside = (u < -mx) | (u > cam.width - 1 + mx) | (v < -my) | (v > cam.height - 1 + my)
        good_before = (kp[..., 2] >= conf).sum(axis=1)
        kp[outside] = 0.0
        good = kp[..., 2] >= conf
        keep = good.sum(axis=1) >= node.min_person_keypoints
        for i in np.flatnonzero(~keep):
            reason = PERSON_OUT_OF_IMAGE if good_before[i] >= node.min_person_keypoints else PERSON_FEW_KEYPOINTS
            self.stats.people_dropped[reason] += 1
            self._log_limited(f"person.{reason}", f"person {frame.person_ids[i]} not fitted: {reason} (fewer than "
                              f"{node.min_person_keypoints} usable keypoints)", "info")
        index = np.flatnonzero(keep)
        if len(index) > node.max_people:
            area = np.array([_box_area(kp[i][good[i], :2]) for i in index])
            order = index[np.argsort(-area, kind="stable")]
            self.stats.people_dropped[PERSON_MAX_PEOPLE] += len(index) - node.max_people
            index = np.sort(order[: node.max_people])
        kp, ids = kp[index], frame.person_ids[index].astype(np.int64)
        anonymous = np.flatnonzero(ids < 0)
        if len(anonymous):  # free ids, left to right, so that colours stay put while people do
            taken = set(ids[ids >= 0].tolist())
            free = (i for i in range(len(ids) + len(taken) + 1) if i not in taken)
            centre_u = [np.mean(kp[i][good[index[i]], 0]) for i in anonymous]
            for i in anonymous[np.argsort(centre_u, kind="stable")]:
                ids[i] = next(free)
        return replace(frame, keypoints=kp, person_ids=ids)

    def outputs(self, fits: list[BodyFit], stamp: Any, frame_id: str) -> dict[str, Any]:
        pub, f = self.node.publish, self.factory
        out: dict[str, Any] = {}
        if pub.markers:
            out["markers"], self._marker_ids = fits_to_markers(
                fits, self.fitter.faces_np, stamp, frame_id, self._marker_ids, f,
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

    def _rotation_center(self, params: BodyParams) -> np.ndarray:
        import torch

        model, dt = self.fitter.model, self.fitter.dtype
        with torch.no_grad():
            shape = torch.as_tensor(params.shape, dtype=dt, device=self.fitter.device)[None]
            transl = torch.as_tensor(params.transl, dtype=dt, device=self.fitter.device)[None]
            return model.rotation_center(shape, transl)[0].cpu().double().numpy()

    # -- the whole frame -----------------------------------------------------------------------------
    def check_stamp(self, stamp_ns: int) -> None:
        """FrameDrop for a stamp at or before the last frame's; a big jump back resets the state."""
        last = self._last_stamp_ns
        if last is None or stamp_ns > last:
            return
        if stamp_ns == last:
            raise FrameDrop(DROP_DUPLICATE, f"stamp {stamp_ns * 1e-9:.9f} s repeats the last frame's")
        back = (last - stamp_ns) * 1e-9
        if back <= self.node.sync.time_reset_s:
            raise FrameDrop(DROP_TIME_BACKWARDS, f"stamp went back by {back:.3f} s")
        self.log.warning(f"time jumped back by {back:.3f} s: clock reset (bag loop?); state cleared")
        self._last_stamp_ns = None
        self.stats.time_resets += 1

    def process(self, msgs: FrameMessages) -> FrameResult:
        """Fit one frame. Never raises for bad input: see the module docstring."""
        t_start = time.perf_counter()
        stats = self.stats
        stats.frames_in += 1
        try:
            stamp = msgs.stamp
            stamp_ns = stamp_to_ns(stamp)
        except Exception as e:  # noqa: BLE001 - a message without a usable header
            stats.drops[DROP_INTERNAL] += 1
            self._log_limited(DROP_INTERNAL, f"dropped a frame without a usable stamp: {e}", "error")
            return FrameResult(None, 0, self.node.output_frame, drop=DROP_INTERNAL, message=str(e))
        result = FrameResult(stamp, stamp_ns, self.node.output_frame)
        try:
            self.check_stamp(stamp_ns)
            t = time.perf_counter()
            frame = self.select_people(self.to_frame(msgs))
            result.latency["convert"] = time.perf_counter() - t
            result.frame = frame if self.keep_frames else None
            camera_frame = frame.frame_id
            lidar_frame = str(msgs.points.header.frame_id)
            T_out = self.transforms.out_from_cam(self.node.output_frame, camera_frame, lidar_frame, stamp)
            result.frame_id = self.node.output_frame or camera_frame
            fits = self._fit(frame, stamp_ns, result.latency) if len(frame.keypoints) else []
            if not np.allclose(T_out, np.eye(4)):
                fits = [transform_fit(fit, T_out, self._rotation_center) for fit in fits]
            t = time.perf_counter()
            result.outputs = self.outputs(fits, stamp, result.frame_id)
            result.latency["outputs"] = time.perf_counter() - t
        except Exception as e:  # noqa: BLE001 - bad input or a bug: count, log, keep going
            drop = e if isinstance(e, FrameDrop) else FrameDrop(DROP_INTERNAL, "".join(
                traceback.format_exception(type(e), e, e.__traceback__)[-4:]))
            stats.drops[drop.reason] += 1
            result.drop, result.message, result.outputs = drop.reason, drop.message, {}
            level = "error" if drop.reason in (DROP_FIT_ERROR, DROP_INTERNAL) else "warning"
            self._log_limited(drop.reason, f"dropped frame {stamp_ns * 1e-9:.3f}: {drop.reason}: {drop.message}",
                              level)
            return result
        self._last_stamp_ns = stamp_ns
        result.fits = fits
        result.latency["total"] = time.perf_counter() - t_start
        for stage, seconds in result.latency.items():
            stats.record(stage, seconds)
        stats.frames_published += 1
        stats.frames_empty += int(not fits)
        stats.people_fitted += len(fits)
        stats.people_per_frame.append(len(fits))
        for fit in fits:
            stats.flags.update(fit.flags)
        return result

    def _fit(self, frame: Frame, stamp_ns: int, latency: dict[str, float]) -> list[BodyFit]:
        from smplify3d_ros.fitting.pipeline import observations_from_frame

        frame = replace(frame, init_bodies=self._init_bodies_for(stamp_ns, frame.frame_id))
        try:
            t = time.perf_counter()
            people, origin = observations_from_frame(frame, self.config)
            latency["extract"] = time.perf_counter() - t
            self.stats.init_bodies_used += sum(p.init is not None for p in people)
            t = time.perf_counter()
            fits = self.fitter.fit(people, frame.camera.K, origin)
            latency["fit"] = time.perf_counter() - t
        except Exception as e:  # noqa: BLE001 - a bug in the method must not stop the node
            detail = "".join(traceback.format_exception(type(e), e, e.__traceback__)[-3:])
            raise FrameDrop(DROP_FIT_ERROR, f"{type(e).__name__}: {e}\n{detail}") from None
        return fits

    # -- diagnostics ---------------------------------------------------------------------------------
    def diagnostic_values(self) -> dict[str, float | int | str]:
        s = self.stats
        values: dict[str, float | int | str] = {
            "frames_in": s.frames_in,
            "frames_published": s.frames_published,
            "frames_without_people": s.frames_empty,
            "people_fitted": s.people_fitted,
            "people_per_frame_mean": float(np.mean(s.people_per_frame)) if s.people_per_frame else 0.0,
            "people_per_frame_last": s.people_per_frame[-1] if s.people_per_frame else 0,
            "frames_dropped": sum(s.drops.values()),
            "time_resets": s.time_resets,
        }
        for reason, n in sorted(s.drops.items()):
            values[f"drop.{reason}"] = n
        for reason, n in sorted(s.people_dropped.items()):
            values[f"people_dropped.{reason}"] = n
        for flag, n in sorted(s.flags.items()):
            values[f"fits_flagged.{flag}"] = n
        values["init_bodies_used"] = s.init_bodies_used
        for reason, n in sorted(s.init_bodies_dropped.items()):
            values[f"init_bodies_dropped.{reason}"] = n
        for stage, lat in s.latency.items():
            if lat.recent:
                values[f"latency_ms.{stage}.mean"] = 1e3 * lat.mean
                values[f"latency_ms.{stage}.max"] = 1e3 * lat.max
        return values


def _box_area(uv: np.ndarray) -> float:
    if len(uv) == 0:
        return 0.0
    span = uv.max(axis=0) - uv.min(axis=0)
    return float(span[0] * span[1])


class DiagnosticsReporter:
    """Builds `/diagnostics` messages: level OK, WARN when frames were dropped or fits flagged `diverged`
    since the last report, ERROR when handling a frame raised (a bug) since the last report."""

    def __init__(self, name: str = "smplify3d: fitting", hardware_id: str = "smplify3d_ros") -> None:
        self.name = name
        self.hardware_id = hardware_id
        self._last: dict[str, float] = {}

    def message(self, stamp: Any, values: dict[str, Any], factory: MessageFactory | None = None) -> Any:
        totals = {
            key: sum(v for k, v in values.items() if k.startswith(prefix) and isinstance(v, (int, float)))
            for key, prefix in (("errors", f"drop.{DROP_FIT_ERROR}"), ("internal", f"drop.{DROP_INTERNAL}"),
                                ("drops", "drop."), ("diverged", "fits_flagged.diverged"))
        }
        new = {key: total - self._last.get(key, 0) for key, total in totals.items()}
        self._last = totals
        if new["errors"] + new["internal"] > 0:
            level, text = "ERROR", f"{int(new['errors'] + new['internal'])} frame(s) failed with an error"
        elif new["drops"] > 0 or new["diverged"] > 0:
            level, text = "WARN", f"{int(new['drops'])} frame(s) dropped, {int(new['diverged'])} fit(s) diverged"
        else:
            level, text = "OK", "fitting"
        return diagnostics_array(stamp, self.name, level, text, values, factory, self.hardware_id)
