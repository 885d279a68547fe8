"""The ground plane under a camera pitched down, looked for around the level LiDAR's up (`lidar.ground_up`)."""

import dataclasses

import numpy as np

from smplify3d_ros.config import load_config
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.frame_fitter import FrameFitter, extract_frame_people
from smplify3d_ros.sim.config import load_sim_config
from smplify3d_ros.sim.scene import make_mount
from smplify3d_ros.sim.world import simulate_scenario


def test_a_camera_pitched_down_finds_the_ground_around_the_lidars_up(anny_model):
    """A camera pitched 25° down over a level VLP-16: the floor's normal is 25° off the camera's −y, past
    the 20° the plane may tilt by, so looked for around the camera's up it is not found, and the fit
    stands upright in the camera frame: 25° off (tuning seeds 0-39 at 2-8 m: 562.5 mm, 64 % of the fits
    off their points). Looked for around the LiDAR's z axis it is the floor, the camera's height below it,
    and the person is fitted standing on it."""
    sim_cfg = load_sim_config(overrides={"sim": {"mount": {"camera_pitch_deg": 25.0}}})
    sim = simulate_scenario(3, sim_cfg, "robot", sensor="vlp16", n_people=1, distance_range=(3.0, 4.0))
    truth = sim.people[0]
    up = make_mount(sim_cfg.mount).up_cam
    config = load_config()
    assert config.lidar.ground_up == "lidar"
    _, result = extract_frame_people(sim.frame, config.lidar)
    assert result.ground.fitted
    assert np.degrees(np.arccos(np.clip(result.ground.normal @ up, -1, 1))) < 2.0
    assert abs(result.ground.offset - sim_cfg.mount.camera_height_m) < 0.05
    own = np.flatnonzero(sim.point_labels == truth.person_id)
    taken = result.people[0].indices
    assert len(own) > 50 and np.isin(taken, own).mean() > 0.95 and len(taken) > 0.6 * len(own)  # head: above the image
    errors = {}
    for ground_up in ("lidar", "camera"):
        core = dataclasses.replace(config, lidar=dataclasses.replace(config.lidar, ground_up=ground_up))
        fits = FrameFitter(core, fitter=Fitter(core.fitting, anny_model)).fit(sim.frame).fits
        assert len(fits) == 1
        errors[ground_up] = 1000 * float(np.linalg.norm(fits[0].joints - truth.joints, axis=1).mean())
    assert errors["lidar"] < 50.0, errors
    assert errors["camera"] > 1.5 * errors["lidar"], errors  # the old prior: no plane, an upright start 25° off


def test_a_lidar_mounted_upside_down_still_gives_the_floor():
    """The same scan from a LiDAR hung upside down (its z axis pointing at the floor; the extrinsic says
    so): its z axis is turned up before the floor is looked for around it."""
    sim_cfg = load_sim_config(overrides={"sim": {"mount": {"camera_pitch_deg": 25.0}}})
    sim = simulate_scenario(3, sim_cfg, "robot", sensor="vlp16", n_people=1, distance_range=(3.0, 4.0))
    flip = np.diag([1.0, -1.0, -1.0, 1.0])  # 180° about the LiDAR's x axis
    frame = dataclasses.replace(sim.frame, points_lidar=(sim.frame.points_lidar @ flip[:3, :3].T).astype(np.float32),
                                T_cam_lidar=sim.frame.T_cam_lidar @ flip)
    _, upright = extract_frame_people(sim.frame, load_config().lidar)
    _, hung = extract_frame_people(frame, load_config().lidar)
    assert hung.ground.fitted
    assert np.allclose(hung.ground.normal, upright.ground.normal, atol=1e-6)
    assert np.array_equal(hung.people[0].indices, upright.people[0].indices)
