"""Depth of people the LiDAR barely sees: image size cues, and points that belong to an occluder."""

import dataclasses

import numpy as np
import torch

from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, random_pose, sample_surface
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.fitting.init import (
    estimate_depth,
    few_points_depth,
    ground_depth,
    nearest_depth,
    pelvis_position,
    points_too_near,
    scan_depth_bound,
    size_depths,
    upright_root_orient,
)
from smplify3d_ros.fitting.losses import project
from smplify3d_ros.fitting.visibility import front_facing
from smplify3d_ros.keypoints import KP
from smplify3d_ros.types import FLAG_IMAGE_ONLY, FLAG_POINTS_TOO_NEAR, BodyParams, PersonObservation


def _seen_on_ground(model, distance=8.0):
    """An adult of the model's mean shape standing `distance` m out, every keypoint confident (0.5 px
    noise), their points on the front of the body, and the ground plane under their feet (level camera:
    up is −y, so the plane n·p + d = 0 has n = (0, −1, 0) and d = the ground's y)."""
    K = default_intrinsics()
    rng = np.random.default_rng(3)
    truth = BodyParams(model.name, model.mean_shape().cpu().double().numpy(),
                       random_pose(model, rng, 0.2), upright_root_orient(0.4),
                       np.array([0.6, -0.45, distance]))  # camera ~0.4 m above the floor (Jackal)
    body = model.posed([truth])[0]
    uv = project(torch.as_tensor(body.keypoints3d)[None], torch.as_tensor(K, dtype=torch.float64))[0].numpy()
    kp = np.concatenate([uv + 0.5 * rng.standard_normal(uv.shape), np.ones((len(uv), 1))], 1)
    faces = model.faces.cpu().numpy()
    front = front_facing(body.vertices, faces, np.zeros(3), 0.0)
    points = sample_surface(body.vertices, faces[front], 150, 0.01, rng).astype(np.float32)
    ankles_y = body.keypoints3d[[KP["left_ankle"], KP["right_ankle"]], 1]
    ground = np.array([0.0, -1.0, 0.0, float(ankles_y.max()) + load_config().fitting.init.ankle_height])
    bbox = np.array([*kp[:, :2].min(0), *kp[:, :2].max(0)])
    obs = PersonObservation(0, kp, bbox, points, ground=ground)
    return obs, body, K


def _person_on_ground(model, distance=8.0):
    """`_seen_on_ground`'s observation, the true root joint's position and the intrinsics."""
    obs, body, K = _seen_on_ground(model, distance)
    return obs, body.joints[0], K


def test_a_raised_foot_does_not_push_an_unseen_person_away(anny_model):
    """Without points, ground contact is one cue of three: a foot raised by a few pixels (a step, a
    detector's error) meets the ground metres farther at 8 m, and the nearest cue takes over."""
    cfg = load_config().fitting.init
    obs, pelvis, K = _person_on_ground(anny_model)
    obs = dataclasses.replace(obs, points=obs.points[:0])
    true_z = float(pelvis[2])
    assert abs(estimate_depth(obs, K, cfg, use_points=False) / true_z - 1) < 0.15
    raised = obs.keypoints.copy()
    raised[[KP["left_ankle"], KP["right_ankle"]], 1] -= 8.0  # both feet 8 px up: the lower still decides
    raised_obs = dataclasses.replace(obs, keypoints=raised)
    assert ground_depth(raised_obs, K, cfg) / true_z - 1 > 0.3  # ground contact alone is far off
    assert abs(estimate_depth(raised_obs, K, cfg, use_points=False) / true_z - 1) < 0.2


