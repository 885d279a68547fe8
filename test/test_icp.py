"""ICP recovers a known rigid offset between a body surface and its LiDAR points."""

import numpy as np
from scipy.spatial.transform import Rotation

from smplify3d_ros.fitting.icp import align_mesh_to_points


def standing_body(model, yaw: float, transl: list[float]):
    """The model's mean body standing at `transl` (camera frame) turned by `yaw`: its forward output."""
    import torch

    from smplify3d_ros.fitting.init import upright_root_orient

    dt = model.anat_frames.dtype
    with torch.no_grad():
        return model(model.mean_shape()[None], torch.zeros(1, 19, 3, dtype=dt),
                     torch.as_tensor(upright_root_orient(yaw), dtype=dt)[None], torch.tensor([transl], dtype=dt))


def test_icp_recovers_known_offset(anny_model, config, rng):
    verts = standing_body(anny_model, 0.4, [0.3, 0.2, 6.0]).vertices[0].double().numpy()
    points = verts[rng.choice(len(verts), 400, replace=False)] + 0.005 * rng.standard_normal((400, 3))
    # the mesh is off by a rigid motion; ICP must bring it back onto the points
    R = Rotation.from_euler("y", 8, degrees=True).as_matrix()
    t = np.array([0.15, -0.05, 0.4])
    centre = verts.mean(0)
    moved = (verts - centre) @ R.T + centre + t
    result = align_mesh_to_points(moved, points, config.fitting.icp)
    assert result.converged
    back = moved @ result.T[:3, :3].T + result.T[:3, 3]
    err = np.linalg.norm(back - verts, axis=1).mean()
    assert err < 0.02, err


def test_icp_empty_inputs_do_not_converge(config):
    result = align_mesh_to_points(np.zeros((0, 3)), np.ones((5, 3)), config.fitting.icp)
    assert not result.converged and np.allclose(result.T, np.eye(4))


def test_icp_keeps_the_start_whose_points_lie_closest(anny_model, config, rng):
    """Points on the legs and hips alone (a LiDAR whose field of view ends below the chest, a person close
    to a VLP-16) can slide down the legs and stay inliers. Of the pre-alignment's two starts, the one whose
    points then lie closest to the mesh must win, not the one with more inliers (or the first of equals):
    here the mesh where it already is, not the bounding boxes' offset (half the body's missing height).
    A kernel this wide makes every point an inlier from either start; the translation-only alignment is the
    pre-alignment's result as it is."""
    import dataclasses

    out = standing_body(anny_model, 0.3, [0.2, 0.1, 7.0])
    verts = out.vertices[0].double().numpy()
    front = verts[verts[:, 2] < np.median(verts[:, 2])]  # the side the sensors see
    pelvis_y = float(out.keypoints[0, 11:13, 1].mean())
    legs = front[front[:, 1] > pelvis_y - 0.1]  # camera y points down: the hips and below
    points = legs[rng.choice(len(legs), 350, replace=False)] + 0.01 * rng.standard_normal((350, 3))
    wide = dataclasses.replace(config.fitting.icp, kernel=0.3, estimate_rotation=False)
    result = align_mesh_to_points(front, points, wide)
    moved = front @ result.T[:3, :3].T + result.T[:3, 3]
    assert np.linalg.norm(moved - front, axis=1).mean() < 0.03
