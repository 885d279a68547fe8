"""Tracks across frames: ids kept through occlusions and crossings, a held shape, velocity, warm starts."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smplify3d_ros.config import load_config
from smplify3d_ros.tracking.motion import MotionFilter
from smplify3d_ros.tracking.tracker import Tracker, pelvis
from smplify3d_ros.types import BodyFit, BodyParams, FitQuality, PersonObservation

NS = 100_000_000  # 10 Hz


def config(**changes):
    return dataclasses.replace(load_config().tracking, **changes)


def observation(pid: int, x: float, z: float = 5.0, n_points: int = 50) -> PersonObservation:
    """A person whose points sit around (x, 0, z) and whose keypoint box follows x."""
    rng = np.random.default_rng(int(1000 * x) % 2**31)
    points = np.array([x, 0.0, z]) + 0.05 * rng.standard_normal((n_points, 3))
    u = 320.0 + 500.0 * x / z
    bbox = np.array([u - 30.0, 100.0, u + 30.0, 300.0])
    return PersonObservation(pid, np.zeros((17, 3)), bbox, points.astype(np.float32))


def fit_at(pid: int, x: float, z: float = 5.0, shape=(0.5,) * 6, n_points: int = 50) -> BodyFit:
    kp = np.tile([x, 0.0, z + 0.1], (17, 1)).astype(np.float32)
    params = BodyParams("anny", np.array(shape, float), np.zeros((19, 3)), np.zeros(3), np.array([x, 0.0, z + 0.1]))
    return BodyFit(pid, params, ["j"] * 19, np.zeros((4, 3), np.float32), kp, np.zeros((19, 3), np.float32),
                   FitQuality(2.0, 0.02, n_points, [], True, 0.1))


def step(tracker: Tracker, frame: int, people: list[PersonObservation], shapes=None) -> list[BodyFit]:
    stamp = frame * NS
    assigned = tracker.assign(people, stamp)
    fits = [fit_at(p.person_id, float(np.median(p.points[:, 0])), float(np.median(p.points[:, 2])),
                   shape=(shapes or {}).get(k, (0.5,) * 6)) for k, p in enumerate(assigned)]
    return tracker.update(fits, assigned, stamp)


def test_anonymous_people_keep_their_ids_while_they_cross():
    """Two people walking towards each other at different depths keep their ids through the crossing."""
    tracker = Tracker(config())
    ids = []
    for frame in range(30):
        a = observation(-1, -1.5 + 0.1 * frame, z=4.0)
        b = observation(-1, 1.5 - 0.1 * frame, z=6.0)
        fits = step(tracker, frame, [b, a] if frame % 2 else [a, b])  # the detector's order changes
        by_depth = {round(float(np.median(f.keypoints3d[:, 2])) - 0.1): f.person_id for f in fits}
        ids.append((by_depth[4], by_depth[6]))
    assert len(set(ids)) == 1, ids
    assert tracker.stats.tracks_started == 2


def test_a_track_keeps_its_id_through_a_short_occlusion_and_ends_after_a_long_one():
    tracker = Tracker(config(max_unseen_s=1.0))
    first = step(tracker, 0, [observation(-1, 0.0)])[0].person_id
    for frame in range(1, 5):
        step(tracker, frame, [observation(-1, 0.1 * frame)])
    for frame in range(5, 10):  # hidden for 0.5 s, walking on
        step(tracker, frame, [])
    back = step(tracker, 10, [observation(-1, 1.0)])[0].person_id
    assert back == first
    for frame in range(11, 31):  # hidden for 2 s: a new track
        step(tracker, frame, [])
    later = step(tracker, 31, [observation(-1, 1.0)])[0].person_id
    assert later != first and tracker.stats.tracks_ended == 1


def test_frames_the_node_skipped_do_not_end_a_track():
    """A node that falls behind fits frames far apart: a person present in each keeps their track (and
    warm start), however long the gap; only frames that miss them count as unseen."""
    tracker = Tracker(config(max_unseen_s=1.0))
    first = step(tracker, 0, [observation(-1, 0.0)])[0].person_id
    step(tracker, 1, [observation(-1, 0.1)])
    for frame in (15, 30, 45):  # 1.5 s between the frames fitted
        assert step(tracker, frame, [observation(-1, 0.1)])[0].person_id == first
    assert tracker.stats.tracks_ended == 0 and tracker.warm_start(first, 46 * NS) is not None
    step(tracker, 46, [])  # missed once, then the next frame fitted is 1.5 s later: unseen for 0.1 s only
    assert step(tracker, 60, [observation(-1, 0.1)])[0].person_id == first


def test_detector_ids_are_kept_and_a_returning_id_starts_fresh():
    tracker = Tracker(config(max_unseen_s=0.5, shape_frames=2))
    for frame in range(3):
        step(tracker, frame, [observation(7, 0.0)], shapes={0: (0.2,) * 6})
    assert tracker.held_shape(7) == pytest.approx(np.full(6, 0.2))
    for frame in range(3, 20):
        step(tracker, frame, [])
    fits = step(tracker, 20, [observation(7, 0.0)], shapes={0: (0.8,) * 6})
    assert fits[0].person_id == 7
    assert tracker.held_shape(7) is None, "a new track for the returning id: its shape is estimated again"


def test_a_held_shape_does_not_drift():
    """After `shape_frames`, noisy per-frame shapes move the held shape by at most `shape_rate` each."""
    tracker = Tracker(config(shape_frames=5, shape_rate=0.0))
    rng = np.random.default_rng(0)
    for frame in range(40):
        noisy = tuple(np.clip(0.5 + 0.2 * rng.standard_normal(6), 0, 1))
        if frame >= 5:
            noisy = (1.0,) * 6  # a bad frame streak after the shape is held
        step(tracker, frame, [observation(3, 0.01 * frame)], shapes={0: noisy})
    held = tracker.held_shape(3)
    assert held is not None and np.all(np.abs(held - 0.5) < 0.2)


def test_the_motion_filter_recovers_a_walking_velocity():
    f = MotionFilter(accel_sigma=2.0, position_sigma=0.05)
    rng = np.random.default_rng(1)
    for k in range(30):
        f.update(np.array([1.2 * 0.1 * k, 0.0, 5.0]) + 0.03 * rng.standard_normal(3), 0.1)
    assert f.velocity[0] == pytest.approx(1.2, abs=0.25)
    assert abs(f.velocity[2]) < 0.25


def test_warm_start_is_the_last_fit_at_the_predicted_place_with_the_held_shape():
    tracker = Tracker(config(shape_frames=3))
    for frame in range(6):
        step(tracker, frame, [observation(1, 0.1 * frame)], shapes={0: (0.3,) * 6})
    warm = tracker.warm_start(1, 7 * NS).params  # two frames after the last
    last = tracker.track(1).last_fit
    assert warm.shape == pytest.approx(np.full(6, 0.3))
    moved = warm.transl - last.params.transl
    assert moved[0] == pytest.approx(0.2, abs=0.05), "walked on at ~1 m/s for 0.2 s"
    assert np.allclose(warm.pose, last.params.pose)
    assert tracker.warm_start(99, 7 * NS) is None
    assert pelvis(last)[0] == pytest.approx(0.5, abs=0.01)


@pytest.mark.bags
def test_a_tracked_person_half_hidden_keeps_their_own_points():
    """bags/crossing: person 2 (7 m) walks behind person 1 (5 m); past person 1's shoulder the LiDAR
    sees a wall 4 m behind person 2, which the extraction took for them while they were half hidden
    (four fits 3.5-4.1 m off, MPJPE over the first 12 frames 491 mm; over the first 8, 212 mm with
    `tracking.extraction_gate_m` off). The track's expected depth keeps them on their own points."""
    from smplify3d_ros.replay import replay_bag

    summary = replay_bag("bags/crossing", max_frames=8, progress=False)
    assert summary.people_evaluated >= 22
    assert summary.mpjpe_mm < 100.0, summary.mpjpe_mm


