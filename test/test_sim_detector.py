"""Statistics of the 2D keypoint detector model on rendered scenes."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smplify3d_ros.camera import project_points
from smplify3d_ros.keypoints import KP
from smplify3d_ros.sim.camera import make_camera, render, visible_fraction
from smplify3d_ros.sim.config import default_sim_config
from smplify3d_ros.sim.detector import SWAP_GROUPS, detect_person
from smplify3d_ros.sim.people import preset_shape
from smplify3d_ros.sim.poses import sample_pose
from smplify3d_ros.sim.scene import (
    PersonPlacement,
    assemble,
    box_object,
    ground_plane,
    make_mount,
    pose_people,
)


@pytest.fixture(scope="module")
def sim_cfg():
    return default_sim_config()


def _scene(model, cfg, distance=4.0, bearing_deg=0.0, heading=np.pi, objects=()):
    mount = make_mount(cfg.mount)
    b = np.deg2rad(bearing_deg)
    pose = sample_pose(model, "standing", np.random.default_rng(0), variation_scale=0.0)
    shape = preset_shape("adult_male", model.shape_names)
    placement = PersonPlacement(
        0, "adult_male", shape, pose, distance * np.array([np.cos(b), np.sin(b)]), heading
    )
    people = pose_people(model, [placement], mount)
    scene = assemble(
        np.random.default_rng(0),
        model,
        mount,
        people,
        [ground_plane(cfg.scene.ground_half_size_m), *objects],
        cfg.render,
    )
    camera = make_camera(cfg.camera)
    return scene, camera, render(scene.ray_scene, camera, scene.face_colors, cfg.render, mount.T_world_cam)


def _draws(cfg, scene, camera, rendering, n, det_cfg=None):
    det_cfg = det_cfg or cfg.detector
    person = scene.people[0]
    rng = np.random.default_rng(42)
    return [
        detect_person(rng, 0, person.keypoints3d, person.vertices, rendering, camera, det_cfg)
        for _ in range(n)
    ]


def test_pixel_noise_matches_the_model(anny_model, sim_cfg):
    det_cfg = dataclasses.replace(sim_cfg.detector, swap_prob=0.0, missing_prob=0.0)
    scene, camera, rendering = _scene(anny_model, sim_cfg)
    draws = _draws(sim_cfg, scene, camera, rendering, 300, det_cfg)
    truth = project_points(scene.people[0].keypoints3d, camera)
    visible = draws[0].visibility.visible > 0.99
    assert visible.sum() >= 12  # a standing person facing the camera: body joints visible
    residual = np.stack([d.keypoints[:, :2] - truth for d in draws])  # (n, 17, 2)
    normalized = residual[:, visible] / draws[0].sigma_px[visible][None, :, None]
    assert abs(normalized.std() - 1.0) < 0.05
    assert abs(normalized.mean()) < 0.05
    # sigma follows the model: relative to the image height, larger for the hips than for the eyes
    sigma = draws[0].sigma_px
    assert sigma[KP["left_hip"]] > 3 * sigma[KP["left_eye"]]
    height_px = np.ptp(project_points(scene.people[0].vertices, camera, distort=False)[:, 1])
    rel = det_cfg.sigma_rel_base + det_cfg.sigma_rel_per_m * 4.0
    mean_sigma = np.sqrt(np.mean(sigma[visible] ** 2 - det_cfg.sigma_px_floor**2))
    assert mean_sigma == pytest.approx(rel * height_px, rel=0.35)


def test_far_people_have_larger_relative_noise_and_lower_scores(anny_model, sim_cfg):
    near = _draws(sim_cfg, *_scene(anny_model, sim_cfg, distance=3.0), 60)
    far = _draws(sim_cfg, *_scene(anny_model, sim_cfg, distance=15.0), 60)
    # relative to the 3.0 / 15.0 image-size ratio, far pixel noise is larger
    assert far[0].sigma_px.mean() * 15.0 / 3.0 > 1.5 * near[0].sigma_px.mean()
    near_score = np.mean([d.keypoints[:, 2].mean() for d in near])
    far_score = np.mean([d.keypoints[:, 2].mean() for d in far])
    assert near_score - far_score == pytest.approx(sim_cfg.detector.score_drop_per_m * 12.0, abs=0.03)


def test_scores_of_visible_and_occluded_joints(anny_model, sim_cfg):
    det_cfg = dataclasses.replace(sim_cfg.detector, swap_prob=0.0, missing_prob=0.0, score_drop_per_m=0.0)
    # a 0.6 m high box 1.5 m in front of the person hides the legs from the camera 0.4 m above ground
    box = box_object("box", np.array([2.5, 0.0, 0.3]), np.array([0.4, 1.2, 0.6]))
    scene, camera, rendering = _scene(anny_model, sim_cfg, objects=[box])
    draws = _draws(sim_cfg, scene, camera, rendering, 200, det_cfg)
    vis = draws[0].visibility
    legs = [KP[n] for n in ("left_knee", "right_knee", "left_ankle", "right_ankle")]
    upper = [KP[n] for n in ("nose", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow")]
    assert np.all(vis.occluded[legs] > 0.99)
    assert np.all(vis.visible[upper] > 0.99)
    scores = np.stack([d.keypoints[:, 2] for d in draws])
    assert scores[:, upper].mean() == pytest.approx(det_cfg.score_visible[0], abs=0.02)
    assert scores[:, upper].std() == pytest.approx(det_cfg.score_visible[1], abs=0.015)
    assert scores[:, legs].mean() == pytest.approx(det_cfg.score_occluded[0], abs=0.03)
    # occluded joints are guessed with more pixel noise
    assert np.all(draws[0].sigma_px[legs] > 2.0 * draws[0].sigma_px[[KP["left_hip"]]])


def test_back_view_self_occludes_the_face(anny_model, sim_cfg):
    det_cfg = dataclasses.replace(sim_cfg.detector, swap_prob=0.0, missing_prob=0.0, score_drop_per_m=0.0)
    scene, camera, rendering = _scene(anny_model, sim_cfg, heading=0.0)  # facing away from the robot
    draws = _draws(sim_cfg, scene, camera, rendering, 100, det_cfg)
    vis = draws[0].visibility
    face = [KP[n] for n in ("nose", "left_eye", "right_eye")]
    assert vis.self_occluded[KP["nose"]] > 0.99
    assert np.all(vis.self_occluded[face] > 0.5) and np.all(vis.occluded[face] == 0.0)
    scores = np.stack([d.keypoints[:, 2] for d in draws])
    expected = (
        vis.self_occluded[face] * det_cfg.score_self_occluded[0]
        + vis.visible[face] * det_cfg.score_visible[0]
    )
    np.testing.assert_allclose(scores[:, face].mean(axis=0), expected, atol=0.04)
    assert scores[:, face].mean() < det_cfg.score_visible[0] - 0.2


def test_swaps_and_missing_joints_happen_at_their_rates(anny_model, sim_cfg):
    det_cfg = dataclasses.replace(sim_cfg.detector, swap_prob=0.25, missing_prob=0.1)
    scene, camera, rendering = _scene(anny_model, sim_cfg)
    draws = _draws(sim_cfg, scene, camera, rendering, 400, det_cfg)
    swaps = np.mean([len(d.swapped) for d in draws]) / len(SWAP_GROUPS)
    assert swaps == pytest.approx(0.25, abs=0.04)
    zero = np.mean([np.mean(d.keypoints[:, 2] == 0.0) for d in draws])
    assert zero == pytest.approx(0.1, abs=0.02)
    # a swapped leg: the left knee lands near the true right knee
    truth = project_points(scene.people[0].keypoints3d, camera)
    d = next(d for d in draws if len(SWAP_GROUPS) - 1 in d.swapped)
    err_swapped = np.linalg.norm(d.keypoints[KP["left_knee"], :2] - truth[KP["right_knee"]])
    assert err_swapped < np.linalg.norm(truth[KP["left_knee"]] - truth[KP["right_knee"]])


def test_out_of_image_joints_have_score_zero(anny_model, sim_cfg):
    # 1.6 m away near the image edge: the head is above the image, the right side beyond it
    scene, camera, rendering = _scene(anny_model, sim_cfg, distance=1.6, bearing_deg=-38.0)
    draws = _draws(sim_cfg, scene, camera, rendering, 20)
    truth = project_points(scene.people[0].keypoints3d, camera)
    outside = ~(
        (truth[:, 0] >= 0)
        & (truth[:, 0] <= camera.width - 1)
        & (truth[:, 1] >= 0)
        & (truth[:, 1] <= camera.height - 1)
    )
    assert outside.any() and (~outside).any()
    for d in draws:
        assert np.all(d.keypoints[outside, 2] == 0.0)
    person = scene.people[0]
    fraction = visible_fraction(scene.ray_scene, camera, 0, person.vertices, sim_cfg.render.visibility_rays)
    assert 0.05 < fraction < 0.9


def test_undetected_when_too_little_is_visible(anny_model, sim_cfg):
    wall = box_object("box", np.array([2.0, 0.0, 1.5]), np.array([0.2, 4.0, 3.0]))
    scene, camera, rendering = _scene(anny_model, sim_cfg, objects=[wall])
    person = scene.people[0]
    assert (
        detect_person(
            np.random.default_rng(0),
            0,
            person.keypoints3d,
            person.vertices,
            rendering,
            camera,
            sim_cfg.detector,
        )
        is None
    )
    assert (
        visible_fraction(scene.ray_scene, camera, 0, person.vertices, sim_cfg.render.visibility_rays) == 0.0
    )
