"""A synthetic person made directly with the body model, for the engine's tests and speed benchmark.

Unlike the full simulator (`smplify3d_ros.sim`), there is no scene and no ray casting: points are sampled
uniformly on the faces that face the sensor, keypoints are the projected truth plus Gaussian noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import roma
import torch

from smplify3d_ros.body import BodyModel
from smplify3d_ros.fitting.losses import project
from smplify3d_ros.fitting.visibility import front_facing
from smplify3d_ros.types import BodyParams, PersonObservation

LIMB_JOINTS = ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")


@dataclass
class SyntheticPerson:
    truth: BodyParams
    observation: PersonObservation
    joints: np.ndarray  # (J, 3) true joint positions, camera frame
    vertices: np.ndarray  # (V, 3) true vertices, camera frame


def default_intrinsics(width: int = 640, height: int = 480, hfov_deg: float = 90.0) -> np.ndarray:
    f = 0.5 * width / np.tan(np.deg2rad(hfov_deg) / 2)
    return np.array([[f, 0, width / 2], [0, f, height / 2], [0, 0, 1.0]])


def random_pose(model: BodyModel, rng: np.random.Generator, spread: float) -> np.ndarray:
    """Anatomical angles drawn uniformly in `spread` x each joint's range of motion, around its middle
    pulled toward rest (so that the body looks natural)."""
    ranges = model.joint_ranges.cpu().double().numpy()
    lo = np.minimum(ranges[..., 0], 0.0) * spread
    hi = np.maximum(ranges[..., 1], 0.0) * spread
    angles = rng.uniform(lo, hi)
    return model.anatomical_to_pose(torch.as_tensor(angles)[None].to(model.anat_frames.dtype))[0].double().numpy()


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, noise: float,
                   rng: np.random.Generator) -> np.ndarray:
    """`n` points uniformly over the area of the triangles `faces`, plus isotropic Gaussian noise (m)."""
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    pick = rng.choice(len(tri), size=n, p=area / area.sum())
    a, b = rng.random((2, n, 1))
    flip = (a + b) > 1  # fold the unit square onto the triangle
    a, b = np.where(flip, 1 - a, a), np.where(flip, 1 - b, b)
    t = tri[pick]
    points = t[:, 0] + a * (t[:, 1] - t[:, 0]) + b * (t[:, 2] - t[:, 0])
    return points + noise * rng.standard_normal(points.shape)


def make_person(
    model: BodyModel,
    rng: np.random.Generator,
    K: np.ndarray,
    distance: float,
    yaw: float,
    n_points: int,
    point_noise: float,
    keypoint_noise_px: float,
    pose_spread: float = 0.3,
    person_id: int = 0,
    pose: np.ndarray | None = None,
) -> SyntheticPerson:
    """A person `distance` m in front of the camera, turned by `yaw`, in a random pose (`pose_spread`) or
    `pose` (J, 3) when given."""
    from smplify3d_ros.fitting.init import upright_root_orient

    shape = np.clip(0.5 + 0.2 * rng.standard_normal(len(model.shape_names)), 0.05, 0.95)
    if model.name != "anny":
        shape = 0.5 * rng.standard_normal(len(model.shape_names))
    lateral = rng.uniform(-0.2, 0.2) * distance
    pose = random_pose(model, rng, pose_spread) if pose is None else np.asarray(pose, np.float64)
    truth = BodyParams(model.name, shape, pose, upright_root_orient(yaw),
                       np.array([lateral, 0.2, distance]))
    body = model.posed([truth])[0]
    uv = project(torch.as_tensor(body.keypoints3d)[None], torch.as_tensor(K, dtype=torch.float64))[0].numpy()
    verts = body.vertices
    faces = model.faces.cpu().numpy()
    front = front_facing(verts, faces, np.zeros(3), 0.0) & (model.part_of_face.cpu().numpy() >= 0)
    points = sample_surface(verts, faces[front], n_points, point_noise, rng)
    kp = np.concatenate([uv + keypoint_noise_px * rng.standard_normal(uv.shape), np.ones((len(uv), 1))], 1)
    bbox = np.array([*kp[:, :2].min(0), *kp[:, :2].max(0)])
    obs = PersonObservation(person_id, kp, bbox, points.astype(np.float32))
    return SyntheticPerson(truth, obs, body.joints, verts)


def perturb(model: BodyModel, params: BodyParams, rng: np.random.Generator, depth_m: float,
            limb_deg: float) -> BodyParams:
    """Push the body `depth_m` along its viewing ray (away) and rotate each limb joint (shoulders,
    elbows, wrists, hips, knees, ankles) by `limb_deg` about a random axis: the engine's test initial
    estimate."""
    out = params.copy()
    ray = params.transl / np.linalg.norm(params.transl)
    out.transl = params.transl + depth_m * ray
    axes = rng.standard_normal(params.pose.shape)
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    axes[[i for i, n in enumerate(model.joint_names) if n.split("_")[-1] not in LIMB_JOINTS]] = 0.0
    delta = torch.as_tensor(axes * np.deg2rad(limb_deg))
    pose = roma.rotvec_composition([delta, torch.as_tensor(params.pose)])
    out.pose = pose.numpy()
    return out
