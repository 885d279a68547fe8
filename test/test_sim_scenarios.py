"""The bench's scenes: the non-repetitive (Livox-like) LiDAR, the new pose families' props, joint-limit
variation, people turned away from the camera, and the scenarios of `sim.bench`."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smplify3d_ros.eval.bench.methods import heading_to_camera_deg
from smplify3d_ros.keypoints import PART_INDEX
from smplify3d_ros.settings import ConfigError, base_values, from_dict
from smplify3d_ros.sim.config import SimConfig, default_sim_config, scenario_sim_config
from smplify3d_ros.sim.lidar import scan_pattern, simulate_scan
from smplify3d_ros.sim.poses import _axes_of, sample_pose
from smplify3d_ros.sim.raycast import LABEL_STATIC, RayScene
from smplify3d_ros.sim.scene import (
    PersonPlacement,
    _vertex_parts,
    footprint,
    make_mount,
    pose_people,
    prop_objects,
    turn_person,
    vertices_world,
)
from smplify3d_ros.sim.world import simulate_scenario


@pytest.fixture(scope="module")
def sim_cfg():
    return default_sim_config()


def _livox(sim_cfg, **changes):
    return dataclasses.replace(sim_cfg.lidar.non_repetitive["livox"], **changes)


def _wall(x: float) -> RayScene:
    v = np.array([[x, -500, -500], [x, 500, -500], [x, 500, 500], [x, -500, 500.0]])
    return RayScene.from_parts([(v, np.array([[0, 1, 2], [0, 2, 3]]), LABEL_STATIC)])


# -- the non-repetitive LiDAR ------------------------------------------------------------------------------
@pytest.mark.parametrize("pattern", ["rosette", "random"])
def test_non_repetitive_frames_fill_the_field_of_view_and_never_repeat(sim_cfg, pattern):
    sensor = _livox(sim_cfg, pattern=pattern)
    a = scan_pattern(sensor, np.random.default_rng(0))
    b = scan_pattern(sensor, np.random.default_rng(1))
    n = round(sensor.points_per_second / sensor.rate_hz)
    assert len(a.time) == n == a.columns
    az, el = np.rad2deg(a.azimuth), np.rad2deg(a.elevation)
    assert np.all(np.abs(az) <= sensor.hfov_deg / 2 + 1e-9) and np.all(np.abs(el) <= sensor.vfov_deg / 2 + 1e-9)
    assert np.ptp(az) > 0.95 * sensor.hfov_deg and np.ptp(el) > 0.95 * sensor.vfov_deg
    # no rings: elevations take thousands of distinct values (a VLP-16 has 16)
    assert len(np.unique(np.round(el, 2))) > 1000
    assert not np.allclose(a.azimuth, b.azimuth)  # the next frame lights other directions
    assert set(np.unique(a.ring)) == set(range(sensor.lines))  # the "line" field
    assert np.all(np.diff(a.time) > 0) and a.time[-1] < 1.0 / sensor.rate_hz
    # every part of the central field is lit: no 1 x 1 deg cell of the inner half is empty
    cells = np.zeros((18, 8), dtype=int)
    inner = (np.abs(az) < sensor.hfov_deg / 4) & (np.abs(el) < sensor.vfov_deg / 4)
    ix = ((az[inner] + sensor.hfov_deg / 4) / (sensor.hfov_deg / 2) * 18).astype(int).clip(0, 17)
    iy = ((el[inner] + sensor.vfov_deg / 4) / (sensor.vfov_deg / 2) * 8).astype(int).clip(0, 7)
    np.add.at(cells, (ix, iy), 1)
    assert cells.min() > 0


def test_non_repetitive_ranges_are_exact_and_noisy_as_configured(sim_cfg):
    clean = _livox(sim_cfg, range_noise_m=0.0, angular_noise_deg=0.0, dropout=0.0)
    scan = simulate_scan(_wall(10.0), np.eye(4), clean, sim_cfg.lidar.intensity, np.random.default_rng(0))
    assert len(scan.points) == round(clean.points_per_second / clean.rate_hz)  # the wall fills the view
    np.testing.assert_allclose(scan.points[:, 0], 10.0, atol=1e-4)
    noisy = _livox(sim_cfg, angular_noise_deg=0.0)
    scan = simulate_scan(_wall(10.0), np.eye(4), noisy, sim_cfg.lidar.intensity, np.random.default_rng(0))
    p = scan.points.astype(np.float64)
    error = np.linalg.norm(p, axis=1) - 10.0 * np.linalg.norm(p, axis=1) / p[:, 0]
    assert abs(error.std() / noisy.range_noise_m - 1.0) < 0.05
    kept = len(p) / round(noisy.points_per_second / noisy.rate_hz)
    assert abs((1 - kept) - noisy.dropout) < 0.01


def test_a_sensor_name_is_unique_across_kinds(sim_cfg):
    values = base_values()["sim"]
    values["lidar"]["non_repetitive"]["vlp16"] = values["lidar"]["non_repetitive"]["livox"]
    with pytest.raises(ConfigError, match="already named"):
        from_dict(SimConfig, values, "sim")
    with pytest.raises(ValueError, match="unknown LiDAR sensor 'hdl64'"):
        sim_cfg.lidar.sensor("hdl64")


# -- people ------------------------------------------------------------------------------------------------
def _posed(model, family, seed, heading=np.pi):
    mount = make_mount(default_sim_config().mount)
    shape = np.full(len(model.shape_names), 0.5)
    pose = sample_pose(model, family, np.random.default_rng(seed))
    return mount, pose_people(model, [PersonPlacement(0, "", shape, pose, np.array([5.0, 0.0]), heading)], mount)[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_stepping_up_stands_on_a_step_and_leaning_touches_a_post(anny_model, sim_cfg, seed):
    mount, person = _posed(anny_model, "stepping_up", seed)
    (step,) = prop_objects(person, anny_model, mount, sim_cfg.scene)
    verts = vertices_world(person, mount)
    foot = verts[_vertex_parts(anny_model) == PART_INDEX[f"{person.placement.pose.side}_lower_leg"]]
    top = step.vertices[:, 2].max()
    assert 0.1 < top < 0.6 and top == pytest.approx(foot[:, 2].min())  # the raised foot rests on it
    lo, hi = step.vertices[:, :2].min(0), step.vertices[:, :2].max(0)
    sole = foot[foot[:, 2] < top + 0.02]
    assert np.all((sole[:, :2] > lo - 0.02) & (sole[:, :2] < hi + 0.02))
    mount, person = _posed(anny_model, "leaning", seed)
    (post,) = prop_objects(person, anny_model, mount, sim_cfg.scene)
    verts = vertices_world(person, mount)
    axis = post.vertices[:, :2].mean(0)
    gap = np.linalg.norm(verts[verts[:, 2] > 0.9][:, :2] - axis, axis=1).min() - sim_cfg.scene.post_radius_m
    assert abs(gap) < 0.02  # the back rests on the post, not in it
    forward = np.array([np.cos(np.pi), np.sin(np.pi)])
    assert (axis - verts[:, :2].mean(0)) @ forward < 0  # behind the body


def test_limit_variation_widens_poses_and_stays_inside_the_joint_ranges(anny_model):
    limits = _axes_of(anny_model).limits_deg
    plain = [sample_pose(anny_model, "standing", np.random.default_rng(s)).angles_deg for s in range(20)]
    wide = [sample_pose(anny_model, "standing", np.random.default_rng(s), limit_variation=0.3).angles_deg
            for s in range(20)]
    assert np.std(wide, axis=0).mean() > 1.5 * np.std(plain, axis=0).mean()
    for a in wide:
        assert np.all(a >= limits[..., 0] - 1e-9) and np.all(a <= limits[..., 1] + 1e-9)
    # without it, no random number is drawn: the pose is the same as before the option existed
    rng_a, rng_b = np.random.default_rng(4), np.random.default_rng(4)
    sample_pose(anny_model, "walking", rng_a)
    sample_pose(anny_model, "walking", rng_b, limit_variation=0.0)
    assert rng_a.random() == rng_b.random()


def test_turning_a_person_keeps_it_in_its_footprint_and_turns_its_heading(anny_model):
    mount, person = _posed(anny_model, "walking", 0, heading=0.3)
    turned = turn_person(person, 1.2, mount, anny_model)
    centre, radius = footprint(vertices_world(person, mount))
    moved = vertices_world(turned, mount)
    assert np.linalg.norm(moved[:, :2] - centre, axis=1).max() <= radius + 1e-6  # clear of whatever it was
    assert not np.allclose(moved, vertices_world(person, mount), atol=0.05)
    assert turned.placement.heading == pytest.approx(1.5)
    # the parameters still produce the turned body
    import torch

    p = turned.params
    dtype = torch.get_default_dtype()
    with torch.no_grad():
        out = anny_model(*(torch.as_tensor(x[None], dtype=dtype) for x in (p.shape, p.pose, p.root_orient, p.transl)))
    np.testing.assert_allclose(out.vertices[0].numpy(), turned.vertices, atol=1e-3)


# -- scenarios ---------------------------------------------------------------------------------------------
def test_every_scenario_names_known_families_and_sensors(sim_cfg):
    from smplify3d_ros.sim.poses import FAMILIES

    for name, sc in sim_cfg.bench.scenarios.items():
        assert sc.sensor in sim_cfg.lidar.names, name
        assert set(sc.family_weights or {}) <= set(FAMILIES), name
    robot = sim_cfg.bench.scenarios["robot"]
    new = {"kneeling", "hands_on_hips", "arms_crossed", "stepping_up", "leaning", "turning"}
    assert set(robot.family_weights) == set(FAMILIES) and new <= set(FAMILIES)
    lab = scenario_sim_config(sim_cfg, "lab")  # the studies' scenes: sim.scene as it is, but for n and distance
    assert lab.scene.family_weights == sim_cfg.scene.family_weights and lab.camera == sim_cfg.camera
    assert sim_cfg.bench.report_seed_start > sim_cfg.bench.tuning_seeds[1]


def test_outdoor_crowd_is_a_high_resolution_dense_crowd_seen_from_behind(sim_cfg):
    sim = simulate_scenario(1000, sim_cfg, "outdoor_crowd", n_people=6)
    sc = sim_cfg.bench.scenarios["outdoor_crowd"]
    assert (sim.frame.camera.width, sim.frame.camera.height) == (2048, 1536)
    assert sim.frame.image.shape == (1536, 2048, 3)
    assert 5 <= len(sim.people) <= 6 and set(sim.lidar_fields["ring"]) <= set(range(6))
    up = make_mount(sim_cfg.mount).up_cam
    hips = [p.keypoints3d[[11, 12]].mean(0) for p in sim.people]
    distance = [float(np.hypot(h[0], h[2])) for h in hips]
    assert all(sc.distance_m[0] - 0.3 <= d <= sc.distance_m[1] + 0.3 for d in distance)
    headings = [heading_to_camera_deg(p.params.root_orient, h, up) for p, h in zip(sim.people, hips)]
    assert sum(h > 180 - sim_cfg.scene.back_facing_spread_deg - 1 for h in headings) >= 2  # seen from behind
    # dense: people near 10 m or closer, in the open, get a hundred points or more
    points = [int((sim.point_labels == p.person_id).sum()) for p in sim.people]
    near = [n for n, d, p in zip(points, distance, sim.people) if d < 10.5 and sim.visible_fraction[p.person_id] > 0.9]
    assert near and min(near) >= 100


def test_back_facing_people_face_away(anny_model, sim_cfg):
    cfg = dataclasses.replace(sim_cfg, scene=dataclasses.replace(sim_cfg.scene, back_facing_prob=1.0))
    sim = simulate_scenario(7, cfg, "lab", n_people=3)
    up = make_mount(cfg.mount).up_cam
    for p in sim.people:
        heading = heading_to_camera_deg(p.params.root_orient, p.keypoints3d[[11, 12]].mean(0), up)
        assert heading > 180 - cfg.scene.back_facing_spread_deg - 2.0  # lean and the bearing's few degrees