def test_a_person_fitted_from_the_image_who_regains_points_gets_the_cold_start():
    """A warm start from an image-only fit carries a guessed depth: when the points come back, the
    cold start (which measures the depth from them) fits the person, and warm starts follow."""
    from types import SimpleNamespace

    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFits, FrameFitter
    from smplify3d_ros.types import FLAG_IMAGE_ONLY

    class ImageOnlyWithoutPoints(StubFitter):
        def fit(self, people, K, origin, options=None):
            fits = super().fit(people, K, origin, options)
            return [dataclasses.replace(f, flags={FLAG_IMAGE_ONLY} if len(p.points) == 0 else set())
                    for f, p in zip(fits, people, strict=True)]

    cold, warm = ImageOnlyWithoutPoints(), ImageOnlyWithoutPoints()
    core = load_config()
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm)
    used = []
    for k, n_points in enumerate((0, 0, 50, 50)):
        frame = SimpleNamespace(stamp_ns=k * NS, camera=SimpleNamespace(K=np.eye(3)))
        people = path.tracker.assign([observation(3, 0.1 * k, n_points=n_points)], frame.stamp_ns)
        path.fit_observed(FrameFits(frame, people, [], np.zeros(3)))
        used.append("cold" if len(cold.calls) > sum(u == "cold" for u in used) else "warm")
    assert used == ["cold", "warm", "cold", "warm"]


