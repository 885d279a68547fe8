"""One frame, from what the sensors gave to fitted bodies: the path the library, the drivers and the
benchmarks all run.

    Frame -> people selected -> observations (undistorted keypoints, each person's LiDAR points)
          -> [tracks: ids, warm starts] -> fits -> [tracks: velocity, shape]

With a `Tracker` (the drivers keep one per stream), people keep their ids across frames and a tracked
person is fitted from their previous fit moved to the new stamp, with the short warm solve (the
`fitting.profiles.<tracking.warm_profile>` profile, shape held); new people and warm fits that lost
their person (reprojection or chamfer beyond `tracking.lost_*`) get the full cold start.

`FrameFitter.fit(frame)` is that path; `fit_frame(frame)` runs it with a cached fitter. The drivers
(`runtime.processor.MessageProcessor`) add what lies around it: messages in, stamps checked, outputs out.
"""

from __future__ import annotations

import json
import threading
import time
from collections import Counter, OrderedDict
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from smplify3d_ros.camera import transform_points, undistort_pixels
from smplify3d_ros.config import Config, load_config
from smplify3d_ros.fitting.config import FittingConfig, InitConfig
from smplify3d_ros.fitting.fitter import FitOptions, Fitter
from smplify3d_ros.fitting.init import nearest_depth
from smplify3d_ros.keypoints import KP
from smplify3d_ros.lidar.config import ExtractionConfig
from smplify3d_ros.lidar.extract import ExtractionResult, extract_people
from smplify3d_ros.lidar.ground import CAMERA_UP, GroundPlane
from smplify3d_ros.settings import to_dict
from smplify3d_ros.tracking.background import BackgroundError, BackgroundFitter
from smplify3d_ros.tracking.tracker import Track, Tracker, WarmStart
from smplify3d_ros.types import (
    FLAG_DIVERGED,
    FLAG_EXTERNAL_INIT,
    FLAG_IMAGE_ONLY,
    FLAG_LOST,
    FLAG_WARM_START,
    BodyFit,
    BodyParams,
    CameraModel,
    Frame,
    PersonObservation,
)

# People that are not fitted, by reason (`FrameFits.people_dropped` keys).
PERSON_FEW_KEYPOINTS = "few_keypoints"  # fewer than people.min_keypoints usable keypoints
PERSON_OUT_OF_IMAGE = "out_of_image"  # ... because keypoints lie far outside the image
PERSON_MAX_PEOPLE = "max_people"  # more people than people.max_people: the smallest boxes are left out


@dataclass
class FrameFits:
    """What one frame gave: the people fitted, their observations and fits, who was left out."""

    frame: Frame  # the frame as fitted: selected people only, each with an id
    observations: list[PersonObservation]
    fits: list[BodyFit]  # one per observation, same order
    lidar_origin: np.ndarray  # (3,) the LiDAR's position in the camera frame
    people_dropped: Counter = field(default_factory=Counter)  # PERSON_* -> people
    # "extract", "fit" -> seconds; tracked frames with warm fits also "warm_fit_per_person" (their batch's
    # warm solve divided by its people)
    latency: dict[str, float] = field(default_factory=dict)


@dataclass
class _PendingRefresh:
    """A refresh's cold fit running in the background (`tracking.refresh_background`), or a lost warm fit's
    (`tracking.lost_background`)."""

    job: int  # BackgroundFitter job
    index: int  # the person's place in that job's batch
    track: Track  # the track it was started for (a returning id's new track does not take it)
    frames: int  # the track's `frames` when it started (its frame not yet counted)
    warm: BodyFit  # the warm fit of that frame, which the cold fit must beat
    lost: bool = False  # a lost warm fit's cold refit (or a refresh whose person's warm fit was lost since)