def test_a_person_whose_legs_are_hidden_starts_a_torso_below_the_shoulders(anny_model):
    """Hips, hands and legs hidden (behind a box): the keypoint box ends at the elbows. The start's pelvis
    goes a torso below the shoulders, with two shoulders seen or one, not into that box, which puts it
    at chest height (crowd tuning seed 4 person 3: 39 cm too high, fitted 351 mm off)."""
    cfg = load_config().fitting.init
    obs, body, K = _seen_on_ground(anny_model, distance=7.0)
    hips = body.keypoints3d[[KP["left_hip"], KP["right_hip"]]].mean(axis=0)
    kp = obs.keypoints.copy()
    hidden = [KP[n] for n in ("left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
                              "left_wrist", "right_wrist")]
    kp[hidden, 2] = 0.1
    seen = kp[:, 2] >= cfg.keypoint_conf
    pad = 0.12 * np.ptp(kp[seen, :2], axis=0).max()
    half = dataclasses.replace(obs, keypoints=kp, bbox=np.array([*(kp[seen, :2].min(0) - pad),
                                                                  *(kp[seen, :2].max(0) + pad)]))
    depth = float(hips[2])
    up = obs.ground[:3]
    assert np.linalg.norm(pelvis_position(half, K, cfg, depth, up) - hips) < 0.1
    one = half.keypoints.copy()
    one[KP["right_shoulder"], 2] = 0.0
    assert np.linalg.norm(pelvis_position(dataclasses.replace(half, keypoints=one), K, cfg, depth, up) - hips) < 0.15
    # the box's centre, where a start without shoulders goes, is a chest's height off
    none = one.copy()
    none[KP["left_shoulder"], 2] = 0.0
    assert np.linalg.norm(pelvis_position(dataclasses.replace(half, keypoints=none), K, cfg, depth, up) - hips) > 0.25


def test_arms_raised_above_the_head_do_not_bring_the_nearest_depth_closer(anny_model):
    """The nearest depth a person's points may lie at (half the whole-body cue, here the only one: no
    ground plane, the hips unsure) reads the span from the head to the ankles, not the keypoint box: wrists
    raised high above the head make the box taller, not the person. An object in front at half their
    depth is then still too near (Ouster-64 tuning seed 39: a box 25 % taller let one at 0.48 x pass)."""
    cfg = load_config().fitting.init
    obs, pelvis, K = _person_on_ground(anny_model, distance=5.4)
    kp = obs.keypoints.copy()
    kp[[KP["left_hip"], KP["right_hip"]], 2] = 0.1  # no torso cue
    obs = dataclasses.replace(obs, keypoints=kp, ground=None)
    raised = kp.copy()
    top = kp[:, 1].min()
    raised[[KP["left_wrist"], KP["right_wrist"]], 1] = top - 0.3 * (kp[:, 1].max() - top)  # hands up
    raised_obs = dataclasses.replace(obs, keypoints=raised,
                                     bbox=np.array([*raised[:, :2].min(0), *raised[:, :2].max(0)]))
    true_z = float(pelvis[2])
    bound = nearest_depth(obs, K, cfg)
    assert abs(bound / (cfg.points_min_depth_ratio * true_z) - 1) < 0.15
    assert nearest_depth(raised_obs, K, cfg) == bound
    # half their depth: the box's height would have let it pass (its bound: 0.46 x their depth)
    in_front = dataclasses.replace(raised_obs, points=_occluder_points(raised_obs, K, 0.5 * true_z))
    assert points_too_near(in_front, K, cfg)
    assert not points_too_near(raised_obs, K, cfg)  # their own points stay


def test_a_lone_ankle_in_the_air_is_no_bound_on_its_own(anny_model):
    """A walker 2.2 m out, their head and shoulders above the image and one foot out of it: the one ankle
    seen is the foot in the air, whose ray meets the ground twice as far from a low camera. Alone, that
    cue said the walker's own points were an occluder's (a camera pitched 15° down, tuning seed 0: 223
    points lost, fitted 228 mm off); beside another cue, the nearest of them still bounds."""
    cfg = load_config().fitting.init
    obs, pelvis, K = _person_on_ground(anny_model, distance=2.2)
    true_z = float(pelvis[2])
    kp = obs.keypoints.copy()
    hidden = [KP[n] for n in ("nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder",
                              "right_shoulder", "right_ankle")]
    kp[hidden, 2] = 0.0
    kp[KP["left_ankle"], 1] -= 0.15 * K[1, 1] / true_z  # the foot 15 cm up, mid-swing
    lone = dataclasses.replace(obs, keypoints=kp)
    # as a bound, that cue would put the walker's own points too near to be theirs
    assert cfg.points_min_depth_ratio * ground_depth(lone, K, cfg) > np.median(obs.points[:, 2])
    assert np.isnan(nearest_depth(lone, K, cfg))
    assert not points_too_near(lone, K, cfg)  # their own points stay theirs
    # with the torso seen too, the nearest cue bounds again; so does ground contact through both ankles
    torso = kp.copy()
    torso[[KP["left_shoulder"], KP["right_shoulder"]], 2] = 1.0
    assert nearest_depth(dataclasses.replace(obs, keypoints=torso), K, cfg) < true_z
    both = obs.keypoints.copy()
    both[hidden[:-1], 2] = 0.0
    assert nearest_depth(dataclasses.replace(obs, keypoints=both), K, cfg) < true_z


