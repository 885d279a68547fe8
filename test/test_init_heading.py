"""The built-in initializer from any viewpoint, and fits that do not depend on the camera's resolution."""

import dataclasses

import numpy as np
from scipy.spatial.transform import Rotation

from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, make_person
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.fitting.heading import estimate_heading, hypotheses


def _facing(root_orient: np.ndarray) -> np.ndarray:
    """The body's forward direction in the camera's horizontal plane (level camera: up = −y)."""
    forward = Rotation.from_rotvec(root_orient).as_matrix()[:, 2]
    forward[1] = 0.0
    return forward / np.linalg.norm(forward)


def _heading_error_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(_facing(a) @ _facing(b), -1.0, 1.0))))


def _person(model, yaw, seed=0, distance=5.0, K=None):
    rng = np.random.default_rng(seed)
    K = default_intrinsics() if K is None else K
    person = make_person(model, rng, K, distance=distance, yaw=yaw, n_points=150, point_noise=0.01,
                         keypoint_noise_px=1.5)
    # every keypoint confident, the face too: what ViTPose-class detectors report for people seen from
    # behind (0.85-0.98 on the nose), so that a confident face cannot be what says "facing the camera"
    assert (person.observation.keypoints[:, 2] >= 0.9).all()
    return person, K


def test_people_facing_away_are_fitted_facing_away(anny_model):
    """Back views at three headings, four random people each, every face keypoint confident."""
    fitter = Fitter(load_config().fitting, anny_model)
    people = [_person(anny_model, yaw, seed=seed)[0] for seed in range(4) for yaw in (np.pi, np.pi - 0.6, -np.pi + 0.9)]
    fits = fitter.fit([p.observation for p in people], default_intrinsics())  # one batch, as in a crowd
    errors = [_heading_error_deg(f.params.root_orient, p.truth.root_orient) for f, p in zip(fits, people, strict=True)]
    print("heading errors (deg):", np.round(errors, 1))
    assert np.median(errors) < 10.0
    assert np.sum(np.array(errors) < 25.0) >= 10  # of 12


def test_heading_hypotheses_contain_the_truth_for_front_and_back_views(anny_model):
    cfg = load_config().fitting.init
    for yaw in (0.3, np.pi - 0.3, -2.2):
        person, K = _person(anny_model, yaw, seed=1)
        pelvis = np.asarray(person.truth.transl)
        heading = estimate_heading(person.observation.keypoints, K, pelvis, person.observation.points, cfg)
        errors = [_heading_error_deg(_yaw_rotvec(h), person.truth.root_orient)
                  for h in heading.hypotheses]
        assert min(errors) < 25.0, (yaw, errors)
        assert errors[0] < 40.0, (yaw, errors)  # the first, the fused estimate, is already close


def test_merged_heading_hypotheses_make_room_for_the_side_views():
    """A facing (or back, or side-on) estimate is its own mirror: the four readings merge into two opposite
    headings, and a person the foreshortening misread (a kneeling person side-on whose hips spread in the
    image) would have no hypothesis within 90 degrees; the freed slots go to the widest gaps."""
    merge = np.deg2rad(20.0)
    for estimate in (0.0, np.pi, np.pi / 2, 0.1):
        out = hypotheses(estimate, merge, 4)
        assert len(out) == 4 and np.isclose(np.cos(out[0] - estimate), 1.0)
        ring = np.sort(np.mod(out, 2 * np.pi))
        gaps = np.diff(np.r_[ring, ring[0] + 2 * np.pi])
        assert np.degrees(gaps.max()) <= 100.0, (estimate, np.degrees(out))
    spread = hypotheses(0.8, merge, 4)  # four distinct readings: nothing added
    assert np.allclose(spread, [0.8, -0.8, 0.8 - np.pi, np.pi - 0.8])
    assert len(hypotheses(0.0, merge, 2)) == 2


def _yaw_rotvec(yaw: float) -> np.ndarray:
    from smplify3d_ros.fitting.init import upright_root_orient

    return upright_root_orient(yaw)


def _scaled_camera(person, factor: float, width: int, height: int):
    """The same person seen by a camera `factor` times the resolution (same field of view): keypoints,
    their noise and the box scale with it; the LiDAR points do not change."""
    K = default_intrinsics(width, height)
    K0 = default_intrinsics()
    obs = person.observation
    kp = obs.keypoints.copy()
    kp[:, :2] = (kp[:, :2] - K0[:2, 2]) * factor + K[:2, 2]
    bbox = ((obs.bbox.reshape(2, 2) - K0[:2, 2]) * factor + K[:2, 2]).ravel()
    return dataclasses.replace(obs, keypoints=kp, bbox=bbox), K


def test_a_2048_px_camera_fits_as_well_as_a_640_px_one(anny_model):
    fitter = Fitter(load_config().fitting, anny_model)
    person, K = _person(anny_model, 0.5, seed=7)
    small = fitter.fit([person.observation], K)[0]
    obs, K_big = _scaled_camera(person, 3.2, 2048, 1536)
    big = fitter.fit([obs], K_big)[0]
    small_err = 1000 * np.linalg.norm(small.joints - person.joints, axis=1).mean()
    big_err = 1000 * np.linalg.norm(big.joints - person.joints, axis=1).mean()
    between = 1000 * np.linalg.norm(small.joints - big.joints, axis=1).mean()
    print(f"MPJPE 640 px {small_err:.1f} mm, 2048 px {big_err:.1f} mm, between them {between:.1f} mm")
    assert between < 10.0
    assert big_err < small_err + 5.0
    assert abs(big.quality.reprojection_px / 3.2 - small.quality.reprojection_px) < 1.0


def test_shapes_stay_in_range_for_a_body_no_phenotype_reaches(anny_model):
    """Keypoints of a person 35 % larger than Anny's tallest, in a 2048 px image with raw pixel residuals
    (the setting in which the old penalty let phenotypes leave [0, 1])."""
    config = load_config(overrides={"fitting": {"profiles": {"robot": {"pixel_reference_px": 0.0}}}})
    fitter = Fitter(config.fitting, anny_model)
    person, _ = _person(anny_model, 0.2, seed=11)
    obs, K = _scaled_camera(person, 3.2, 2048, 1536)
    hips = obs.keypoints[[11, 12], :2].mean(0)
    obs.keypoints[:, :2] = hips + 1.35 * (obs.keypoints[:, :2] - hips)
    fit = fitter.fit([obs], K)[0]
    assert np.all((fit.params.shape >= 0.0) & (fit.params.shape <= 1.0))
    assert np.isfinite(fit.vertices).all()