def calibrated_scores(scores: np.ndarray, level: float, max_gain: float) -> np.ndarray:
    """Keypoint scores on the scale of a detector that scores plainly seen joints `level` or more (the
    simulated detector the package is tuned on scores them 0.9, as ViTPose-class detectors do). A frame
    whose detected scores' upper quartile is below `level` (a less confident detector, e.g. one that
    scores seen joints 0.7) has every score divided by that quartile over `level`, at most `max_gain`
    times, capped at 1; a confident detector's scores stay as they are. Every score threshold of the path
    (selection, extraction, initializer, the image term's visibility) then means what it was tuned to
    mean. Read from everyone in the frame, not per person: a mostly hidden person scores most joints low,
    and read alone would have their guessed joints taken for seen ones. `level` 0: scores as given."""
    scores = np.asarray(scores, np.float64)
    detected = scores[np.isfinite(scores) & (scores > 0)]
    if level <= 0 or len(detected) == 0:
        return scores
    gain = min(level / max(float(np.quantile(detected, 0.75)), 1e-6), max_gain)
    return np.minimum(scores * gain, 1.0) if gain > 1.0 else scores


def _box_area(uv: np.ndarray) -> float:
    if len(uv) == 0:
        return 0.0
    span = uv.max(axis=0) - uv.min(axis=0)
    return float(span[0] * span[1])


def _undistorted(keypoints: np.ndarray, camera: CameraModel) -> np.ndarray:
    out = np.asarray(keypoints, dtype=np.float64).copy().reshape(-1, 17, 3)
    if len(out) and camera.has_distortion:
        out[..., :2] = undistort_pixels(out[..., :2].reshape(-1, 2), camera).reshape(-1, 17, 2)
    return out


def undistorted_keypoints(frame: Frame) -> np.ndarray:
    """(P, 17, 3) the frame's keypoints as an ideal pinhole camera of the same K would see them."""
    return _undistorted(frame.keypoints, frame.camera)


def extract_frame_people(frame: Frame, config: ExtractionConfig, expected_depth: np.ndarray | None = None,
                         init: InitConfig | None = None) -> tuple[np.ndarray, ExtractionResult]:
    """The frame's undistorted keypoints and each person's points cut out of its scan (camera frame);
    `expected_depth`: optional (P, 2) depth and tolerance where each person should be (a track's);
    `init`: the fitter's initializer settings, whose `nearest_depth` (the person's size in the image)
    bounds how near each person's points may lie. The frame's `bystanders` take part in the extraction
    (their points are theirs) but are not returned."""
    undistorted = undistorted_keypoints(frame)
    points_cam = transform_points(frame.points_lidar, frame.T_cam_lidar).astype(np.float32)
    pinhole = CameraModel(frame.camera.K, frame.camera.width, frame.camera.height)
    bystanders = _undistorted(frame.bystanders if frame.bystanders is not None else np.zeros((0, 17, 3)),
                              frame.camera)
    everyone = np.concatenate([undistorted, bystanders])
    n = len(undistorted)
    if expected_depth is not None:  # bystanders: expected anywhere
        expected_depth = np.concatenate([np.asarray(expected_depth, np.float64).reshape(n, 2),
                                         np.full((len(bystanders), 2), np.nan)])
    nearest = None if init is None else partial(_nearest_depths, everyone, pinhole.K, init)
    up = CAMERA_UP
    if config.ground_up == "lidar":  # the LiDAR's z axis, turned up should the LiDAR hang upside down
        up = np.asarray(frame.T_cam_lidar, np.float64)[:3, 2]
        up = -up if up @ CAMERA_UP < 0 else up
    result = extract_people(points_cam, everyone, pinhole, config, expected_depth, nearest, up)
    labels = np.where(result.labels >= n, -1, result.labels).astype(np.int32)
    return undistorted, replace(result, people=result.people[:n], labels=labels)


def ground_vector(plane: GroundPlane) -> np.ndarray | None:
    """(4,) n, d of a fitted ground plane, as `PersonObservation.ground`; None for the fallback height band
    (the initializer stands people on the ground: an assumed height is not a plane)."""
    return np.array([*plane.normal, plane.offset], dtype=np.float64) if plane.fitted else None


def _nearest_depths(keypoints: np.ndarray, K: np.ndarray, init: InitConfig, plane: GroundPlane,
                    boxes: np.ndarray) -> np.ndarray:
    """(P,) `fitting.init.nearest_depth` of undistorted keypoint sets with the extraction's boxes (NaN
    rows: no skeleton), on the frame's ground plane when one was fitted (NaN: no bound)."""
    ground = ground_vector(plane)
    out = np.full(len(keypoints), np.nan)
    for k in np.flatnonzero(np.all(np.isfinite(boxes), axis=1)):
        obs = PersonObservation(person_id=-1, keypoints=keypoints[k], bbox=boxes[k], points=np.zeros((0, 3)),
                                ground=ground)
        out[k] = nearest_depth(obs, K, init)
    return out