def _occluder_points(obs, K, depth, n=200, seed=0):
    """Points of a flat occluder at `depth` covering the lower two thirds of the person's box."""
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = obs.bbox
    u = rng.uniform(x0, x1, n)
    v = rng.uniform(y0 + (y1 - y0) / 3, y1, n)
    return np.column_stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth,
                            np.full(n, depth)]).astype(np.float32)


def test_an_occluders_points_are_not_taken_for_a_far_person(anny_model):
    """Points 2.5 m out for a person whose whole body shows 8 m out: no foreshortening shrinks every
    cue fourfold, so they are dropped (flag points_too_near) and the person is fitted from the image,
    near their true depth; with the check off (ratio 0) the fit stands on the occluder."""
    config = load_config().fitting
    obs, pelvis, K = _person_on_ground(anny_model)
    obs = dataclasses.replace(obs, points=_occluder_points(obs, K, 2.5))
    true_z = float(pelvis[2])
    assert points_too_near(obs, K, config.init)
    fit = Fitter(config, anny_model).fit([obs], K)[0]
    assert {FLAG_POINTS_TOO_NEAR, FLAG_IMAGE_ONLY} <= fit.flags
    assert abs(fit.joints[0, 2] / true_z - 1) < 0.2, fit.joints[0]
    off = dataclasses.replace(config, init=dataclasses.replace(config.init, points_min_depth_ratio=0.0))
    assert not points_too_near(obs, K, off.init)
    fit = Fitter(off, anny_model).fit([obs], K)[0]
    assert FLAG_POINTS_TOO_NEAR not in fit.flags
    assert fit.joints[0, 2] < 0.5 * true_z, fit.joints[0]


def test_the_scans_bound_holds_a_person_whose_size_cues_read_too_far(anny_model):
    """A person 8 m out without points whose keypoints read half their size (as a crouch with the hips
    hidden, or a mostly hidden body, does): every size cue puts them twice as far. The scan's returns
    along their keypoints' rays (`depth_bound`, here 1 m past them) bound the start and the fit; without
    the bound the fit stands near the size cues' 16 m. A bound nearer than the image allows
    (`nearest_depth`: an occluder's surface, the keypoints guessed on it) is refused."""
    config = load_config().fitting
    obs, pelvis, K = _person_on_ground(anny_model)
    true_z = float(pelvis[2])
    kp = obs.keypoints.copy()
    centre = kp[:, :2].mean(axis=0)
    kp[:, :2] = centre + 0.5 * (kp[:, :2] - centre)  # half the size in the image
    obs = dataclasses.replace(obs, keypoints=kp, bbox=np.array([*kp[:, :2].min(0), *kp[:, :2].max(0)]),
                              points=obs.points[:0], ground=None)
    assert min(size_depths(obs, K, config.init, whole_body=False)) > 1.7 * true_z
    free = Fitter(config, anny_model).fit([obs], K)[0]
    assert FLAG_IMAGE_ONLY in free.flags and free.joints[0, 2] > 1.5 * true_z, free.joints[0]
    bounded = dataclasses.replace(obs, depth_bound=true_z + 1.0)
    assert scan_depth_bound(bounded, K, config.init) == true_z + 1.0
    assert estimate_depth(bounded, K, config.init, use_points=False) == true_z + 1.0
    fit = Fitter(config, anny_model).fit([bounded], K)[0]
    assert fit.params.transl[2] <= true_z + 1.05, fit.params.transl
    occluder = dataclasses.replace(obs, depth_bound=0.3 * true_z)
    assert occluder.depth_bound < nearest_depth(occluder, K, config.init)
    assert scan_depth_bound(occluder, K, config.init) is None
    assert estimate_depth(occluder, K, config.init, use_points=False) > 1.7 * true_z


