"""People tracked across frames: ids, one shape per person, a motion filter, warm starts.

Per frame, `Tracker.assign` gives every observation its track: the detector's track id when the
keypoints carry one (`person_id >= 0`), else the package's own association (the gated, Hungarian
assignment of `association.associate`). `Tracker.warm_start` is a tracked person's previous fit moved
to where the motion filter predicts the pelvis at the new stamp (pose as last seen, the track's held
shape), for the fitter's short warm solve. `Tracker.update` folds the frame's fits in: the filter's
velocity goes onto each fit, the shape is averaged over the track's first frames (weighted by their
LiDAR points) and then held. A track ends once the frames the tracker was given show it unseen for
longer than `max_unseen_s` (an id that comes back then starts a new track): time between frames the
node did not process is not evidence that a person left, so a node that falls behind and skips frames
keeps its tracks (and their warm starts). Everything is in the camera frame, in which the fits are made.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from smplify3d_ros.geometry import move_body, transform
from smplify3d_ros.keypoints import hip_midpoint
from smplify3d_ros.tracking.association import associate, box_iou
from smplify3d_ros.tracking.config import TrackingConfig
from smplify3d_ros.tracking.motion import MotionFilter
from smplify3d_ros.types import FLAG_IMAGE_ONLY, FLAG_WARM_START, BodyFit, BodyParams, PersonObservation

_NS = 1e-9
PoseFunction = Callable[[list[BodyParams]], list[Any]]  # BodyModel.posed: params -> PosedBody geometry


def _extrapolated(before: np.ndarray, last: np.ndarray) -> np.ndarray:
    """(N, 3) rotations one step on from `last` at the rate from `before` to `last`."""
    rb, rl = Rotation.from_rotvec(np.asarray(before, np.float64)), Rotation.from_rotvec(np.asarray(last, np.float64))
    return (rl * (rb.inv() * rl)).as_rotvec()


def _slerp(a: np.ndarray, b: np.ndarray, weight: float) -> np.ndarray:
    """(N, 3) axis-angle rotations `weight` of the way from `a` to `b` (on the rotation group)."""
    ra, rb = Rotation.from_rotvec(np.asarray(a, np.float64)), Rotation.from_rotvec(np.asarray(b, np.float64))
    return (ra * Rotation.from_rotvec(weight * (ra.inv() * rb).as_rotvec())).as_rotvec()


def pelvis(fit: BodyFit) -> np.ndarray:
    """(3,) the hip midpoint of a fit (camera frame)."""
    return hip_midpoint(fit.keypoints3d)


def surface_point(obs: PersonObservation) -> np.ndarray | None:
    """(3,) the median of a person's LiDAR points, or None without points: where the scan sees them."""
    return np.median(obs.points, axis=0).astype(np.float64) if len(obs.points) else None


@dataclass
class Track:
    track_id: int
    from_detector: bool  # the id is the detector's
    last_stamp_ns: int
    motion: MotionFilter
    bbox: np.ndarray  # (4,) the last keypoint box, px
    surface: np.ndarray | None  # (3,) the median of the last points the track's person had, camera frame
    surface_stamp_ns: int  # when those points were measured (frames without points keep the last ones)
    last_fit: BodyFit | None = None  # the last fit as the fitter made it (the next warm start)
    # the keypoint joints (17, 3) of the fit before `last_fit` and its stamp: the joints' velocity
    previous_keypoints: np.ndarray | None = None
    previous_stamp_ns: int = 0
    last_output: BodyFit | None = None  # ... as it was output (smoothed)
    previous_output: BodyFit | None = None  # the output before that (the rotations' rate of change)
    frames: int = 0  # frames fitted
    last_refresh_frame: int = 0  # `frames` at the track's last refresh (`FrameFitter._refreshes_due`)
    shape_sum: np.ndarray | None = None
    shape_weight: float = 0.0
    shape: np.ndarray | None = None  # the held shape, once `shape_frames` frames are in
    missed_ns: int | None = None  # the latest frame given to the tracker without this track's person since last seen

    def unseen_s(self) -> float:
        """How long the frames given to the tracker show this track unseen (0 until a frame misses it)."""
        return 0.0 if self.missed_ns is None else (self.missed_ns - self.last_stamp_ns) * _NS

    def age_s(self, stamp_ns: int) -> float:
        return (stamp_ns - self.last_stamp_ns) * _NS

    def surface_age_s(self, stamp_ns: int) -> float:
        """How long before `stamp_ns` the track's last points were measured."""
        return (stamp_ns - self.surface_stamp_ns) * _NS

    def predicted_surface(self, stamp_ns: int) -> np.ndarray | None:
        """(3,) where the last points' median will be at `stamp_ns` (moved by the filter's velocity since
        they were measured), or None when the track's person never had points. The fitted positions of
        frames without points (depth from the image alone) move only the velocity: the surface keeps the
        depth the LiDAR measured."""
        if self.surface is None:
            return None
        return self.surface + max(self.surface_age_s(stamp_ns), 0.0) * self.motion.velocity


