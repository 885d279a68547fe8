"""The simulated LiDAR against analytic cases: ranges on planes, VLP-16 beam geometry and timing,
drop-out and range noise statistics, the driver's field layout."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

from smplify3d_ros.sim.config import default_sim_config
from smplify3d_ros.sim.lidar import scan_pattern, simulate_scan
from smplify3d_ros.sim.raycast import LABEL_GROUND, LABEL_STATIC, RayScene


@pytest.fixture(scope="module")
def sim_cfg():
    return default_sim_config()


def _sensor(sim_cfg, name="vlp16", **changes):
    return dataclasses.replace(sim_cfg.lidar.sensors[name], **changes)


def _noiseless(sim_cfg, name="vlp16"):
    return _sensor(sim_cfg, name, range_noise_m=0.0, angular_noise_deg=0.0, dropout=0.0)


def _wall_scene(x: float) -> RayScene:
    v = np.array([[x, -500, -500], [x, 500, -500], [x, 500, 500], [x, -500, 500.0]])
    return RayScene.from_parts([(v, np.array([[0, 1, 2], [0, 2, 3]]), LABEL_STATIC)])


def _enclosing_box(half: float = 20.0) -> RayScene:
    box = trimesh.creation.box(extents=[2 * half] * 3)
    return RayScene.from_parts([(box.vertices, box.faces, LABEL_STATIC)])


def test_plane_at_known_distance_gives_exact_ranges(sim_cfg):
    scan = simulate_scan(
        _wall_scene(10.0), np.eye(4), _noiseless(sim_cfg), sim_cfg.lidar.intensity, np.random.default_rng(0)
    )
    p = scan.points.astype(np.float64)
    assert len(p) > 5000  # the front half of the turn hits the wall
    np.testing.assert_allclose(p[:, 0], 10.0, atol=1e-4)
    # range along each beam = 10 / (cos(elevation) cos(azimuth)), from the nominal beam angles
    elevation = np.deg2rad(-15.0 + 2.0 * scan.ring.astype(np.float64))
    azimuth = np.arctan2(p[:, 1], p[:, 0])
    expected = 10.0 / (np.cos(elevation) * np.cos(azimuth))
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), expected, rtol=1e-5)


def test_ground_plane_seen_from_a_mount(sim_cfg):
    height = 0.55
    ground = np.array(
        [[-200, -200, -height], [200, -200, -height], [200, 200, -height], [-200, 200, -height]]
    )
    scene = RayScene.from_parts([(ground, np.array([[0, 1, 2], [0, 2, 3]]), LABEL_GROUND)])
    scan = simulate_scan(
        scene, np.eye(4), _noiseless(sim_cfg), sim_cfg.lidar.intensity, np.random.default_rng(0)
    )
    assert set(np.unique(scan.ring)) == set(range(8))  # only the 8 downward lasers hit the ground
    np.testing.assert_allclose(scan.points[:, 2], -height, atol=1e-4)
    horizontal = np.linalg.norm(scan.points[:, :2].astype(np.float64), axis=1)
    for ring in range(8):
        elevation = np.deg2rad(-15.0 + 2.0 * ring)
        expected = height / np.tan(-elevation)
        sel = scan.ring == ring
        if expected <= sim_cfg.lidar.sensors["vlp16"].max_range_m:
            np.testing.assert_allclose(horizontal[sel], expected, rtol=1e-4)
    assert np.all(scan.label == LABEL_GROUND)


def test_vlp16_rings_azimuth_step_and_timing(sim_cfg):
    sensor = _noiseless(sim_cfg)
    scan = simulate_scan(
        _enclosing_box(), np.eye(4), sensor, sim_cfg.lidar.intensity, np.random.default_rng(0)
    )
    assert len(scan.points) == 1808 * 16  # about 29k points per turn before drop-out
    p = scan.points.astype(np.float64)
    elevation = np.rad2deg(np.arcsin(p[:, 2] / np.linalg.norm(p, axis=1)))
    np.testing.assert_allclose(elevation, -15.0 + 2.0 * scan.ring, atol=1e-3)
    for ring in (0, 7, 15):
        az = np.unwrap(np.arctan2(p[scan.ring == ring, 1], p[scan.ring == ring, 0]))
        step = np.rad2deg(np.diff(az))
        np.testing.assert_allclose(step, -360.0 * 10.0 * 55.296e-6, atol=1e-3)  # clockwise, ~0.2 deg
    # firing order inside one column, 2.304 us apart; columns every 55.296 us; one turn < 0.1 s
    first = scan.time[:16].astype(np.float64)
    np.testing.assert_allclose(np.diff(first), 2.304e-6, rtol=1e-3)
    np.testing.assert_allclose(-15.0 + 2.0 * scan.ring[:16], sensor.firing_order_deg)
    np.testing.assert_allclose(scan.time[16] - scan.time[0], 55.296e-6, rtol=1e-3)
    assert np.all(np.diff(scan.time) >= 0) and scan.time[-1] < 0.1
    # the scan starts behind the robot
    assert abs(abs(np.rad2deg(np.arctan2(p[0, 1], p[0, 0]))) - 180.0) < 0.5


def test_output_has_the_velodyne_driver_field_layout(sim_cfg):
    scan = simulate_scan(
        _enclosing_box(), np.eye(4), _sensor(sim_cfg), sim_cfg.lidar.intensity, np.random.default_rng(0)
    )
    assert scan.points.dtype == np.float32 and scan.points.ndim == 2 and scan.points.shape[1] == 3
    fields = scan.fields()
    assert set(fields) == {"intensity", "ring", "time"}
    assert fields["intensity"].dtype == np.float32
    assert fields["ring"].dtype == np.uint16
    assert fields["time"].dtype == np.float32
    assert scan.label.dtype == np.int32
    n = len(scan.points)
    assert all(len(v) == n for v in fields.values()) and len(scan.label) == n
    assert fields["ring"].max() == 15 and fields["ring"].min() == 0
    assert np.all((fields["intensity"] >= 0) & (fields["intensity"] <= 255))


@pytest.mark.parametrize("dropout", [0.1, 0.4])
def test_dropout_fraction(sim_cfg, dropout):
    sensor = _sensor(sim_cfg, range_noise_m=0.0, angular_noise_deg=0.0, dropout=dropout)
    scan = simulate_scan(
        _enclosing_box(), np.eye(4), sensor, sim_cfg.lidar.intensity, np.random.default_rng(3)
    )
    kept = len(scan.points) / (1808 * 16)
    sigma = np.sqrt(dropout * (1 - dropout) / (1808 * 16))
    assert abs((1 - kept) - dropout) < 5 * sigma


def test_range_noise_is_gaussian_along_the_ray(sim_cfg):
    sigma = 0.03
    scene = _wall_scene(10.0)
    sensor = _sensor(sim_cfg, range_noise_m=sigma, angular_noise_deg=0.0, dropout=0.0)
    scan = simulate_scan(scene, np.eye(4), sensor, sim_cfg.lidar.intensity, np.random.default_rng(5))
    p = scan.points.astype(np.float64)
    rays = p / np.linalg.norm(p, axis=1, keepdims=True)
    true_range = 10.0 / rays[:, 0]
    error = np.linalg.norm(p, axis=1) - true_range
    assert abs(error.mean()) < 3 * sigma / np.sqrt(len(error))
    assert abs(error.std() / sigma - 1.0) < 0.05
    # the error is along the ray: the point's direction is the nominal beam's
    clean = simulate_scan(
        scene, np.eye(4), _noiseless(sim_cfg), sim_cfg.lidar.intensity, np.random.default_rng(5)
    )
    np.testing.assert_allclose(
        rays, clean.points / np.linalg.norm(clean.points, axis=1, keepdims=True), atol=1e-5
    )


def test_angular_noise_moves_points_across_the_ray(sim_cfg):
    scene = _wall_scene(10.0)
    rms = []
    for sigma_deg in (0.05, 0.1):
        sensor = _sensor(sim_cfg, range_noise_m=0.0, angular_noise_deg=sigma_deg, dropout=0.0)
        scan = simulate_scan(scene, np.eye(4), sensor, sim_cfg.lidar.intensity, np.random.default_rng(7))
        # reported along the nominal beam: the x coordinate on the wall is no longer exactly 10 m
        rms.append(float(np.sqrt(np.mean((scan.points[:, 0].astype(np.float64) - 10.0) ** 2))))
    assert rms[0] > 1e-3
    assert 1.6 < rms[1] / rms[0] < 2.4  # about linear in sigma


def test_max_range_drops_far_returns(sim_cfg):
    sensor = dataclasses.replace(_noiseless(sim_cfg), max_range_m=9.0)
    scan = simulate_scan(
        _wall_scene(10.0), np.eye(4), sensor, sim_cfg.lidar.intensity, np.random.default_rng(0)
    )
    assert len(scan.points) == 0


def test_lidar_pose_in_the_scene_is_applied(sim_cfg):
    # LiDAR 2 m behind the origin and turned 90 deg left: the wall at scene x = 10 is 12 m to its right
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = (-2.0, 0.0, 0.0)
    scan = simulate_scan(
        _wall_scene(10.0), T, _noiseless(sim_cfg), sim_cfg.lidar.intensity, np.random.default_rng(0)
    )
    np.testing.assert_allclose(scan.points[:, 1], -12.0, atol=1e-4)


@pytest.mark.parametrize(
    "name,channels,columns", [("os1_32", 32, 512), ("os1_64", 64, 1024), ("os1_128", 128, 2048)]
)
def test_ouster_patterns(sim_cfg, name, channels, columns):
    pattern = scan_pattern(sim_cfg.lidar.sensors[name])
    assert pattern.columns == columns and len(pattern.time) == channels * columns
    elevations = np.unique(np.round(np.rad2deg(pattern.elevation), 6))
    np.testing.assert_allclose(elevations, np.linspace(-22.5, 22.5, channels), atol=1e-6)
    top = pattern.elevation == pattern.elevation.max()
    assert np.all(pattern.ring[top] == 0)  # ouster driver: ring 0 is the top beam
    step = np.rad2deg(np.abs(np.diff(np.unwrap(pattern.azimuth[pattern.ring == 0]))))
    np.testing.assert_allclose(step, 360.0 / columns, rtol=1e-6)