def test_a_persons_own_points_are_kept(anny_model):
    cfg = load_config().fitting.init
    obs, _, K = _person_on_ground(anny_model)
    assert len(obs.points) and not points_too_near(obs, K, cfg)


def test_one_size_cue_alone_may_drop_a_persons_own_points(anny_model):
    """Only the legs seen (the upper body's keypoints guessed, 0.1) and both ankles a few pixels too
    high (a foot lifted, or an ankle guessed behind something): ground contact, the one size cue left,
    puts the person more than twice as far as their own points. With `points_min_depth_cues` 1 those
    points are dropped as an occluder's (the default: on the tuning seeds a person 9.6 m out behind an
    object 2.5 m out had only this cue, and the object's points were the ones dropped); asking two
    cues for the bound keeps them."""
    cfg = load_config().fitting.init
    obs, _, K = _person_on_ground(anny_model)
    kp = obs.keypoints.copy()
    kp[:11, 2] = 0.1
    kp[[KP["left_ankle"], KP["right_ankle"]], 1] -= 9.0
    obs = dataclasses.replace(obs, keypoints=kp)
    assert ground_depth(obs, K, cfg) > 2.0 * float(np.median(obs.points[:, 2]))
    assert cfg.points_min_depth_cues == 1 and points_too_near(obs, K, cfg)
    assert not points_too_near(obs, K, dataclasses.replace(cfg, points_min_depth_cues=2))


def _upper_body_only(obs, keep_points):
    """The person with the lower body hidden: hips, knees and ankles guessed (confidence 0.1), the box
    around the rest, no ground plane, and only `keep_points` points."""
    kp = obs.keypoints.copy()
    kp[11:, 2] = 0.1
    seen = kp[:11, :2]
    return dataclasses.replace(obs, keypoints=kp, bbox=np.array([*seen.min(0), *seen.max(0)]), ground=None,
                               points=keep_points)


def test_a_few_points_the_image_agrees_with_give_a_half_hidden_persons_depth(anny_model):
    """Two points on the chest of a person 8 m out whose lower body is hidden (fewer than
    `min_points_depth`): the upper body's box alone puts them twice as far, and the points, nearer than
    that, give the depth, held by the fit. Two points of the background seen past the body, beyond every
    size cue, contradict the image: the box cue decides; 10 % beyond the nearest cue they do not
    (`few_points_max_ratio`: the cues' own noise). With `few_points_max_ratio` 0 the chest's points are
    ignored too."""
    config = load_config().fitting
    obs, pelvis, K = _person_on_ground(anny_model)
    true_z = float(pelvis[2])
    chest = obs.points[np.argsort(np.abs(obs.points[:, 1] - (pelvis[1] - 0.3)))[:2]]  # 30 cm above the pelvis
    assert len(chest) < config.min_points_depth
    hidden = _upper_body_only(obs, chest)
    assert abs(few_points_depth(hidden, K, config.init) / true_z - 1) < 0.05
    assert abs(estimate_depth(hidden, K, config.init, use_points=False) / true_z - 1) < 0.05
    fit = Fitter(config, anny_model).fit([hidden], K)[0]
    assert FLAG_IMAGE_ONLY in fit.flags
    assert abs(fit.joints[0, 2] / true_z - 1) < 0.05, (fit.joints[0], true_z)

    size_only = estimate_depth(dataclasses.replace(hidden, points=hidden.points[:0]), K, config.init, False)
    assert size_only / true_z - 1 > 0.3  # the counterfactual: the box of the upper body is far off
    wall = chest * np.float32(1.2 * size_only / true_z)  # along the same rays, beyond every size cue
    background = _upper_body_only(obs, wall)
    assert few_points_depth(background, K, config.init) is None
    assert estimate_depth(background, K, config.init, use_points=False) == size_only
    # a little beyond the nearest cue (10 %: its keypoint noise at that range) the points still decide
    beyond = _upper_body_only(obs, chest * np.float32(1.1 * size_only / true_z))
    assert abs(few_points_depth(beyond, K, config.init) / size_only - 1.1) < 0.05
    strict = dataclasses.replace(config.init, few_points_max_ratio=1.0)
    assert few_points_depth(beyond, K, strict) is None

    off = dataclasses.replace(config, init=dataclasses.replace(config.init, few_points_max_ratio=0.0))
    assert few_points_depth(hidden, K, off.init) is None
    fit = Fitter(off, anny_model).fit([hidden], K)[0]
    assert fit.joints[0, 2] / true_z - 1 > 0.3, (fit.joints[0], true_z)