def test_every_nth_frame_of_a_track_is_a_cold_start_with_the_warm_start_among_its_hypotheses():
    """A warm solve keeps whatever minimum it inherited (a wrong heading, say) and its residuals do not
    tell: every `refresh_frames` frames the cold start runs too, the warm start one of its hypotheses,
    and replaces the warm fit only with a clearly lower final loss."""
    from types import SimpleNamespace

    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFits, FrameFitter

    cold, warm = StubFitter(), StubFitter()
    core = load_config(overrides={"tracking": {"refresh_frames": 3}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm)
    for k in range(7):
        frame = SimpleNamespace(stamp_ns=k * NS, camera=SimpleNamespace(K=np.eye(3)))
        people = path.tracker.assign([observation(4, 0.1 * k)], frame.stamp_ns)
        path.fit_observed(FrameFits(frame, people, [], np.zeros(3)))
    assert len(cold.calls) == 3 and len(warm.calls) == 6  # cold: frames 0 (new), 3 and 6 (refresh)
    first, *refreshed = [call[0] for call in cold.calls]
    assert first.hypothesis is None and all(p.hypothesis is not None for p in refreshed)
    expected = path.tracker.track(4).motion.predicted(0.0)  # after the last update: where the hips are
    assert np.linalg.norm(refreshed[-1].hypothesis.transl - expected) < 0.2, "transl is the hip midpoint"
    fits = path.tracker.stats.fits
    assert fits["refresh"] == 2 and fits["refreshed"] == 0 and fits["warm"] == 6, "equal losses: warm kept"
    assert path.tracker.track(4).last_fit.flags == {"warm_start"}


def test_people_tracked_together_are_refreshed_in_turn():
    """Three tracks started in the same frame would all be refreshed in the same frames, each such frame
    as slow as fitting everyone cold: with `refresh_max_people` 1, one per frame, the longest waiting
    first, and every track still refreshed about every `refresh_frames` frames."""
    from types import SimpleNamespace

    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFits, FrameFitter

    cold, warm = StubFitter(), StubFitter()
    core = load_config(overrides={"tracking": {"refresh_frames": 3, "refresh_max_people": 1}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm)
    refreshed_per_frame = []
    for k in range(10):
        frame = SimpleNamespace(stamp_ns=k * NS, camera=SimpleNamespace(K=np.eye(3)))
        people = path.tracker.assign([observation(pid, 0.1 * k + pid) for pid in (1, 2, 3)], frame.stamp_ns)
        calls = len(cold.calls)
        path.fit_observed(FrameFits(frame, people, [], np.zeros(3)))
        refreshed_per_frame.append([p.person_id for call in cold.calls[calls:] for p in call])
    assert refreshed_per_frame[0] == [1, 2, 3]  # the new tracks
    assert all(len(ids) <= 1 for ids in refreshed_per_frame[1:]), refreshed_per_frame
    assert sorted(sum(refreshed_per_frame[3:6], [])) == [1, 2, 3], refreshed_per_frame


def test_a_warm_fit_that_lost_its_person_falls_back_to_the_cold_start():
    """A warm fit whose keypoints reproject far off (more than `lost_reprojection` of the box height) or
    whose points lie far from its mesh is thrown away and the person fitted cold, and counted as lost."""
    from types import SimpleNamespace

    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFits, FrameFitter

    class LosesThePerson(StubFitter):  # the warm solve: 1 px off, then 80 px (box 200 px tall), then 40 cm
        def fit(self, people, K, origin, options=None):
            fits = super().fit(people, K, origin, options)
            reprojection, off = ((1.0, 0.01), (80.0, 0.01), (1.0, 0.4))[min(len(self.calls) - 1, 2)]
            return [dataclasses.replace(f, quality=dataclasses.replace(f.quality, reprojection_px=reprojection,
                                                                       points_to_mesh_m=off)) for f in fits]

    cold, warm = StubFitter(), LosesThePerson()
    core = load_config(overrides={"tracking": {"refresh_frames": 0}})
    path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm)
    flags = []
    for k in range(4):
        frame = SimpleNamespace(stamp_ns=k * NS, camera=SimpleNamespace(K=np.eye(3)))
        people = path.tracker.assign([observation(2, 0.1 * k)], frame.stamp_ns)
        flags.append(sorted(path.fit_observed(FrameFits(frame, people, [], np.zeros(3))).fits[0].flags))
    assert len(warm.calls) == 3 and len(cold.calls) == 3  # frame 0 new; frames 2 and 3 lost
    assert flags == [[], ["warm_start"], [], []]
    assert path.tracker.stats.fits["lost"] == 2 and path.tracker.stats.fits["warm"] == 1
    # the warm solves and the lost person's cold fits know where the track expects them; a new track does not
    predicted = [[None if p.predicted_pelvis is None else p.predicted_pelvis.round(3).tolist() for p in call]
                 for call in cold.calls + warm.calls]
    assert predicted[0] == [None] and all(row[0] is not None for row in predicted[1:])
    assert all(np.allclose(c[0].predicted_pelvis, w[0].predicted_pelvis) for c, w in zip(cold.calls[1:],
                                                                                         warm.calls[1:]))


def test_a_person_seen_without_points_keeps_the_depth_their_points_had():
    """Someone 8 m out, behind a person at 4 m, is detected without points for a frame and then not at
    all; the person in front, whose box now covers where theirs was, keeps their own track: the hidden
    person's track still has the depth the LiDAR measured, 4 m behind."""
    tracker = Tracker(config())
    front = [observation(-1, 0.1 * k, z=4.0) for k in range(3)]
    behind = dataclasses.replace(observation(-1, 0.2, z=8.0), bbox=front[2].bbox.copy())
    ids = [f.person_id for f in step(tracker, 0, [front[0], observation(-1, 0.2, z=8.0)])]
    people = tracker.assign([front[1], dataclasses.replace(behind, points=np.zeros((0, 3), np.float32))], NS)
    tracker.update([fit_at(people[0].person_id, 0.1, 4.0), fit_at(people[1].person_id, 0.2, 8.0)], people, NS)
    assert [p.person_id for p in people] == ids
    assert step(tracker, 2, [front[2]])[0].person_id == ids[0]
    predicted = tracker.track(ids[1]).predicted_surface(2 * NS)
    assert predicted is not None and abs(predicted[2] - 8.0) < 0.3


def test_an_image_only_depth_barely_moves_the_velocity():
    """A fit from the image alone measures its depth to decimetres: a 25 cm jump along the camera ray
    from one frame to the next barely moves the velocity (when the LiDAR measured it, it moves it as
    much as the same jump sideways does)."""
    def after_jump(jump, depth_sigma):
        f = MotionFilter(accel_sigma=2.0, position_sigma=0.05)
        for _ in range(5):
            f.update(np.array([0.0, 0.0, 8.0]), 0.1)
        f.update(np.array([0.0, 0.0, 8.0]) + jump, 0.1, depth_sigma=depth_sigma)
        return f.velocity

    along = np.array([0.0, 0.0, 0.25])
    assert abs(after_jump(along, 0.5)[2]) < 0.05
    assert after_jump(along, None)[2] > 0.5
    assert after_jump(np.array([0.25, 0.0, 0.0]), 0.5)[0] > 0.5


def test_a_half_hidden_person_is_lost_by_their_size_in_the_image_not_their_box():
    """The keypoint box of a person half hidden behind someone spans their visible half; their keypoints
    are as noisy as a whole person's. The lost test measures reprojection against the taller of the box
    and the fit's joints projected."""
    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFitter

    core = load_config()
    path = FrameFitter(core, fitter=StubFitter(), tracker=Tracker(core.tracking), warm_fitter=StubFitter())
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    standing = np.zeros((17, 3), np.float32)
    standing[:, 1], standing[:, 2] = np.linspace(-0.9, 0.8, 17), 5.0  # 1.7 m tall at 5 m: 170 px
    obs = dataclasses.replace(observation(2, 0.0), bbox=np.array([300.0, 240.0, 330.0, 280.0]))  # 40 px
    fit = dataclasses.replace(fit_at(2, 0.0), keypoints3d=standing)
    assert not path._lost(dataclasses.replace(fit, quality=dataclasses.replace(fit.quality, reprojection_px=5.0)),
                          obs, K)
    assert path._lost(dataclasses.replace(fit, quality=dataclasses.replace(fit.quality, reprojection_px=20.0)),
                      obs, K)


def test_a_far_persons_warm_fit_is_not_lost_by_the_detectors_pixel_noise():
    """A person 40 px tall reprojecting 4 px off is within a detector's own noise (it does not shrink with
    the person): with `lost_reprojection_floor_px` the warm fit stands, without it it is refitted cold; a
    fit 15 px off is lost either way."""
    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFitter

    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    far = np.zeros((17, 3), np.float32)
    far[:, 1], far[:, 2] = np.linspace(-0.85, 0.85, 17), 21.25  # 1.7 m tall at 21.25 m: 40 px
    obs = dataclasses.replace(observation(2, 0.0), bbox=np.array([310.0, 220.0, 330.0, 260.0]))  # 40 px
    fit = dataclasses.replace(fit_at(2, 0.0), keypoints3d=far)

    def lost(floor_px: float, reprojection_px: float) -> bool:
        core = load_config(overrides={"tracking": {"lost_reprojection_floor_px": floor_px}})
        path = FrameFitter(core, fitter=StubFitter(), tracker=Tracker(core.tracking), warm_fitter=StubFitter())
        quality = dataclasses.replace(fit.quality, reprojection_px=reprojection_px, points_to_mesh_m=0.01)
        return path._lost(dataclasses.replace(fit, quality=quality), obs, K)

    assert lost(0.0, 4.0) and not lost(5.0, 4.0)  # 0.08 x 40 px = 3.2 px; with the floor hypot(3.2, 5) = 5.9 px
    assert lost(0.0, 15.0) and lost(5.0, 15.0)


def test_a_sparse_persons_warm_fit_is_not_lost_by_mesh_without_points_near_it():
    """A far or half-hidden person's points all lie on the warm fit's mesh while most of the visible mesh has
    no point near it (the symmetric chamfer is large): the fit keeps its person. Points 10 cm off it: lost."""
    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFitter

    core = load_config()
    path = FrameFitter(core, fitter=StubFitter(), tracker=Tracker(core.tracking), warm_fitter=StubFitter())
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])
    obs, fit = observation(2, 0.0), fit_at(2, 0.0)

    def lost(chamfer, off):
        quality = dataclasses.replace(fit.quality, reprojection_px=1.0, chamfer_m=chamfer, points_to_mesh_m=off)
        return path._lost(dataclasses.replace(fit, quality=quality), obs, K)

    assert not lost(chamfer=0.2, off=0.03)
    assert lost(chamfer=0.2, off=0.10)


