"""A simulated image-HMR initial estimate, calibrated to behave like CLIFF on 3DPW.

What an image regressor gets wrong, and how each error is produced from the ground truth:
- shape: regressed towards the population mean (`shape_shrink`) plus noise;
- depth / scale: an image fixes the body's direction from the camera, not its distance. The predicted
  body (of the predicted, more average, size) is placed along the ray through the true pelvis at the
  distance where it projects about as large as the true body: distance x size_pred / size_true, times
  a log-normal factor (`depth_log_sigma`, `depth_log_bias`) for the regressor's own scale error, plus a
  small error across the ray (`lateral_sigma_rel` x distance). Its image projection stays roughly
  right while its 3D position is off by decimetres: the unaligned MPJPE;
- pose: each joint's rotation is perturbed mostly about its depth-ambiguous axis, bone x viewing ray,
  which swings the child joint along the camera ray (invisible in the image), with
  `pose_depth_sigma_deg`, plus a small isotropic error (`pose_sigma_deg`); the root turns about the
  body's vertical (`root_yaw_sigma_deg`) and leans towards or away from the camera
  (`root_tilt_sigma_deg`). These give the root-aligned MPJPE.

`smplify3d_ros.eval.hmr_statistics` measures the errors this model produces over random people at 3DPW-like distances;
the defaults give about 60 to 80 mm root-aligned and 300 to 600 mm unaligned MPJPE (CLIFF on 3DPW:
about 69 / 479 mm, as reported by CLIFF's authors).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from smplify3d_ros.body.joints import BODY_JOINTS, JOINT_CHILD, JOINT_INDEX, JOINT_PARENT
from smplify3d_ros.geometry import unit
from smplify3d_ros.sim.config import HmrConfig
from smplify3d_ros.types import BodyParams


def _rot(rotvec: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(rotvec).as_matrix()


def bone_length_sum(joints: np.ndarray, pelvis: np.ndarray) -> float:
    """Sum of the skeleton's bone lengths (pose independent), m: a body-size measure."""
    total = 0.0
    for name, parent in JOINT_PARENT.items():
        start = pelvis if parent is None else joints[JOINT_INDEX[parent]]
        total += float(np.linalg.norm(joints[JOINT_INDEX[name]] - start))
    return total


def global_rotations(params: BodyParams) -> dict[str, np.ndarray]:
    """Camera-frame rotation of each joint: root_orient · (parents' local rotations) · own."""
    out: dict[str, np.ndarray] = {}
    root = _rot(params.root_orient)
    for name in BODY_JOINTS:  # parents come before children in BODY_JOINTS
        parent = JOINT_PARENT[name]
        base = root if parent is None else out[parent]
        out[name] = base @ _rot(params.pose[JOINT_INDEX[name]])
    return out


def perturb_pose(
    rng: np.random.Generator, params: BodyParams, joints: np.ndarray, cfg: HmrConfig
) -> tuple[np.ndarray, np.ndarray]:
    """(pose, root_orient) with depth-ambiguous joint errors and root orientation errors."""
    globals_ = global_rotations(params)
    root = _rot(params.root_orient)
    pose = params.pose.copy()
    for name in BODY_JOINTS:
        i = JOINT_INDEX[name]
        parent = JOINT_PARENT[name]
        parent_rot = root if parent is None else globals_[parent]
        local = _rot(params.pose[i])
        delta = _rot(np.deg2rad(rng.normal(0.0, cfg.pose_sigma_deg, 3)))
        child = JOINT_CHILD[name]
        if child is not None:
            bone = joints[JOINT_INDEX[child]] - joints[i]
            axis_cam = unit(np.cross(bone, unit(joints[i])))  # swings the bone along the ray
            if np.any(axis_cam):
                axis_local = parent_rot.T @ axis_cam
                angle = np.deg2rad(rng.normal(0.0, cfg.pose_depth_sigma_deg))
                delta = _rot(axis_local * angle) @ delta
        pose[i] = Rotation.from_matrix(delta @ local).as_rotvec()
    pelvis = params.transl
    body_up = root @ np.array([0.0, 1.0, 0.0])
    tilt_axis = unit(np.cross(body_up, unit(pelvis)))
    yaw = _rot(body_up * np.deg2rad(rng.normal(0.0, cfg.root_yaw_sigma_deg)))
    tilt = _rot(tilt_axis * np.deg2rad(rng.normal(0.0, cfg.root_tilt_sigma_deg)))
    root_orient = Rotation.from_matrix(tilt @ yaw @ root).as_rotvec()
    return pose, root_orient


def predicted_shape(
    rng: np.random.Generator, shape: np.ndarray, mean: np.ndarray, cfg: HmrConfig
) -> np.ndarray:
    pred = mean + cfg.shape_shrink * (shape - mean) + rng.normal(0.0, cfg.shape_noise, shape.shape)
    return np.clip(pred, 0.0, 1.0)


def _rest_sizes(model, shapes: np.ndarray) -> np.ndarray:
    """Bone-length sums of bodies of the given shapes."""
    dtype = torch.get_default_dtype()
    B = len(shapes)
    with torch.no_grad():
        out = model(
            torch.as_tensor(shapes, dtype=dtype),
            torch.zeros(B, len(BODY_JOINTS), 3, dtype=dtype),
            torch.zeros(B, 3, dtype=dtype),
            torch.zeros(B, 3, dtype=dtype),
        )
        centre = model.rotation_center(torch.as_tensor(shapes, dtype=dtype), torch.zeros(B, 3, dtype=dtype))
    joints = out.joints.double().numpy()
    centre = centre.double().numpy()
    return np.array([bone_length_sum(j, c) for j, c in zip(joints, centre)])


def simulate_hmr(
    rng: np.random.Generator,
    model,
    people: list[tuple[BodyParams, np.ndarray]],
    cfg: HmrConfig,
) -> list[BodyParams]:
    """CLIFF-like estimates of (ground-truth params, ground-truth joints (J, 3)) people, camera frame.

    One batched forward pass measures the predicted bodies' sizes; everything else is closed form.
    """
    if not people:
        return []
    mean = model.reference_shape().detach().cpu().double().numpy()  # the fitter's prior mean may differ
    shapes = np.stack([predicted_shape(rng, p.shape, mean, cfg) for p, _ in people])
    sizes_pred = _rest_sizes(model, shapes)
    dtype = torch.get_default_dtype()
    estimates = []
    for (params, joints), shape, size_pred in zip(people, shapes, sizes_pred):
        joints = np.asarray(joints, dtype=np.float64)
        pelvis = (
            model.rotation_center(
                torch.as_tensor(params.shape[None], dtype=dtype),
                torch.as_tensor(params.transl[None], dtype=dtype),
            )[0]
            .double()
            .numpy()
        )
        size_true = bone_length_sum(joints, pelvis)
        pose, root_orient = perturb_pose(rng, params, joints, cfg)
        factor = size_pred / size_true * np.exp(rng.normal(cfg.depth_log_bias, cfg.depth_log_sigma))
        distance = float(np.linalg.norm(pelvis))
        ray = pelvis / distance
        lateral = rng.normal(0.0, cfg.lateral_sigma_rel * distance, 3)
        lateral -= ray * (lateral @ ray)
        new_pelvis = pelvis * factor + lateral
        estimates.append(
            BodyParams(
                params.model,
                shape,
                pose,
                root_orient,
                params.transl + (new_pelvis - pelvis),
            )
        )
    return estimates
