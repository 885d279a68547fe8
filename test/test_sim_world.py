"""Scene generation: determinism, the SimFrame contract, geometry consistency, speed, sequences."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from smplify3d_ros.camera import transform_points
from smplify3d_ros.sim.config import default_sim_config
from smplify3d_ros.sim.lidar import simulate_scan
from smplify3d_ros.sim.raycast import LABEL_GROUND, LABEL_STATIC
from smplify3d_ros.sim.scene import make_mount
from smplify3d_ros.sim.world import (
    SimFrame,
    _load_model,
    assemble,
    random_people,
    simulate_scene,
    simulate_sequence,
    static_objects,
)


@pytest.fixture(scope="module")
def sim_cfg():
    return default_sim_config()


@pytest.fixture(scope="module")
def frame(anny_model, sim_cfg) -> SimFrame:
    return simulate_scene(11, sim_cfg, n_people=4, distance_range=(2.0, 8.0))


def test_same_seed_same_scene(anny_model, sim_cfg, frame):
    again = simulate_scene(11, sim_cfg, n_people=4, distance_range=(2.0, 8.0))
    np.testing.assert_array_equal(again.frame.points_lidar, frame.frame.points_lidar)
    np.testing.assert_array_equal(again.frame.keypoints, frame.frame.keypoints)
    np.testing.assert_array_equal(again.frame.image, frame.frame.image)
    np.testing.assert_array_equal(again.point_labels, frame.point_labels)
    for a, b in zip(again.people, frame.people):
        np.testing.assert_array_equal(a.vertices, b.vertices)
    for pid in frame.hmr_init:
        np.testing.assert_array_equal(again.hmr_init[pid].transl, frame.hmr_init[pid].transl)
    other = simulate_scene(12, sim_cfg, n_people=4, distance_range=(2.0, 8.0))
    assert not np.array_equal(other.frame.image, frame.frame.image)


def test_frame_contract(frame, sim_cfg):
    fr = frame.frame
    H, W = sim_cfg.camera.height, sim_cfg.camera.width
    assert fr.image.shape == (H, W, 3) and fr.image.dtype == np.uint8
    assert fr.camera.width == W and fr.camera.distortion_model == sim_cfg.camera.distortion_model
    assert fr.points_lidar.dtype == np.float32 and fr.points_lidar.shape[1] == 3
    assert fr.keypoints.shape == (len(fr.person_ids), 17, 3) and fr.person_ids.dtype == np.int64
    assert frame.point_labels.dtype == np.int32 and len(frame.point_labels) == len(fr.points_lidar)
    assert frame.lidar_fields["ring"].dtype == np.uint16
    assert (
        frame.lidar_fields["time"].dtype == np.float32 and frame.lidar_fields["intensity"].dtype == np.float32
    )
    assert frame.mask.shape == (H, W) and frame.mask.dtype == np.int32
    ids = {p.person_id for p in frame.people}
    assert len(ids) == 4 and set(frame.visible_fraction) == ids
    assert set(fr.person_ids.tolist()) <= ids and set(frame.hmr_init) == set(fr.person_ids.tolist())
    assert set(np.unique(frame.mask)) <= ids | {-1}
    for p in frame.people:
        assert p.vertices.dtype == np.float32 and p.keypoints3d.shape == (17, 3) and p.joints.shape == (19, 3)


def test_geometry_is_consistent(frame, sim_cfg):
    fr = frame.frame
    mount = make_mount(sim_cfg.mount)
    np.testing.assert_allclose(fr.T_cam_lidar, mount.T_cam_lidar)
    # the LiDAR sits 0.15 m above (camera -y) and 0.10 m behind (camera -z) the camera
    np.testing.assert_allclose(fr.T_cam_lidar[:3, 3], [0.0, -0.15, -0.10], atol=1e-9)
    points_cam = transform_points(fr.points_lidar, fr.T_cam_lidar).astype(np.float64)
    points_world = transform_points(points_cam, mount.T_world_cam)
    ground = frame.point_labels == LABEL_GROUND
    assert np.abs(points_world[ground, 2]).max() < 0.15  # range noise 2 cm, grazing angles
    for p in frame.people:
        world = transform_points(p.vertices.astype(np.float64), mount.T_world_cam)
        assert abs(world[:, 2].min()) < 1e-3  # feet on the ground
        mine = frame.point_labels == p.person_id
        if mine.any():  # the person's points lie on their mesh (up to noise)
            d, _ = cKDTree(p.vertices).query(points_cam[mine])
            assert np.median(d) < 0.04
    assert (frame.point_labels == LABEL_STATIC).any()


def test_keypoints_match_projected_ground_truth(frame):
    from smplify3d_ros.camera import project_points

    fr = frame.frame
    people = {p.person_id: p for p in frame.people}
    for kp, pid in zip(fr.keypoints, fr.person_ids):
        truth = project_points(people[int(pid)].keypoints3d, fr.camera)
        good = kp[:, 2] > 0.6
        err = np.linalg.norm(kp[good, :2] - truth[good], axis=1)
        assert np.median(err) < 15.0


def test_mask_and_visible_fraction_agree(frame):
    for pid, fraction in frame.visible_fraction.items():
        assert 0.0 <= fraction <= 1.0
        if fraction == 0.0:
            assert not (frame.mask == pid).any()


def test_full_vlp16_scan_of_a_five_person_scene(anny_model, sim_cfg):
    # (speed is reported by benchmarks, never asserted in tests)
    rng = np.random.default_rng(0)
    mount, people = random_people(rng, sim_cfg, anny_model, 5, (1.5, 20.0))
    objects = static_objects(rng, sim_cfg, anny_model, mount, people, walls=True)
    scene = assemble(rng, anny_model, mount, people, objects, sim_cfg.render)
    scan = simulate_scan(
        scene.ray_scene, mount.T_cam_lidar, sim_cfg.lidar.sensors["vlp16"], sim_cfg.lidar.intensity, rng
    )
    assert 0.5 * 28928 < len(scan.points) <= 28928  # walls all around; some beams pass over them
    assert set(np.unique(scan.label)) >= {-1, -2}  # ground and walls are hit


def test_sequences_move_people_and_keep_ids(anny_model, sim_cfg):
    frames = list(simulate_sequence(4, sim_cfg, "crossing", n_frames=3, rate_hz=10.0))
    assert [f.frame.stamp_ns for f in frames] == [0, 100_000_000, 200_000_000]
    ids = [sorted(p.person_id for p in f.people) for f in frames]
    assert ids[0] == ids[1] == ids[2] and 2 <= len(ids[0]) <= 3
    a, b = frames[0].people[0], frames[1].people[0]
    step = np.linalg.norm(b.params.transl - a.params.transl)
    assert 0.05 < step < 0.25  # walking speed 0.9 to 1.5 m/s at 10 Hz
    np.testing.assert_array_equal(a.params.shape, b.params.shape)
    with pytest.raises(ValueError):
        next(simulate_sequence(0, sim_cfg, "nope", 1))


def test_close_scenario_cuts_the_body(anny_model, sim_cfg):
    frame = next(simulate_sequence(2, sim_cfg, "close", n_frames=1))
    assert len(frame.people) == 1
    assert frame.visible_fraction[0] < 0.95  # partly out of the frame


def test_model_is_cached(sim_cfg):
    assert _load_model(sim_cfg) is _load_model(sim_cfg)