def _body_facing(forward: np.ndarray, z: float = 5.0) -> np.ndarray:
    """(17, 3) COCO keypoints of a person at depth z facing `forward` (horizontal, camera frame: y down)."""
    from smplify3d_ros.keypoints import KP

    up = np.array([0.0, -1.0, 0.0])
    left = np.cross(up, forward)  # a person facing the camera (forward -z) has their left on the image's right
    kp = np.zeros((17, 3))
    for side, sign in (("left", 1.0), ("right", -1.0)):
        kp[KP[f"{side}_shoulder"]] = 0.2 * sign * left + 0.5 * up
        kp[KP[f"{side}_hip"]] = 0.12 * sign * left
        kp[KP[f"{side}_ear"]] = 0.07 * sign * left + 0.65 * up
        kp[KP[f"{side}_eye"]] = 0.03 * sign * left + 0.1 * forward + 0.68 * up
    kp[KP["nose"]] = 0.11 * forward + 0.66 * up
    return kp + np.array([0.0, 0.0, z])


def test_a_warm_fit_facing_away_from_the_detected_face_is_lost():
    """Seen side-on, a body and its mirror image (turned round) project almost alike but for the face: a
    warm fit whose torso faces one way across the image while the detected nose lies on the other side of
    the ears is lost. Seen from the front or the back (a detector's confident nose on someone turned
    away), the nose between the ears decides nothing; an unsure nose decides nothing either."""
    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFitter
    from smplify3d_ros.keypoints import KP

    core = load_config()
    path = FrameFitter(core, fitter=StubFitter(), tracker=Tracker(core.tracking), warm_fitter=StubFitter())
    K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])

    def detected(body: np.ndarray, nose_conf: float = 0.9) -> PersonObservation:
        uv = body[:, :2] / body[:, 2:] * 500.0 + [320.0, 240.0]
        kp = np.column_stack([uv, np.full(17, 0.9)])
        kp[KP["nose"], 2] = nose_conf
        return dataclasses.replace(observation(2, 0.0), keypoints=kp)

    def lost(fitted: np.ndarray, seen: PersonObservation) -> bool:
        fit = dataclasses.replace(fit_at(2, 0.0), keypoints3d=fitted.astype(np.float32))
        return path._lost(dataclasses.replace(fit, quality=dataclasses.replace(fit.quality, reprojection_px=1.0)),
                          seen, K)

    right, left, away = np.array([1.0, 0, 0]), np.array([-1.0, 0, 0]), np.array([0, 0, 1.0])
    assert not lost(_body_facing(right), detected(_body_facing(right)))
    assert lost(_body_facing(right), detected(_body_facing(left)))
    assert lost(_body_facing(left), detected(_body_facing(right)))
    assert not lost(_body_facing(right), detected(_body_facing(left), nose_conf=0.2))
    hallucinated = detected(_body_facing(away))
    hallucinated.keypoints[KP["nose"], 0] -= 8.0  # 8 px left of the ears, confidently
    assert not lost(_body_facing(away), hallucinated)
    core_off = load_config(overrides={"tracking": {"lost_face_offset_m": 0.0}})
    path = FrameFitter(core_off, fitter=StubFitter(), tracker=Tracker(core_off.tracking), warm_fitter=StubFitter())
    assert not lost(_body_facing(right), detected(_body_facing(left)))