def test_a_crouching_person_keeps_their_own_points():
    """A simulated crowd (outdoor_crowd seed 40, five people; the camera 0.4 m up): person 4 crouches 7.3 m
    out, and every size cue of a crouching body reads about twice as far (ground contact through an
    ankle 19.5 px below the horizon 16.4 m, the torso 14.6 m, the head-to-ankle span 17.3 m). Half the
    nearest, 8.2 m, took their 453 points at 6.6-7.3 m for an occluder's: none were extracted and the
    person was fitted from the image 5.5 m too far. Their keypoints show a thigh far shorter down the
    image than its shin, so no bound is set, and the points are theirs again."""
    from smplify3d_ros.frame_fitter import FrameFitter, extract_frame_people
    from smplify3d_ros.sim.config import load_sim_config
    from smplify3d_ros.sim.world import simulate_scenario

    config = load_config()
    sim = simulate_scenario(40, load_sim_config(), "outdoor_crowd", sensor="livox", n_people=5,
                            distance_range=(6.0, 15.0))
    frame, _ = FrameFitter(config, fitter=object()).select_people(sim.frame)  # selection needs no fitter
    k = list(frame.person_ids).index(4)
    own = np.flatnonzero(sim.point_labels == 4)
    assert len(own) > 400
    for ratio, keeps_own in ((0.0, False), (config.fitting.init.crouch_thigh_ratio, True)):
        init = dataclasses.replace(config.fitting.init, crouch_thigh_ratio=ratio)
        _, result = extract_frame_people(frame, config.lidar, None, init)
        taken = result.people[k].indices
        assert (len(taken) > 0.8 * len(own) and np.isin(taken, own).mean() > 0.95) == keeps_own, (ratio, len(taken))


def test_only_a_leg_whose_thigh_the_image_shortens_reads_as_crouched(anny_model):
    """A standing person's thighs are about as long down the image as their shins: the nearest-depth
    bound stays; a crouching leg (the knee raised to just below the hip) lifts it; an unsure hip, knee or
    ankle says nothing."""
    from smplify3d_ros.fitting.init import crouched

    cfg = load_config().fitting.init
    obs, _, K = _person_on_ground(anny_model, distance=7.0)
    assert not crouched(obs.keypoints, cfg.keypoint_conf, cfg.crouch_thigh_ratio)
    assert np.isfinite(nearest_depth(obs, K, cfg))
    kp = obs.keypoints.copy()
    hip, knee, ankle = (KP[f"left_{j}"] for j in ("hip", "knee", "ankle"))
    kp[knee, 1] = kp[hip, 1] + 0.2 * (kp[ankle, 1] - kp[hip, 1])
    assert crouched(kp, cfg.keypoint_conf, cfg.crouch_thigh_ratio)
    assert np.isnan(nearest_depth(dataclasses.replace(obs, keypoints=kp), K, cfg))
    unsure = kp.copy()
    unsure[knee, 2] = 0.1
    assert not crouched(unsure, cfg.keypoint_conf, cfg.crouch_thigh_ratio)