class FrameFitter:
    """The core configuration and a `Fitter`; `fit(frame)` runs one frame's path (module docstring).
    `tracker` follows people across the frames given to `fit`, in order; `warm_fitter` makes the warm fits
    (default: a `Fitter` of the warm profile, sharing `fitter`'s body model); `background` fits the
    refreshes beside the frames (default: a `BackgroundFitter` of `fitter`'s configuration, started with
    the first refresh or `start_background`). `close` ends that process."""

    def __init__(self, config: Config, fitter: Fitter | None = None, tracker: Tracker | None = None,
                 warm_fitter: Fitter | None = None, background: BackgroundFitter | None = None) -> None:
        self.config = config
        self.fitter = fitter if fitter is not None else Fitter(config.fitting)
        self.tracker = tracker
        self.warm_fitter = warm_fitter
        if tracker is not None and warm_fitter is None:
            self.warm_fitter = warm_fitter_for(config, self.fitter)
        self._background = background  # the refreshes' helper process (started on demand when None)
        self._background_failed = False  # after a failure, refreshes are fitted inline
        self._pending: dict[int, _PendingRefresh] = {}  # person id -> refresh running in the background
        self._jobs: dict[int, list[BodyFit]] = {}  # background job -> its fits, while some are not taken

    # -- background refreshes ------------------------------------------------------------------------
    @property
    def refreshes_in_background(self) -> bool:
        """Whether refreshes run in the helper process (`tracking.refresh_background`, a real `Fitter`)."""
        return (self.tracker is not None and self.config.tracking.refresh_background and not self._background_failed
                and (self._background is not None or isinstance(self.fitter, Fitter)))

    def start_background(self, wait: bool = False) -> None:
        """Start the refreshes' helper process now (it loads a body model of its own: seconds), and with
        `wait` wait until it is ready (the node, at startup: else its first refresh would wait for the
        load, holding up a frame); otherwise it starts with the first refresh."""
        if self.refreshes_in_background and self._background is None:
            self._background = BackgroundFitter(self.fitter.config, self.config.tracking.refresh_nice)
        if wait and self._background is not None and not self._background.wait_ready(
                self.config.tracking.refresh_timeout_s):
            self._background_failed = True  # refreshes inline; counted when a frame would have sent one
            self.close()

    def close(self) -> None:
        """End the helper process, if any (pending refreshes are forgotten)."""
        if self._background is not None:
            self._background.close()
        self._background, self._pending, self._jobs = None, {}, {}

    def select_people(self, frame: Frame) -> tuple[Frame, Counter]:
        """Usable people only, their scores calibrated (`calibrated_scores`, `people.score_level`): far
        out-of-image keypoints become missing, people with too few keypoints and beyond
        `people.max_people` (smallest boxes) are left out (counted by reason), people without a detector
        id get one (free ids, left to right, so that colours stay put while people do) unless a tracker
        will associate them."""
        dropped: Counter = Counter()
        if len(frame.keypoints) == 0:
            return frame, dropped
        kp = frame.keypoints.astype(np.float64).copy()
        cam, sel = frame.camera, self.config.people
        kp[..., 2] = calibrated_scores(kp[..., 2], sel.score_level, sel.score_max_gain)
        conf = self.config.fitting.init.keypoint_conf
        mx, my = sel.keypoint_margin * cam.width, sel.keypoint_margin * cam.height
        u, v = kp[..., 0], kp[..., 1]
        with np.errstate(invalid="ignore"):
            outside = (u < -mx) | (u > cam.width - 1 + mx) | (v < -my) | (v > cam.height - 1 + my)
        good_before = (kp[..., 2] >= conf).sum(axis=1)
        kp[outside] = 0.0
        good = kp[..., 2] >= conf
        keep = good.sum(axis=1) >= sel.min_keypoints
        for i in np.flatnonzero(~keep):
            dropped[PERSON_OUT_OF_IMAGE if good_before[i] >= sel.min_keypoints else PERSON_FEW_KEYPOINTS] += 1
        index = np.flatnonzero(keep)
        bystanders = None
        if len(index) > sel.max_people:
            area = np.array([_box_area(kp[i][good[i], :2]) for i in index])
            dropped[PERSON_MAX_PEOPLE] += len(index) - sel.max_people
            by_area = index[np.argsort(-area, kind="stable")]
            index, bystanders = np.sort(by_area[: sel.max_people]), kp[np.sort(by_area[sel.max_people:])]
        kp, ids = kp[index], frame.person_ids[index].astype(np.int64)
        anonymous = np.flatnonzero(ids < 0) if self.tracker is None else []
        if len(anonymous):
            taken = set(ids[ids >= 0].tolist())
            free = (i for i in range(len(ids) + len(taken) + 1) if i not in taken)
            centre_u = [np.mean(kp[i][good[index[i]], 0]) for i in anonymous]
            for i in anonymous[np.argsort(centre_u, kind="stable")]:
                ids[i] = next(free)
        return replace(frame, keypoints=kp, person_ids=ids, bystanders=bystanders), dropped

    def observations(self, frame: Frame) -> tuple[list[PersonObservation], np.ndarray]:
        """Undistort the keypoints, move the scan into the camera frame and cut out each person's points.
        Returns the observations and the LiDAR origin in the camera frame."""
        expected = None
        if self.tracker is not None and len(frame.person_ids) == len(frame.keypoints):
            expected = self.tracker.expected_depth(frame.person_ids, frame.stamp_ns)
        undistorted, extraction = extract_frame_people(frame, self.config.lidar, expected, self.config.fitting.init)
        ground = ground_vector(extraction.ground)
        people = []
        for i, person in enumerate(extraction.people):
            pid = int(frame.person_ids[i]) if i < len(frame.person_ids) else -1
            people.append(PersonObservation(
                person_id=pid, keypoints=undistorted[i], bbox=np.asarray(person.bbox, dtype=np.float64),
                points=person.points, init=frame.init_bodies.get(pid) if pid >= 0 else None, ground=ground,
                depth_bound=float(person.depth_bound) if np.isfinite(person.depth_bound) else None,
            ))
        return people, frame.T_cam_lidar[:3, 3].copy()

    def observe(self, frame: Frame) -> FrameFits:
        """The path up to the fit: people selected, their observations (`fits` left empty)."""
        frame, dropped = self.select_people(frame)
        if len(frame.keypoints) == 0:
            if self.tracker is not None:
                self.tracker.assign([], frame.stamp_ns)  # a frame without people: the tracks missed it
            return FrameFits(frame, [], [], frame.T_cam_lidar[:3, 3].copy(), dropped)
        t = time.perf_counter()
        people, origin = self.observations(frame)
        if self.tracker is not None:
            people = self.tracker.assign(people, frame.stamp_ns)
            frame = replace(frame, person_ids=np.array([p.person_id for p in people], dtype=np.int64))
        return FrameFits(frame, people, [], origin, dropped, {"extract": time.perf_counter() - t})

    def fit_observed(self, observed: FrameFits, options: FitOptions | None = None) -> FrameFits:
        """The fit of `observe`'s people (the bench fits one observation several ways)."""
        t = time.perf_counter()
        latency = dict(observed.latency)
        if self.tracker is None:
            fits = self.fitter.fit(observed.observations, observed.frame.camera.K, observed.lidar_origin, options)
        else:
            fits = self._fit_tracked(observed, options, latency)
        latency["fit"] = time.perf_counter() - t
        return replace(observed, fits=fits, latency=latency)

    def _fit_tracked(self, observed: FrameFits, options: FitOptions | None,
                     latency: dict[str, float]) -> list[BodyFit]:
        """Warm fits for tracked people, cold ones for the others and for warm fits that lost their person;
        every `tracking.refresh_frames` frames of a track (`_refreshes_due`), a cold fit too, with the warm
        start as one more hypothesis, which replaces the warm fit when its final loss is below
        `tracking.refresh_margin` of the warm fit's (a warm solve cannot leave a wrong minimum, e.g. a
        heading it inherited, and the fits' residuals do not tell). The tracks are updated with the
        result (velocity onto each fit)."""
        tracker, stamp, K = self.tracker, observed.frame.stamp_ns, observed.frame.camera.K
        people = observed.observations
        second_starts = self._take_background_refreshes(people)
        warm_start = {i: tracker.warm_start(p.person_id, stamp) for i, p in enumerate(people)
                      if p.init is None and not self._regained(p)}
        warm = [i for i, start in warm_start.items() if start is not None]
        second = {i: tracker.warm_start(people[i].person_id, stamp, second_starts[people[i].person_id])
                  for i in warm if people[i].person_id in second_starts}
        warm_fits: dict[int, BodyFit] = {}
        lost_fits: dict[int, BodyFit] = {}
        second_won = 0
        if warm:
            rows = [(i, warm_start[i]) for i in warm] + [(i, start) for i, start in second.items()]
            warm_people = [replace(people[i], init=start.params, init_vertices=start.vertices,
                                   predicted_pelvis=start.pelvis, predicted_keypoints=start.keypoints)
                           for i, start in rows]
            warm_options = replace(options or FitOptions(), use_icp=self.config.tracking.warm_icp)
            t = time.perf_counter()
            warm_results = self.warm_fitter.fit(warm_people, K, observed.lidar_origin, warm_options)
            latency["warm_fit_per_person"] = (time.perf_counter() - t) / len(warm)
            chosen = dict(zip(warm, warm_results[:len(warm)], strict=True))
            for (i, _), fit in zip(rows[len(warm):], warm_results[len(warm):], strict=True):
                if fit.quality.final_loss < chosen[i].quality.final_loss:  # same profile, same data: comparable
                    chosen[i], second_won = fit, second_won + 1
            for i, fit in chosen.items():
                fit = replace(fit, flags=(fit.flags - {FLAG_EXTERNAL_INIT}) | {FLAG_WARM_START})
                (lost_fits if self._lost(fit, people[i], K) else warm_fits)[i] = fit
        refresh = self._refreshes_due([i for i in warm_fits if people[i].person_id not in self._pending], people)
        for i in refresh:
            track = tracker.track(people[i].person_id)
            track.last_refresh_frame = track.frames
        settled = self._settled_refreshes(sorted(refresh), people, warm_start, K, observed.lidar_origin, options)
        inline = refresh - settled
        if self.refreshes_in_background:  # fitted beside the next frames; this frame is output warm
            self._start_background_refreshes(sorted(inline), people, warm_start, warm_fits, K,
                                             observed.lidar_origin, options)
            inline = set()
        deferred: set[int] = set()  # lost warm fits output as they are, their cold refits in the background
        if self.refreshes_in_background and self.config.tracking.lost_background:
            running = {i for i in lost_fits if people[i].person_id in self._pending}  # a refresh's cold fit will do
            for i in running:
                self._pending[people[i].person_id].lost = True
            deferred = running | self._start_background_refreshes(
                sorted(set(lost_fits) - running), people, warm_start, lost_fits, K, observed.lidar_origin, options,
                lost=True)
        fits = {**warm_fits, **{i: replace(lost_fits[i], flags=lost_fits[i].flags | {FLAG_LOST}) for i in deferred}}
        cold = [i for i in range(len(people)) if i not in fits or i in inline]
        if cold:
            cold_people = [self._cold_start(people[i], warm_start.get(i), i in refresh) for i in cold]
            for i, fit in zip(cold, self.fitter.fit(cold_people, K, observed.lidar_origin, options), strict=True):
                if i not in warm_fits or self._better(fit, warm_fits[i]):
                    fits[i] = fit
        refreshed = sum(fits[i] is not warm_fits[i] for i in refresh)
        lost = len(lost_fits)
        tracker.stats.fits.update({"warm": len(warm_fits) - refreshed, "lost": lost, "refresh": len(refresh),
                                   "refresh_second_starts": len(second), "refreshed_second_start": second_won,
                                   "refresh_settled": len(settled), "refreshed": refreshed,
                                   "refresh_background": len(refresh) - len(settled) - len(inline),
                                   "lost_background": len(deferred),
                                   "cold": len(cold) - len(inline) - (lost - len(deferred))})
        pose = self.fitter.model.posed if isinstance(self.fitter, Fitter) else None  # stand-ins: unsmoothed
        return tracker.update([fits[i] for i in range(len(people))], people, stamp, pose)

    def _start_background_refreshes(self, refresh: list[int], people: list[PersonObservation],
                                    warm_start: dict[int, WarmStart | None], warm_fits: dict[int, BodyFit],
                                    K: np.ndarray, lidar_origin: np.ndarray, options: FitOptions | None,
                                    lost: bool = False) -> set[int]:
        """Send the refreshes' cold fits (one batch) to the helper process, or with `lost` the cold refits of
        lost warm fits (`warm_fits` then holds those); returns the people sent."""
        if not refresh:
            return set()
        self.start_background()
        batch = [self._cold_start(people[i], warm_start.get(i), not lost) for i in refresh]
        try:
            job = self._background.submit(batch, K, lidar_origin, options)
        except BackgroundError:
            self._background_failed = True  # from now on inline; this frame's refreshes are skipped
            self.tracker.stats.fits["refresh_failed"] += len(refresh)
            return set()
        for k, i in enumerate(refresh):
            track = self.tracker.track(people[i].person_id)
            self._pending[people[i].person_id] = _PendingRefresh(job, k, track, track.frames, warm_fits[i], lost)
        return set(refresh)

    def _take_background_refreshes(self, people: list[PersonObservation]) -> dict[int, BodyFit]:
        """The background refreshes due in this frame: those `tracking.refresh_apply_frames` fitted frames
        of their track past the frame they started on (waiting for them if need be, so that the node and
        the replay take each at the same frame). A cold fit clearly better than its frame's warm fit
        (`_better`) becomes a second start of this frame's warm solve, beside the track's last fit, the
        lower final loss kept (`tracking.refresh_second_start`: it is that many frames old; false: it
        becomes the track's last fit, the only start); a track that was refitted cold since, or ended,
        does not take it. A lost fit's cold refit is due after
        `tracking.lost_apply_frames` and is taken while the track's last fit is still lost, or clearly
        worse than it. Returns the second starts: person id -> cold fit."""
        cfg = self.config.tracking
        second_starts: dict[int, BodyFit] = {}
        for pid in [p.person_id for p in people if p.person_id in self._pending]:
            pending = self._pending[pid]
            track = self.tracker.track(pid)
            wait = cfg.lost_apply_frames if pending.lost else cfg.refresh_apply_frames
            if track is pending.track and track.frames - pending.frames <= wait:
                continue
            del self._pending[pid]
            try:
                if pending.job not in self._jobs:
                    self._jobs[pending.job] = self._background.result(pending.job, cfg.refresh_timeout_s)
                cold = self._jobs[pending.job][pending.index]
            except BackgroundError:
                self._background_failed = True
                self.tracker.stats.fits["refresh_failed"] += 1
                self.close()
                return {}
            last = track.last_fit if track is pending.track else None
            if last is None or FLAG_WARM_START not in last.flags:
                continue
            if pending.lost and (FLAG_LOST in last.flags or self._better(cold, last)):
                track.last_fit = cold
                self.tracker.stats.fits["lost_refitted"] += 1
            elif not pending.lost and self._better(cold, pending.warm):
                if cfg.refresh_second_start:
                    second_starts[pid] = cold
                else:
                    track.last_fit = cold
                    self.tracker.stats.fits["refreshed"] += 1
        waiting = {p.job for p in self._pending.values()}
        self._jobs = {job: fits for job, fits in self._jobs.items() if job in waiting}
        return second_starts

    @staticmethod
    def _cold_start(person: PersonObservation, warm_start: WarmStart | None, refresh: bool) -> PersonObservation:
        """A tracked person's cold fit knows where their track expects them (the depth of a start from
        the image alone: a half-hidden person's size in the image put one 2.8 m too deep on
        bags/people_anonymous); a refresh also weighs the warm start among the built-in hypotheses."""
        if warm_start is None:
            return person
        return replace(person, predicted_pelvis=warm_start.pelvis,
                       hypothesis=_as_hypothesis(warm_start) if refresh else person.hypothesis)

    def _settled_refreshes(self, refresh: list[int], people: list[PersonObservation],
                           warm_start: dict[int, WarmStart | None], K: np.ndarray, lidar_origin: np.ndarray,
                           options: FitOptions | None) -> set[int]:
        """The refreshes that need no cold fit (with `tracking.refresh_compete_first`): those whose warm
        start beats the built-in heading hypotheses in the initializer's joint refinement. Their cold fit
        would have gone on from the warm start, which the warm fit has refined already."""
        compete = getattr(self.fitter, "given_hypothesis_wins", None)
        if not refresh or not self.config.tracking.refresh_compete_first or compete is None:
            return set()
        trial = [replace(people[i], hypothesis=_as_hypothesis(warm_start[i])) for i in refresh]
        return {i for i, won in zip(refresh, compete(trial, K, lidar_origin, options), strict=True) if won}

    def _better(self, cold: BodyFit, warm: BodyFit) -> bool:
        """A refresh's cold fit is kept over the warm fit only when its final loss is clearly lower."""
        return bool(np.isfinite(cold.quality.final_loss) and FLAG_DIVERGED not in cold.flags
                    and cold.quality.final_loss < self.config.tracking.refresh_margin * warm.quality.final_loss)

    def _refreshes_due(self, candidates: list[int], people: list[PersonObservation]) -> set[int]:
        """Which of the warm-fitted `candidates` get the refresh's cold fit: those `refresh_frames` or more
        frames past their last refresh (or start), at most `refresh_max_people` of them, the longest waiting first
        (tracks that started together would otherwise all refresh in the same frame, a frame as slow as
        fitting everyone cold; the others wait a frame or two)."""
        cfg = self.config.tracking
        if cfg.refresh_frames <= 0:
            return set()
        waited = {i: (t := self.tracker.track(people[i].person_id)).frames - t.last_refresh_frame for i in candidates}
        due = sorted((i for i in candidates if waited[i] >= cfg.refresh_frames), key=lambda i: -waited[i])
        return set(due[: cfg.refresh_max_people] if cfg.refresh_max_people > 0 else due)

    def _regained(self, obs: PersonObservation) -> bool:
        """A tracked person fitted from the image alone last time who has LiDAR points again: their last
        fit's depth and pose were guesses the points may contradict by metres, which a short warm solve
        walks off only over many frames, so they get the cold start."""
        track = self.tracker.track(obs.person_id)
        return (track is not None and track.last_fit is not None and FLAG_IMAGE_ONLY in track.last_fit.flags
                and len(obs.points) >= self.config.fitting.min_points)

    def _lost(self, fit: BodyFit, obs: PersonObservation, K: np.ndarray) -> bool:
        """A warm fit that does not explain its person any more: the cold start takes over. The person's
        size in the image is the taller of their keypoint box and the fit's joints projected: a person
        half hidden behind someone has a box of their visible half, and keypoints as noisy as a whole
        person's (the hidden ones noisier). In 3D it is the points that must lie on the mesh, not the mesh
        on the points: a sparse or half-hidden person's visible mesh has no points near much of it however
        well it fits (the symmetric chamfer of good far fits reaches 0.15-0.2 m on a VLP-16)."""
        cfg = self.config.tracking
        joints = np.asarray(fit.keypoints3d, np.float64) @ np.asarray(K, np.float64).T
        front = joints[joints[:, 2] > 0.1]
        rows = front[:, 1] / front[:, 2]  # image rows of the joints in front of the camera
        height = max(float(obs.bbox[3] - obs.bbox[1]), float(np.ptp(rows)) if rows.size else 0.0, 1.0)
        off = fit.quality.points_to_mesh_m
        limit = float(np.hypot(cfg.lost_reprojection * height, cfg.lost_reprojection_floor_px))
        return (FLAG_DIVERGED in fit.flags or not fit.quality.reprojection_px <= limit
                or (np.isfinite(off) and off > cfg.lost_points_to_mesh_m) or self._faces_away(fit, obs, K))

    def _faces_away(self, fit: BodyFit, obs: PersonObservation, K: np.ndarray) -> bool:
        """The fit faces the other way from the detected face (`tracking.lost_face_offset_m`): across the
        image, the detected nose lies on one side of the ears and the fit's torso faces the other, both by
        more than the limit (metres at the nose's depth; the fit's side is where its nose would lie were
        its head turned as its torso). It catches what the reprojection cannot: a person seen side-on who
        turned round between two fits (a stop and a turn on the spot 0.3 s apart, as when the node fits
        every third frame) stays fitted facing where they faced before, and the mirror image of a side
        view projects almost alike but for the face, which the warm solve then turns alone. A person
        facing the camera or turned away has their nose between their ears in the image and a torso
        facing along the ray, so a detector's confident nose on someone seen from behind does not set it
        off."""
        limit = self.config.tracking.lost_face_offset_m
        kp = np.asarray(obs.keypoints, np.float64)
        conf = self.config.fitting.visibility.keypoint_conf_image
        nose = KP["nose"]
        ears = [KP[n] for n in ("left_ear", "right_ear") if kp[KP[n], 2] >= conf]
        X = np.asarray(fit.keypoints3d, np.float64)
        if limit <= 0 or kp[nose, 2] < conf or not ears or X[nose, 2] <= 0.1:
            return False
        seen = (kp[nose, 0] - kp[ears, 0].mean()) * X[nose, 2] / K[0, 0]
        shoulders, hips = X[[KP["left_shoulder"], KP["right_shoulder"]]], X[[KP["left_hip"], KP["right_hip"]]]
        forward = np.cross(shoulders[0] + hips[0] - shoulders[1] - hips[1], shoulders.mean(0) - hips.mean(0))
        forward /= max(float(np.linalg.norm(forward)), 1e-9)
        pelvis = hips.mean(0)
        across = forward[0] - pelvis[0] / max(pelvis[2], 1e-3) * forward[2]  # image-x component at the pelvis
        fitted = across * float(np.linalg.norm(X[nose] - X[ears].mean(0)))
        return bool(seen * fitted < 0 and min(abs(seen), abs(fitted)) > limit)

    def fit(self, frame: Frame, options: FitOptions | None = None) -> FrameFits:
        """The whole path of one frame (module docstring)."""
        return self.fit_observed(self.observe(frame), options)


