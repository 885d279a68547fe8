"""A detector's left/right swap of a limb (`keypoints.SWAP_GROUPS`): the built-in initializer also tries
the swapped reading (`fitting.init.swap_hypotheses`) and keeps it only where the whole objective, the
LiDAR points included, clearly prefers it (`swap_hypothesis_margin`)."""

import numpy as np
import pytest
import torch

from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, make_person
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.keypoints import KP, SWAP_GROUPS, swapped_order
from smplify3d_ros.settings import ConfigError
from smplify3d_ros.types import FLAG_SWAPPED_KEYPOINTS

ANKLES = [KP["left_ankle"], KP["right_ankle"]]


def _fitter(model, **init) -> Fitter:
    return Fitter(load_config(overrides={"fitting": {"init": init}}).fitting, model)


def _mid_stride(model) -> np.ndarray:
    """A walker's pose mid-stride: left thigh forward, right back."""
    angles = torch.zeros(1, len(model.joint_names), 3, dtype=torch.float64)
    for name, degrees in (("left_hip", 30.0), ("right_hip", -20.0), ("left_knee", 10.0), ("right_knee", 30.0)):
        angles[0, model.joint_names.index(name), 0] = np.deg2rad(degrees)
    return model.anatomical_to_pose(angles, from_neutral=True)[0].numpy()


def _walker_from_behind(model, rng, distance: float = 5.0, n_points: int = 250):
    """A person `distance` m out walking away from the camera, mid-stride (left thigh forward, right
    back), the LiDAR's `n_points` over the surface turned to the sensor; perfect keypoints."""
    K = default_intrinsics()
    person = make_person(model, rng, K, distance, np.pi, n_points, 0.005, 0.0, pose=_mid_stride(model))
    return person.observation, K, model.posed([person.truth])[0]


def test_swapped_order_swaps_the_groups_pairs_only():
    order = swapped_order(["legs"])
    assert order[KP["left_knee"]] == KP["right_knee"] and order[KP["right_ankle"]] == KP["left_ankle"]
    assert [i for i in range(17) if order[i] != i] == sorted(i for pair in SWAP_GROUPS["legs"] for i in pair)
    assert swapped_order([]) == list(range(17))


def test_legs_a_detector_swapped_are_read_back_by_the_points(anny_model, rng):
    obs, K, body = _walker_from_behind(anny_model, rng)
    obs.keypoints[:] = obs.keypoints[swapped_order(["legs"])]  # the detector called the left leg the right
    error, flags = {}, {}
    for groups in ([], ["arms", "legs"]):
        fit = _fitter(anny_model, swap_hypotheses=groups).fit([obs], K)[0]
        key = len(groups)
        error[key] = float(np.linalg.norm(fit.keypoints3d[ANKLES] - body.keypoints3d[ANKLES], axis=1).mean())
        flags[key] = fit.flags
    print(f"ankle error: as detected {1000 * error[0]:.0f} mm, with the swapped readings {1000 * error[2]:.0f} mm")
    assert FLAG_SWAPPED_KEYPOINTS in flags[2] and FLAG_SWAPPED_KEYPOINTS not in flags[0]
    assert error[2] < 0.1 and error[0] > 2 * error[2], error


def test_a_detection_without_a_swap_is_read_as_detected(anny_model, rng):
    obs, K, body = _walker_from_behind(anny_model, rng)
    fit = _fitter(anny_model, swap_hypotheses=["arms", "legs"]).fit([obs], K)[0]
    assert FLAG_SWAPPED_KEYPOINTS not in fit.flags
    assert float(np.linalg.norm(fit.keypoints3d[ANKLES] - body.keypoints3d[ANKLES], axis=1).mean()) < 0.1


def test_an_unknown_swap_group_is_a_config_error(anny_model):
    with pytest.raises(ConfigError, match="swap_hypotheses"):
        _fitter(anny_model, swap_hypotheses=["tail"])


def test_shoulders_a_detector_swapped_start_from_the_heading_they_give_when_swapped(anny_model, rng):
    """A shoulder pair swapped alone contradicts the hips about where the person faces: its swapped
    reading starts from the heading of the swapped detection, and wins. Few points, as on a person 10 m
    out: many would hold the torso on their own."""
    obs, K, body = _walker_from_behind(anny_model, rng, 10.0, 25)
    obs.keypoints[:] = obs.keypoints[swapped_order(["shoulders"])]
    shoulders = [KP["left_shoulder"], KP["right_shoulder"]]
    error, flags = {}, {}
    for groups in ([], ["shoulders"]):
        fit = _fitter(anny_model, swap_hypotheses=groups).fit([obs], K)[0]
        error[len(groups)] = float(np.linalg.norm(fit.keypoints3d - body.keypoints3d, axis=1).mean())
        flags[len(groups)] = fit.flags
        print(f"{groups}: keypoints {1000 * error[len(groups)]:.0f} mm off, shoulders "
              f"{1000 * np.linalg.norm(fit.keypoints3d[shoulders] - body.keypoints3d[shoulders], axis=1).mean():.0f}")
    assert FLAG_SWAPPED_KEYPOINTS in flags[1]
    assert error[1] < 0.06 and error[0] > 1.5 * error[1], error


def test_a_tracked_start_is_tried_in_the_reading_it_projects_closest_to(anny_model, rng):
    """A person's own start (a track's warm start) is one row, not one per reading: the reading its
    projected joints match, here the true body against a detection with the legs swapped."""
    K = default_intrinsics()
    person = make_person(anny_model, rng, K, 5.0, np.pi, 250, 0.005, 0.0, pose=_mid_stride(anny_model))
    obs, start = person.observation, person.truth
    fitter = _fitter(anny_model, swap_hypotheses=["arms", "legs"])
    assert fitter._reading_of(start, obs.keypoints, K) is None
    swapped = obs.keypoints[swapped_order(["legs"])]
    assert fitter._reading_of(start, swapped, K) == swapped_order(["legs"])
    assert _fitter(anny_model, swap_hypotheses=[])._reading_of(start, swapped, K) is None
