"""The pose library and body shapes: joint limits, conventions, reproducibility, plausible bodies."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from smplify3d_ros.body.joints import JOINT_INDEX
from smplify3d_ros.sim.config import default_sim_config
from smplify3d_ros.sim.people import SHAPE_PRESETS, preset_shape, sample_shape
from smplify3d_ros.sim.poses import FAMILIES, PROP_SEAT, _axes_of, angles_to_pose, sample_pose


def _joints(model, pose, shape=None):
    shape = model.mean_shape()[None] if shape is None else torch.as_tensor(shape, dtype=torch.float32)[None]
    with torch.no_grad():
        out = model(
            shape, torch.as_tensor(pose, dtype=torch.float32)[None], torch.zeros(1, 3), torch.zeros(1, 3)
        )
    return out.joints[0].double().numpy(), out.vertices[0].double().numpy()


def _bone(joints, a, b):
    d = joints[JOINT_INDEX[b]] - joints[JOINT_INDEX[a]]
    return d / np.linalg.norm(d)


def test_anatomical_conventions(anny_model):
    """Canonical axes: x left, y up, z forward. Our angles are symmetric left/right."""
    for side, lateral in (("left", 1.0), ("right", -1.0)):
        angles = np.zeros((19, 3))
        angles[JOINT_INDEX[f"{side}_shoulder"]] = (90, 0, 0)  # arm forward
        angles[JOINT_INDEX[f"{side}_hip"]] = (0, 0, 40)  # leg out sideways
        j, _ = _joints(anny_model, angles_to_pose(anny_model, angles))
        assert _bone(j, f"{side}_shoulder", f"{side}_elbow") @ [0, 0, 1] > 0.95
        assert _bone(j, f"{side}_hip", f"{side}_knee") @ [lateral, 0, 0] > 0.55
        # abducted 90 deg, rotated externally 90 deg, elbow bent: the forearm points up (a wave)
        angles = np.zeros((19, 3))
        angles[JOINT_INDEX[f"{side}_shoulder"]] = (0, 90, 90)
        angles[JOINT_INDEX[f"{side}_elbow"]] = (90, 0, 0)
        j, _ = _joints(anny_model, angles_to_pose(anny_model, angles))
        assert _bone(j, f"{side}_shoulder", f"{side}_elbow") @ [lateral, 0, 0] > 0.95
        assert _bone(j, f"{side}_elbow", f"{side}_wrist") @ [0, 1, 0] > 0.95
    # knees bend backwards, the neutral pose hangs the arms straight down
    angles = np.zeros((19, 3))
    angles[JOINT_INDEX["left_knee"]] = (90, 0, 0)
    j, _ = _joints(anny_model, angles_to_pose(anny_model, angles))
    assert _bone(j, "left_knee", "left_ankle") @ [0, 0, -1] > 0.95
    assert _bone(j, "left_shoulder", "left_elbow") @ [0, -1, 0] > 0.98
    assert _bone(j, "left_elbow", "left_wrist") @ [0, -1, 0] > 0.98


@pytest.mark.parametrize("family", FAMILIES)
def test_families_stay_inside_joint_limits_and_are_reproducible(anny_model, family):
    limits = _axes_of(anny_model).limits_deg
    for seed in range(3):
        a = sample_pose(anny_model, family, np.random.default_rng(seed))
        b = sample_pose(anny_model, family, np.random.default_rng(seed))
        np.testing.assert_array_equal(a.pose, b.pose)
        assert np.all(a.angles_deg >= limits[..., 0] - 1e-9) and np.all(a.angles_deg <= limits[..., 1] + 1e-9)
        assert a.family == family and a.pose.shape == (19, 3)
    assert (PROP_SEAT in a.props) == (family == "sitting")


def test_walking_cycle_alternates_the_legs(anny_model):
    rng = np.random.default_rng(0)
    first = sample_pose(anny_model, "walking", rng, phase=0.0, variation_scale=0.0)
    half = sample_pose(anny_model, "walking", rng, phase=0.5, variation_scale=0.0)
    left, right = JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"]
    assert first.angles_deg[left, 0] > 20 and first.angles_deg[right, 0] < 0  # left heel strike
    np.testing.assert_allclose(first.angles_deg[left], half.angles_deg[right], atol=1e-9)


def test_unknown_family_is_an_error(anny_model):
    with pytest.raises(ValueError, match="unknown pose family"):
        sample_pose(anny_model, "dancing", np.random.default_rng(0))


def test_shape_presets_cover_adults_and_a_child(anny_model):
    cfg = default_sim_config().people
    statures = {}
    rest = np.zeros((19, 3))
    for name in SHAPE_PRESETS:
        _, v = _joints(anny_model, rest, preset_shape(name, anny_model.shape_names))
        statures[name] = np.ptp(v[:, 1])
    assert 1.65 < statures["adult_male"] < 1.9 and 1.55 < statures["adult_female"] < 1.75
    assert statures["tall_male"] > 1.85 and statures["short_female"] < 1.5
    assert statures["child"] < 1.4
    name, shape = sample_shape(np.random.default_rng(0), cfg, anny_model.shape_names)
    assert name in SHAPE_PRESETS and np.all((shape >= 0) & (shape <= 1))