def _as_hypothesis(start: WarmStart) -> BodyParams:
    """A warm start in the built-in hypotheses' form: `transl` is where the hip midpoint goes."""
    hypothesis = start.params.copy()
    hypothesis.transl = start.pelvis.copy()
    return hypothesis


def warm_fitter_for(config: Config, fitter: Fitter) -> Fitter:
    """A `Fitter` of the tracking's warm profile, sharing `fitter`'s body model (the same fitter when the
    warm profile is the fitter's own)."""
    warm = config.tracking.warm_profile
    if not isinstance(fitter, Fitter) or warm == fitter.config.profile:  # a stand-in fitter (tests) fits both
        return fitter
    return Fitter(replace(fitter.config, profile=warm), model=fitter.model)


# -- the library entry point --------------------------------------------------------------------------------
FITTER_CACHE_SIZE = 2  # fitters kept by `fit_frame` (each holds a body model's tensors)
_FITTERS: OrderedDict[str, Fitter] = OrderedDict()
_FITTERS_LOCK = threading.Lock()


def cached_fitter(config: FittingConfig) -> Fitter:
    """A `Fitter` for this configuration's value (two equal configurations share one), least recently used
    first out beyond `FITTER_CACHE_SIZE`."""
    key = json.dumps(to_dict(config), sort_keys=True)
    with _FITTERS_LOCK:
        fitter = _FITTERS.pop(key, None)
        if fitter is None:
            fitter = Fitter(config)
        _FITTERS[key] = fitter
        while len(_FITTERS) > FITTER_CACHE_SIZE:
            _FITTERS.popitem(last=False)
    return fitter


def fit_frame(
    frame_or_observations: Frame | list[PersonObservation],
    config: Config | None = None,
    K: np.ndarray | None = None,
    options: FitOptions | None = None,
) -> list[BodyFit]:
    """Fit every person of a frame. `config` defaults to the default profile (params/jackal_vlp16.yaml).

    A `Frame` runs the whole path (people selected, keypoints undistorted, points cut out of the scan);
    a list of observations (camera frame, keypoints undistorted) goes straight to the fitter: pass `K`.
    """
    config = config or load_config()
    fitter = cached_fitter(config.fitting)
    if isinstance(frame_or_observations, Frame):
        return FrameFitter(config, fitter).fit(frame_or_observations, options).fits
    if K is None:
        raise ValueError("fit_frame on observations needs the camera intrinsics K")
    return fitter.fit(list(frame_or_observations), K, None, options)