@dataclass
class WarmStart:
    """A tracked person's start for the warm solve (`Tracker.warm_start`)."""

    params: BodyParams  # the last fit moved to the predicted pelvis, with the track's shape
    pelvis: np.ndarray  # (3,) where its hip midpoint now is: the motion filter's prediction
    vertices: np.ndarray | None  # (V, 3) float32 the last fit's mesh moved with it (None: the fit had none)
    keypoints: np.ndarray | None = None  # (17, 3) where its keypoint joints now are predicted (`predicted_joints`)


@dataclass
class TrackerStats:
    tracks_started: int = 0
    tracks_ended: int = 0
    fits: Counter = field(default_factory=Counter)  # "warm", "cold", "lost" (warm fits refitted cold)


class Tracker:
    """See the module docstring."""

    def __init__(self, config: TrackingConfig) -> None:
        self.config = config
        self.tracks: dict[int, Track] = {}
        self.stats = TrackerStats()
        self._next_id = 0  # the package's own ids, for people the detector gives none ...
        self._own: set[int] = set()  # ... and the ones handed out

    def reset(self) -> None:
        """Forget every track (a clock reset, e.g. a bag played again)."""
        self.stats.tracks_ended += len(self.tracks)
        self.tracks.clear()

    # -- ids -------------------------------------------------------------------------------------------
    def assign(self, people: list[PersonObservation], stamp_ns: int) -> list[PersonObservation]:
        """The observations with their track ids (detector ids kept; anonymous people associated). Every
        frame the node fits goes through here, those without people too (`people` empty): the tracks
        missing from it count it as a frame unseen."""
        self._end_stale()
        out = list(people)
        anonymous = [i for i, p in enumerate(people) if p.person_id < 0]
        claimed = {p.person_id for p in people if p.person_id >= 0}
        candidates = [t for t in self.tracks.values() if not t.from_detector and t.track_id not in claimed]
        matches = associate(candidates, [people[i] for i in anonymous], stamp_ns, self.config)
        for k, i in enumerate(anonymous):
            track = matches.get(k)
            if track is None:
                while self._next_id in self.tracks or self._next_id in claimed:
                    self._next_id += 1
                track_id, self._next_id = self._next_id, self._next_id + 1
                self._own.add(track_id)
            else:
                track_id = track.track_id
            out[i] = replace(people[i], person_id=track_id)
        present = {p.person_id for p in out}
        for track in self.tracks.values():
            if track.track_id not in present:
                track.missed_ns = stamp_ns
        return out

    def _end_stale(self) -> None:
        for track_id in [t.track_id for t in self.tracks.values() if t.unseen_s() > self.config.max_unseen_s]:
            del self.tracks[track_id]
            self._own.discard(track_id)
            self.stats.tracks_ended += 1

    # -- warm starts -----------------------------------------------------------------------------------
    def track(self, person_id: int) -> Track | None:
        return self.tracks.get(person_id)

    def warm_start(self, person_id: int, stamp_ns: int, fit: BodyFit | None = None) -> WarmStart | None:
        """The track's last fit (or `fit`, another of its fits) moved (translated) to the predicted pelvis
        at `stamp_ns`, with the track's shape, and its mesh moved with it: the warm solve's ICP needs no
        forward pass of its own. The held shape may differ from the last fit's by one step of the shape
        averaging, millimetres of surface, which the rigid alignment does not notice."""
        track = self.tracks.get(person_id)
        if track is None or track.last_fit is None or not self.config.warm_start:
            return None
        fit = track.last_fit if fit is None else fit
        target = track.motion.predicted(track.age_s(stamp_ns))
        shift = target - pelvis(fit)
        root, transl, _ = move_body(fit.params.root_orient, fit.params.transl, fit.center, transform(t=shift))
        shape = track.shape if track.shape is not None else self._mean_shape(track)
        params = fit.params.copy()
        params.root_orient, params.transl, params.shape = root, transl, shape.copy()
        vertices = None if fit.vertices is None else (fit.vertices + shift).astype(np.float32)
        joints = self.predicted_joints(track, stamp_ns, shift) if fit is track.last_fit else \
            np.asarray(fit.keypoints3d, np.float64) + shift
        return WarmStart(params, target.copy(), vertices, joints)

    def predicted_joints(self, track: Track, stamp_ns: int, shift: np.ndarray) -> np.ndarray:
        """(17, 3) where the track's last fit's keypoint joints are predicted at `stamp_ns`
        (`joint_prediction`): `constant_velocity` moves each on at its velocity between the last two fits
        (J + (J − J_before) · dt_now / dt_before), `filtered` puts the hip midpoint where the motion filter
        predicts it and moves the joints about it on at their velocity, `last_pose` moves the last pose by
        the filter's prediction (`shift`, the warm start's). With one fit, or when the last fit was not a
        warm fit (a cold one, a refresh: its difference from the one before is no motion), the last pose
        moved by the filter's prediction."""
        last = np.asarray(track.last_fit.keypoints3d, np.float64)
        mode = self.config.joint_prediction
        before, dt_before = track.previous_keypoints, (track.last_stamp_ns - track.previous_stamp_ns) * _NS
        if mode == "last_pose" or before is None or dt_before <= 0 or FLAG_WARM_START not in track.last_fit.flags:
            return last + shift
        rate = track.age_s(stamp_ns) / dt_before
        if mode == "filtered":
            root, root_before = hip_midpoint(last), hip_midpoint(before)
            relative, relative_before = last - root, before - root_before
            return root + shift + relative + (relative - relative_before) * rate
        return last + (last - before) * rate

    def expected_depth(self, person_ids: np.ndarray, stamp_ns: int) -> np.ndarray:
        """(P, 2) where the LiDAR should see each detector-tracked person at `stamp_ns`: the depth of their
        last points' median moved by the motion filter's prediction, and a tolerance of `extraction_gate_m`
        grown by `gate_speed_mps` per second unseen; NaN rows for anonymous people, tracks without points
        last time, and with the gate off (`extraction_gate_m` 0)."""
        out = np.full((len(person_ids), 2), np.nan)
        if self.config.extraction_gate_m <= 0:
            return out
        for i, person_id in enumerate(np.asarray(person_ids).tolist()):
            track = self.tracks.get(int(person_id)) if person_id >= 0 else None
            if track is None or not track.from_detector or track.surface is None or track.last_fit is None \
                    or track.surface_stamp_ns != track.last_stamp_ns:
                continue
            age = track.age_s(stamp_ns)
            if age > self.config.max_unseen_s:
                continue
            tolerance = self.config.extraction_gate_m + self.config.gate_speed_mps * age
            out[i] = track.predicted_surface(stamp_ns)[2], tolerance
        return out

    def held_shape(self, person_id: int) -> np.ndarray | None:
        """The shape a track holds (None while it is still being estimated)."""
        track = self.tracks.get(person_id)
        return None if track is None or track.shape is None else track.shape.copy()

    @staticmethod
    def _mean_shape(track: Track) -> np.ndarray:
        return track.shape_sum / max(track.shape_weight, 1e-12)

    # -- after the fit ---------------------------------------------------------------------------------
    def update(self, fits: list[BodyFit], people: list[PersonObservation], stamp_ns: int,
               pose: PoseFunction | None = None) -> list[BodyFit]:
        """Fold the frame's fits into their tracks; the fits back with their velocity (m/s, camera frame),
        and, with `pose` (BodyParams -> geometry, the body model's), smoothed (`_smoothed`)."""
        by_id = {p.person_id: p for p in people}
        out = []
        for fit in fits:
            obs = by_id.get(fit.person_id)
            track = self._track_for(fit, obs, stamp_ns)
            track.motion.update(pelvis(fit), track.age_s(stamp_ns),
                                self.config.image_depth_sigma_m if FLAG_IMAGE_ONLY in fit.flags else None)
            if track.last_fit is not None:
                track.previous_keypoints = np.asarray(track.last_fit.keypoints3d, np.float64)
                track.previous_stamp_ns = track.last_stamp_ns
            track.last_fit = fit
            if pose is not None and track.last_output is not None:
                fit = self._smoothed(fit, track, pose)
            track.previous_output, track.last_output = track.last_output, fit
            track.last_stamp_ns, track.frames, track.missed_ns = stamp_ns, track.frames + 1, None
            if obs is not None:
                track.bbox = np.asarray(obs.bbox, np.float64)
                if len(obs.points):
                    track.surface, track.surface_stamp_ns = surface_point(obs), stamp_ns
            self._fold_shape(track, fit)
            # a track's first fit has no velocity yet (the filter starts at rest, which would be a guess)
            out.append(replace(fit, velocity=track.motion.velocity if track.frames > 1 else None))
        return out

    def _smoothed(self, fit: BodyFit, track: Track, pose: PoseFunction) -> BodyFit:
        """The fit moved towards the track: its joint and root rotations part of the way from the track's
        prediction (the last output's rotations turned on at their last rate: an alpha-beta filter, which
        does not lag behind a steady motion; `pose_smoothing` is the new fit's weight), its pelvis at the
        motion filter's estimate."""
        cfg = self.config
        if cfg.pose_smoothing >= 1.0 and not cfg.filter_position:
            return fit
        params = fit.params.copy()
        last = track.last_output.params
        if cfg.pose_smoothing < 1.0 and last.pose.shape == params.pose.shape:
            before = track.previous_output.params if track.previous_output is not None else last
            joints, root = _extrapolated(before.pose, last.pose), _extrapolated(before.root_orient[None],
                                                                                last.root_orient[None])
            params.pose = _slerp(joints, params.pose, cfg.pose_smoothing)
            params.root_orient = _slerp(root, params.root_orient[None], cfg.pose_smoothing)[0]
        body = pose([params])[0]
        shift = (track.motion.position if cfg.filter_position else pelvis(fit)) - hip_midpoint(body.keypoints3d)
        params.transl = params.transl + shift
        return replace(fit, params=params, vertices=(body.vertices + shift).astype(np.float32),
                       keypoints3d=(body.keypoints3d + shift).astype(np.float32),
                       joints=(body.joints + shift).astype(np.float32), rotation_center=body.rotation_center + shift)

    def _track_for(self, fit: BodyFit, obs: PersonObservation | None, stamp_ns: int) -> Track:
        track = self.tracks.get(fit.person_id)
        if track is None:
            cfg = self.config
            track = self.tracks[fit.person_id] = Track(
                track_id=fit.person_id, from_detector=fit.person_id not in self._own, last_stamp_ns=stamp_ns,
                motion=MotionFilter(cfg.accel_sigma_mps2, cfg.position_sigma_m),
                bbox=np.zeros(4) if obs is None else np.asarray(obs.bbox, np.float64),
                surface=None if obs is None else surface_point(obs), surface_stamp_ns=stamp_ns)
            self.stats.tracks_started += 1
        return track

    def _fold_shape(self, track: Track, fit: BodyFit) -> None:
        """Average the shape over the first `shape_frames` fits (weight: LiDAR points + 1), then hold it
        (moving it by `shape_rate` per frame)."""
        shape = np.asarray(fit.params.shape, np.float64)
        if track.shape is not None:
            track.shape = (1.0 - self.config.shape_rate) * track.shape + self.config.shape_rate * shape
            return
        weight = 1.0 + fit.quality.num_points
        track.shape_sum = weight * shape if track.shape_sum is None else track.shape_sum + weight * shape
        track.shape_weight += weight
        if track.frames >= self.config.shape_frames:
            track.shape = self._mean_shape(track)


__all__ = ["Track", "Tracker", "TrackerStats", "WarmStart", "box_iou", "pelvis", "surface_point"]