def test_a_refresh_fits_cold_only_when_a_builtin_hypothesis_beats_the_warm_start():
    """With `refresh_compete_first` (off by default), a refresh first pits the warm start against the built-in heading
    hypotheses; where the warm start wins, the cold fit (which would go on from it) is not run."""
    from types import SimpleNamespace

    from node_support import StubFitter

    from smplify3d_ros.frame_fitter import FrameFits, FrameFitter

    class Competes(StubFitter):
        def __init__(self, verdicts):
            super().__init__()
            self.verdicts, self.competed = list(verdicts), []

        def given_hypothesis_wins(self, people, K, origin=None, options=None):
            self.competed.append(people)
            return [self.verdicts.pop(0) for _ in people]

    for verdicts, cold_calls in (([True, True], 1), ([False, True], 2)):
        cold, warm = Competes(verdicts), StubFitter()
        core = load_config(overrides={"tracking": {"refresh_frames": 3, "refresh_compete_first": True}})
        path = FrameFitter(core, fitter=cold, tracker=Tracker(core.tracking), warm_fitter=warm)
        for k in range(7):
            frame = SimpleNamespace(stamp_ns=k * NS, camera=SimpleNamespace(K=np.eye(3)))
            people = path.tracker.assign([observation(4, 0.1 * k)], frame.stamp_ns)
            path.fit_observed(FrameFits(frame, people, [], np.zeros(3)))
        assert len(cold.competed) == 2 and all(call[0].hypothesis is not None for call in cold.competed)
        assert len(cold.calls) == cold_calls, verdicts  # frame 0 (new) and the refreshes the warm start lost
        fits = path.tracker.stats.fits
        assert fits["refresh"] == 2 and fits["refresh_settled"] == sum(verdicts) and fits["warm"] == 6


