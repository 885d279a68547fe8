"""A detector that scores lower than the one the package is tuned on (`people.score_level`): every score
threshold of the path reads its scores as the tuned-on detector's (`frame_fitter.calibrated_scores`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from smplify3d_ros.config import load_config
from smplify3d_ros.frame_fitter import FrameFitter, calibrated_scores


def test_a_confident_frame_keeps_its_scores_and_a_less_confident_one_is_scaled_to_the_level():
    confident = np.r_[np.full(12, 0.92), np.full(4, 0.5), 0.0]
    np.testing.assert_array_equal(calibrated_scores(confident, 0.8, 2.0), confident)
    low = np.r_[np.full(12, 0.64), np.full(4, 0.3), 0.0]  # seen joints 0.64: upper quartile 0.64
    out = calibrated_scores(low, 0.8, 2.0)
    np.testing.assert_allclose(out, np.r_[np.full(12, 0.8), np.full(4, 0.375), 0.0])  # x 0.8 / 0.64
    assert calibrated_scores(np.full(17, 0.2), 0.8, 2.0) == pytest.approx(np.full(17, 0.4))  # at most x2
    assert calibrated_scores(np.r_[np.full(16, 0.7), 0.99], 0.8, 2.0).max() <= 1.0
    np.testing.assert_array_equal(calibrated_scores(low, 0.0, 2.0), low)  # level 0: as given
    np.testing.assert_array_equal(calibrated_scores(np.zeros((2, 17)), 0.8, 2.0), np.zeros((2, 17)))


def test_a_less_confident_detector_sees_as_many_joints_as_the_tuned_one():
    """Tuning seed 0's people at 2-8 m with every score x 0.65 (seen joints about 0.58): without the
    calibration most of the joints the image term counts as seen (score >= keypoint_conf_image)
    drop under it; with it, the count stays within a joint or two of the original detector's."""
    from smplify3d_ros.sim.config import load_sim_config
    from smplify3d_ros.sim.world import simulate_scenario

    config = load_config()
    sim = simulate_scenario(0, load_sim_config(), "robot", sensor="vlp16", n_people=3, distance_range=(2.0, 8.0))
    low = dataclasses.replace(sim.frame, keypoints=sim.frame.keypoints * np.array([1.0, 1.0, 0.65]))
    seen_level = config.fitting.visibility.keypoint_conf_image

    def seen(cfg, frame) -> int:
        selected, _ = FrameFitter(cfg, fitter=object()).select_people(frame)  # selection needs no fitter
        return int((selected.keypoints[..., 2] >= seen_level).sum())

    original = seen(config, sim.frame)
    uncalibrated = dataclasses.replace(config, people=dataclasses.replace(config.people, score_level=0.0))
    assert seen(uncalibrated, low) < 0.5 * original
    assert abs(seen(config, low) - original) <= 2, (seen(config, low), original)
