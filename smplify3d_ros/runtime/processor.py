"""One synchronized set of messages -> outputs: the step the node and the replay both run per frame.

    messages -> stamp checked -> Frame (`messages.to_frame`) -> FrameFitter (the core) -> output frame
    -> output messages (`outputs.OutputBuilder`)

`MessageProcessor.process` never raises for bad input: a frame it cannot use (malformed or empty cloud,
zero-size image, unusable camera info, keypoints it cannot read, a stamp going back, a missing
transform) is dropped, counted by reason in `stats.drops` and logged (rate-limited per reason). People
it cannot fit (too few usable keypoints, keypoints far outside the image, more than `max_people`) are
counted in `stats.people_dropped`. A frame without people is not a drop: its outputs are published
empty, so that markers of people who left are deleted.

No NaN or infinity is ever published: a fit with a non-finite parameter, vertex or keypoint (a diverged
optimization, an overflowing transform) is withheld from the frame's outputs, counted as
`people_dropped.non_finite` and logged; the frame's other people are published (the withheld person's
markers are deleted, as for a person who left). Withheld, not replaced by the person's last finite
state: a stale body shown as current is a worse lie than a missing one. `init_bodies` documents are
checked against the body model's joints and shape size (a wrong shape size is a `bad_document`).

Keypoint points the reader ignores in a frame it uses (joint index outside the format, NaN / inf u, v
or score, a joint given twice) are counted in `stats.keypoints_ignored` (`keypoints_ignored.<reason>`
values, messages.IGNORED_*).
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from msg_adapters import BodiesError, MessageFactory, bodies_json_to_params, clip, stamp_to_ns
from msg_adapters.factory import resolve_factory
from smplify3d_ros.config import Config
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.frame_fitter import FrameFits, FrameFitter
from smplify3d_ros.runtime.config import NodeConfig
from smplify3d_ros.runtime.messages import (
    DROP_BAD_STAMP,
    DROP_DUPLICATE,
    DROP_FIT_ERROR,
    DROP_INTERNAL,
    DROP_NO_TRANSFORM,
    DROP_TIME_BACKWARDS,
    FrameDrop,
    FrameMessages,
    to_frame,
)
from smplify3d_ros.runtime.outputs import HriSettings, OutputBuilder
from smplify3d_ros.runtime.stats import ProcessorStats
from smplify3d_ros.runtime.transforms import Transforms, TransformUnavailable, transform_fit
from smplify3d_ros.tracking.tracker import Tracker
from smplify3d_ros.types import BodyFit, BodyParams, Frame

_LOG_EVERY_S = 5.0  # each drop reason is logged at most this often (with the count in between)
PERSON_NON_FINITE = "non_finite"  # people_dropped key: a fit holding NaN / inf, withheld


def _short_traceback(e: BaseException, frames: int) -> str:
    """The exception and its last `frames` frames, without the "Traceback" header (one log entry)."""
    lines = traceback.format_list(traceback.extract_tb(e.__traceback__)[-frames:])
    return "".join(lines + traceback.format_exception_only(type(e), e))


def _finite(fit: BodyFit) -> bool:
    p = fit.params
    return all(np.isfinite(np.asarray(a, dtype=np.float64)).all()
               for a in (p.shape, p.pose, p.root_orient, p.transl, fit.vertices, fit.keypoints3d, fit.joints))


@dataclass
class FrameResult:
    stamp: Any  # stamp message of the frame (outputs carry it exactly)
    stamp_ns: int
    frame_id: str  # frame of the outputs
    fits: list[BodyFit] = field(default_factory=list)  # in `frame_id`
    outputs: dict[str, Any] = field(default_factory=dict)  # output name (outputs.OUTPUTS) -> message
    latency: dict[str, float] = field(default_factory=dict)  # stage -> seconds
    frame: Frame | None = None  # the frame as fitted (only with `keep_frames`)
    drop: str | None = None  # DROP_* reason when the frame was dropped
    message: str = ""

    @property
    def ok(self) -> bool:
        return self.drop is None


class MessageProcessor:
    """The core frame path (`FrameFitter`) with the drivers' input and output sides and their counters."""

    def __init__(
        self,
        config: Config,
        node: NodeConfig,
        factory: MessageFactory | None = None,
        *,
        fitter: Fitter | None = None,
        transforms: Transforms | None = None,
        log: Any = None,
        keep_frames: bool = False,
        build_outputs: bool = True,
    ) -> None:
        self.config = config
        self.node = node
        self.factory = resolve_factory(factory)
        self.log = log or logging.getLogger(__name__)
        self.tracker = Tracker(config.tracking) if config.tracking.enabled else None
        self.frames = FrameFitter(config, fitter, self.tracker)
        self.fitter = self.frames.fitter
        self.transforms = transforms or Transforms(node.extrinsic, log=self.log)
        self.outputs = OutputBuilder(node.publish, self.fitter.faces_np, self.factory,
                                     HriSettings(node.topics.hri_bodies))
        self.keep_frames = keep_frames
        self.build_outputs = build_outputs  # False: fits only (a replay without an output bag)
        # the outputs not to build this frame (the node's lazy publishing: nobody subscribes to them)
        self.skip_outputs: Callable[[], Collection[str]] = tuple
        self.stats = ProcessorStats(latency_window=node.diagnostics.latency_window)
        self.stats.tracking = None if self.tracker is None else self.tracker.stats
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
        shape_names = getattr(self.fitter.model, "shape_names", None)
        try:
            stamp, frame_id, bodies = bodies_json_to_params(
                text, self.fitter.model.joint_names, shape_size=None if shape_names is None else len(shape_names))
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
            self._log_limited("init_frame", f"init_bodies: document in frame {clip(frame_id)!r}, the camera "
                              f"is {clip(camera_frame)!r}; ignored")
            return {}
        model = self.fitter.model.name
        usable = {pid: p for pid, p in bodies.items() if p.model == model}
        if len(usable) < len(bodies):
            self.stats.init_bodies_dropped["wrong_model"] += len(bodies) - len(usable)
        return usable

    # -- the frame -----------------------------------------------------------------------------------
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
        if self.tracker is not None:
            self.tracker.reset()

    def process(self, msgs: FrameMessages) -> FrameResult:
        """Fit one frame. Never raises for bad input: see the module docstring."""
        t_start = time.perf_counter()
        self.stats.frames_in += 1
        try:
            stamp, stamp_ns = msgs.stamp, msgs.stamp_ns
        except Exception as e:  # noqa: BLE001 - a message without a usable header
            self.stats.drops[DROP_BAD_STAMP] += 1
            self._log_limited(DROP_BAD_STAMP, f"dropped a frame without a usable stamp: {e}")
            return FrameResult(None, 0, self.node.output_frame, drop=DROP_BAD_STAMP, message=str(e))
        result = FrameResult(stamp, stamp_ns, self.node.output_frame)
        try:
            self._process(msgs, result)
        except Exception as e:  # noqa: BLE001 - bad input or a bug: count, log, keep going
            drop = e if isinstance(e, FrameDrop) else FrameDrop(DROP_INTERNAL, _short_traceback(e, 3))
            self.stats.drops[drop.reason] += 1
            result.drop, result.message, result.outputs, result.fits = drop.reason, drop.message, {}, []
            level = "error" if drop.reason in (DROP_FIT_ERROR, DROP_INTERNAL) else "warning"
            detail = drop.message if drop.reason in (DROP_FIT_ERROR, DROP_INTERNAL) else clip(drop.message, 300)
            self._log_limited(drop.reason, f"dropped frame {stamp_ns * 1e-9:.3f}: {drop.reason}: {detail}", level)
            return result
        self._last_stamp_ns = stamp_ns
        result.latency["total"] = time.perf_counter() - t_start
        self._count(result)
        return result

    def _process(self, msgs: FrameMessages, result: FrameResult) -> None:
        self.check_stamp(result.stamp_ns)
        t = time.perf_counter()
        try:  # every transform at the image's stamp; TF knowing the frames but not then drops the frame
            frame, T_out = self._frame_and_output_transform(msgs, result.stamp_ns)
        except TransformUnavailable as e:
            raise FrameDrop(e.reason, e.message) from None
        result.latency["convert"] = time.perf_counter() - t
        if T_out is None:
            raise FrameDrop(DROP_NO_TRANSFORM, f"no transform from {frame.frame_id!r} to output_frame "
                            f"{self.node.output_frame!r}")
        result.frame_id = self.node.output_frame or frame.frame_id
        frame = replace(frame, init_bodies=self._init_bodies_for(result.stamp_ns, frame.frame_id))
        fitted = self._fit(frame)
        result.latency.update(fitted.latency)
        result.frame = fitted.frame if self.keep_frames else None
        fits = fitted.fits
        if not np.allclose(T_out, np.eye(4)):
            fits = [transform_fit(fit, T_out) for fit in fits]
        fits = self._withhold_non_finite(fits)
        if self.build_outputs:
            t = time.perf_counter()
            result.outputs = self.outputs.build(fits, result.stamp, result.frame_id, frame, self.skip_outputs())
            result.latency["outputs"] = time.perf_counter() - t
        result.fits = fits

    def _withhold_non_finite(self, fits: list[BodyFit]) -> list[BodyFit]:
        """The fits without NaN / inf (module docstring); the others are counted and logged."""
        finite = [fit for fit in fits if _finite(fit)]
        if len(finite) < len(fits):
            withheld = sorted({fit.person_id for fit in fits} - {fit.person_id for fit in finite})
            self.stats.people_dropped[PERSON_NON_FINITE] += len(fits) - len(finite)
            self._log_limited(PERSON_NON_FINITE, f"withheld the fit of person(s) {withheld}: NaN or infinite "
                              "values (diverged)")
        return finite

    def _frame_and_output_transform(self, msgs: FrameMessages, stamp_ns: int) -> tuple[Frame, np.ndarray | None]:
        frame = to_frame(msgs, self.node.keypoint_format, self.transforms, self.node.extrinsic.camera_frame,
                         self.stats.keypoints_ignored)
        lidar_frame = str(msgs.points.header.frame_id)
        if self.transforms.compensates_motion:  # the scan moved to the image's time through the fixed frame
            cloud_ns = stamp_to_ns(msgs.points.header.stamp)
            frame = replace(frame, T_cam_lidar=self.transforms.cam_from_lidar(frame.frame_id, lidar_frame, stamp_ns,
                                                                              cloud_ns))
        return frame, self.transforms.out_from_cam(self.node.output_frame, frame.frame_id, lidar_frame, stamp_ns)

    def _fit(self, frame: Frame) -> FrameFits:
        try:
            fitted = self.frames.fit(frame)
        except Exception as e:  # noqa: BLE001 - a bug in the method must not stop the node
            raise FrameDrop(DROP_FIT_ERROR, _short_traceback(e, 2)) from None
        for reason, n in fitted.people_dropped.items():
            self.stats.people_dropped[reason] += n
            self._log_limited(f"person.{reason}", f"{n} person(s) not fitted: {reason}", "info")
        self.stats.init_bodies_used += sum(p.init is not None for p in fitted.observations)
        return fitted

    def _count(self, result: FrameResult) -> None:
        stats = self.stats
        for stage, seconds in result.latency.items():
            stats.record(stage, seconds)
        stats.frames_published += 1
        stats.frames_empty += int(not result.fits)
        stats.people_fitted += len(result.fits)
        stats.people_per_frame.append(len(result.fits))
        for fit in result.fits:
            stats.flags.update(fit.flags)