def test_the_warm_start_competes_with_the_builtin_hypotheses_in_the_fitter():
    """`Fitter.given_hypothesis_wins` on a real fit: a person's own fit as their hypothesis beats the
    built-in hypotheses of their keypoints and points; a body turned round does not."""
    from scipy.spatial.transform import Rotation

    from smplify3d_ros.fitting.fitter import Fitter
    from smplify3d_ros.frame_fitter import FrameFitter
    from smplify3d_ros.sim.config import load_sim_config
    from smplify3d_ros.sim.world import simulate_scene

    core = load_config()
    sim = simulate_scene(3, load_sim_config(), sensor="vlp16", n_people=1, distance_range=(4.0, 5.0))
    fitter = Fitter(core.fitting)
    obs = [o for o in FrameFitter(core, fitter=fitter).observe(sim.frame).observations if len(o.points) >= 15][0]
    K = sim.frame.camera.K
    fit = fitter.fit([obs], K)[0]
    own = fit.params.copy()
    own.transl = np.asarray(fit.keypoints3d, np.float64)[[11, 12]].mean(axis=0)  # hypotheses place the hips
    turned = own.copy()
    turned.root_orient = (Rotation.from_euler("y", np.pi) * Rotation.from_rotvec(own.root_orient)).as_rotvec()
    wins = fitter.given_hypothesis_wins([dataclasses.replace(obs, hypothesis=h) for h in (own, turned)], K)
    assert wins == [True, False]
