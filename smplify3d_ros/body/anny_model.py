"""Anny (NAVER, Apache-2.0 code, CC0 MakeHuman assets), the embedded default body model.

What this adapter adds to `anny.Anny`:
- the 19 body joints (`body.joints.BODY_JOINTS`) mapped to Anny bones; fingers, toes, twist bones and
  eyes stay at rest;
- canonical axes: Anny is z-up with the face towards −y; we expose x left, y up, z forward like SMPL,
  so that poses and root orientations mean the same for every model;
- `transl` is the position of the pelvis (Anny's root bone) in the camera frame;
- COCO-17 keypoints from the regressor the wheel ships (`anny/data/keypoints/coco.pth`);
- a face -> body-part map from the skinning weights (each vertex's dominant bone).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import roma
import torch

from smplify3d_ros.body.base import BodyModel, BodyOutput
from smplify3d_ros.body.joints import BODY_JOINTS
from smplify3d_ros.keypoints import NUM_KEYPOINTS, PART_INDEX

log = logging.getLogger(__name__)

JOINT_TO_BONE: dict[str, str] = {
    "left_hip": "upperleg01.L", "right_hip": "upperleg01.R",
    "left_knee": "lowerleg01.L", "right_knee": "lowerleg01.R",
    "left_ankle": "foot.L", "right_ankle": "foot.R",
    "spine1": "spine04", "spine2": "spine02", "spine3": "spine01",
    "neck": "neck01", "head": "head",
    "left_collar": "clavicle.L", "right_collar": "clavicle.R",
    "left_shoulder": "upperarm01.L", "right_shoulder": "upperarm01.R",
    "left_elbow": "lowerarm01.L", "right_elbow": "lowerarm01.R",
    "left_wrist": "wrist.L", "right_wrist": "wrist.R",
}

# Bones that start a body part; every other bone belongs to the part of its nearest such ancestor.
PART_ROOT_BONES: dict[str, str] = {
    "upperleg01.L": "left_upper_leg", "lowerleg01.L": "left_lower_leg",
    "upperleg01.R": "right_upper_leg", "lowerleg01.R": "right_lower_leg",
    "upperarm01.L": "left_upper_arm", "lowerarm01.L": "left_lower_arm",
    "upperarm01.R": "right_upper_arm", "lowerarm01.R": "right_lower_arm",
    "neck01": "head", "root": "torso",
}

# Anny axes (x left, y back, z up) from canonical axes (x left, y up, z forward): a = C @ s.
C_ANNY_FROM_CANONICAL = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

# Parts of the Anny segmentation that are inside the body (never seen by a camera or a LiDAR).
_INTERNAL_SEGMENTS = ("eye_back.L", "eye_back.R", "eye_cavity.L", "eye_cavity.R", "mouth_cavity", "tongue")


@dataclass(frozen=True)
class _VertexSubset:
    """Anny's per-vertex tensors restricted to `index`."""

    key: torch.Tensor  # the caller's vertex index tensor this subset was built for (cache key)
    index: torch.Tensor  # (V,) vertex indices: the keypoint support, then the caller's vertices
    template: torch.Tensor  # (V, 3) template positions
    blendshapes: torch.Tensor  # (C, V, 3) blend-shape offsets
    bone_weights: torch.Tensor  # (V, k) skinning weights
    bone_indices: torch.Tensor  # (V, k) their bones


class AnnyBody(BodyModel):
    name = "anny"

    def __init__(self, shape_sigma: float, shape_bound_weight: float, keypoint_support: int) -> None:
        super().__init__()
        import anny  # heavy import (warp), kept local

        dtype = torch.get_default_dtype()
        model = anny.Anny().to(dtype=dtype)
        model.requires_grad_(False)
        self.anny = model
        self._subset_cache: _VertexSubset | None = None
        self.shape_names = tuple(model.phenotype_labels)
        self.shape_sigma = shape_sigma
        self.shape_bound_weight = shape_bound_weight
        labels = list(model.bone_labels)
        self.bone_index = [labels.index(JOINT_TO_BONE[j]) for j in BODY_JOINTS]
        self.root_bone = labels.index("root")
        regressor = anny.KeypointsRegressor.coco(model)
        self._init_keypoints(regressor.regression_weights[:NUM_KEYPOINTS].to(dtype), keypoint_support)
        self.register_buffer("C", C_ANNY_FROM_CANONICAL.to(dtype))
        self.faces = torch.as_tensor(model.faces, dtype=torch.int64)
        self.part_of_face = self._face_parts(model, labels)
        with torch.no_grad():
            rest = self._posed_canonical(self.mean_shape()[None], torch.zeros(1, len(BODY_JOINTS), 3))
        self._init_anatomy(rest[1][0].double().numpy())

    # -- construction helpers ----------------------------------------------------------------------
    def _init_keypoints(self, weights: torch.Tensor, support: int) -> None:
        """Keep each keypoint's `support` largest regression weights (renormalized): the shipped regressor
        spreads over 8,241 vertices, its top 64 per keypoint reproduce it within 0.3 mm and let a forward
        pass skin only the vertices it needs (see `forward(vertex_index=...)`)."""
        if 0 < support < weights.shape[1]:
            top = weights.abs().topk(support, dim=1).indices
            weights = torch.zeros_like(weights).scatter(1, top, weights.gather(1, top))
            weights = weights / weights.sum(dim=1, keepdim=True)
        self.register_buffer("kp_weights", weights)
        used = (weights != 0).any(dim=0).nonzero()[:, 0]
        self.register_buffer("kp_support", used)
        self.register_buffer("kp_sparse", weights[:, used])

    def _face_parts(self, model, labels: list[str]) -> torch.Tensor:
        parents = list(model.bone_parents)
        bone_part = []
        for b in range(len(labels)):
            i = b
            while labels[i] not in PART_ROOT_BONES:
                i = parents[i]
            bone_part.append(PART_INDEX[PART_ROOT_BONES[labels[i]]])
        weights = model.vertex_bone_weights
        dominant = model.vertex_bone_indices.gather(1, weights.argmax(dim=1, keepdim=True))[:, 0]
        vertex_part = torch.as_tensor(bone_part)[dominant]
        face_part = vertex_part[self.faces].mode(dim=1).values
        try:
            from anny.face_segmentation import get_face_segmentation_mask

            internal = get_face_segmentation_mask(model, list(_INTERNAL_SEGMENTS)).cpu()
            face_part[internal] = -1
        except Exception as exc:  # noqa: BLE001 - the segmentation is a refinement, not a requirement
            log.warning("Anny segmentation unavailable (%s); internal faces kept", exc)
        return face_part

    # -- model -------------------------------------------------------------------------------------
    def mean_shape(self) -> torch.Tensor:
        return torch.full((len(self.shape_names),), 0.5, dtype=self.kp_weights.dtype,
                          device=self.kp_weights.device)

    def shape_prior(self, shape: torch.Tensor) -> torch.Tensor:
        """Phenotypes near the population mean (0.5, spread `shape_sigma`) and inside [0, 1]."""
        near_mean = (((shape - 0.5) / self.shape_sigma) ** 2).sum(-1)
        outside = (torch.relu(-shape) + torch.relu(shape - 1.0)) ** 2
        return near_mean + self.shape_bound_weight * outside.sum(-1)

    def _posed_canonical(self, shape: torch.Tensor, pose: torch.Tensor, subset: _VertexSubset | None = None):
        """Vertices (all, or those of `subset`) and joints of the posed body in canonical axes, pelvis at the
        origin."""
        B = max(shape.shape[0], pose.shape[0])
        C = self.C.to(pose.dtype)
        rot = C @ roma.rotvec_to_rotmat(pose) @ C.T  # (B, J, 3, 3) in Anny axes
        deltas = torch.eye(4, dtype=pose.dtype, device=pose.device).repeat(B, len(self.anny.bone_labels), 1, 1)
        deltas[:, self.bone_index, :3, :3] = rot.expand(B, -1, -1, -1)
        if subset is None:
            out = self.anny(pose_parameters=deltas, phenotype_kwargs=shape.expand(B, -1))
            verts, bone_poses = out["vertices"], out["bone_poses"]
        else:  # Anny's forward, shaping and skinning only the requested vertices
            anny = self.anny
            no_changes = shape.new_zeros(B, 0)
            coeffs = anny._get_phenotype_blendshape_coefficients(shape.expand(B, -1), no_changes, no_changes)
            rest_vertices, rest_bone_poses = self._rest_subset(coeffs, subset)
            transforms, bone_poses = anny.get_bone_transforms(deltas, rest_bone_poses)
            verts = _skin(rest_vertices, subset.bone_weights, subset.bone_indices, transforms)
        pelvis = bone_poses[:, self.root_bone, :3, 3]  # (B, 3)
        verts = (verts - pelvis[:, None]) @ C  # C^T applied to row vectors
        joints = (bone_poses[:, self.bone_index, :3, 3] - pelvis[:, None]) @ C
        return verts, joints

    def _subset(self, vertex_index: torch.Tensor) -> _VertexSubset:
        """Anny's per-vertex data for the keypoint support followed by `vertex_index`, cached for the last
        index tensor: a fitting stage passes the same tensor on every step, and slicing 136 blend shapes
        costs as much as using them."""
        cached = self._subset_cache
        if cached is not None and cached.key is vertex_index:
            return cached
        anny = self.anny
        index = torch.cat([self.kp_support, vertex_index])
        subset = _VertexSubset(
            vertex_index,
            index,
            anny.template_vertices[index],
            anny.blendshapes[:, index].contiguous(),
            anny.vertex_bone_weights[index],
            anny.vertex_bone_indices[index],
        )
        self._subset_cache = subset
        return subset

    def _rest_subset(self, coeffs: torch.Tensor, subset: _VertexSubset) -> tuple[torch.Tensor, torch.Tensor]:
        """Rest vertices of `subset` and rest bone poses for blend-shape `coeffs` (B, C).

        `anny.get_rest_model` shapes all 13,718 vertices with 136 blend shapes, forward and backward, on
        every call: most of a fitting step. With the bone orientations Anny caches (its default), the bone
        poses do not depend on the vertices, so only the requested vertices are shaped here; the result
        equals `get_rest_model`'s (test_anny_subset_forward_matches_the_full_one).
        """
        anny = self.anny
        if anny.bone_orientation != "cached":
            rest = anny.get_rest_model(coeffs)
            return rest["rest_vertices"][:, subset.index], rest["rest_bone_poses"]
        from anny.skinning.skinning import apply_linear_blendshape

        rest_vertices = apply_linear_blendshape(subset.template, subset.blendshapes, coeffs)
        heads = apply_linear_blendshape(anny.template_bone_heads, anny.bone_heads_blendshapes, coeffs)
        M = anny.bone_template_orientation_matrices[None] + torch.einsum(
            "ba,akij->bkij", coeffs, anny.bone_orientation_blendshapes)
        orientation = roma.special_procrustes(M)
        if anny.rest_orientation_refiner is not None:
            orientation = anny.rest_orientation_refiner(orientation, heads)
        poses = roma.Rigid(linear=orientation, translation=heads).to_homogeneous()
        if anny.root_identity_orientation:
            poses[:, 0, :3, :3] = torch.eye(3, device=poses.device, dtype=poses.dtype)
        return rest_vertices, poses

    def forward(
        self,
        shape: torch.Tensor,
        pose: torch.Tensor,
        root_orient: torch.Tensor,
        transl: torch.Tensor,
        vertex_index: torch.Tensor | None = None,
    ) -> BodyOutput:
        if vertex_index is None:
            verts, joints = self._posed_canonical(shape, pose)
            kp_verts, kp_weights = verts, self.kp_weights
        else:
            n = len(self.kp_support)
            both, joints = self._posed_canonical(shape, pose, self._subset(vertex_index))
            kp_verts, verts, kp_weights = both[:, :n], both[:, n:], self.kp_sparse
        R = roma.rotvec_to_rotmat(root_orient)  # (B, 3, 3)
        verts = verts @ R.transpose(1, 2) + transl[:, None]
        joints = joints @ R.transpose(1, 2) + transl[:, None]
        keypoints = torch.einsum("kv,bvd->bkd", kp_weights.to(verts.dtype), kp_verts) @ R.transpose(1, 2)
        keypoints = keypoints + transl[:, None]
        return BodyOutput(verts, joints, keypoints)


def _skin(
    vertices: torch.Tensor, weights: torch.Tensor, indices: torch.Tensor, transforms: torch.Tensor
) -> torch.Tensor:
    """Linear blend skinning of (B, V, 3) rest vertices with (V, k) bone weights and indices and (B, J, 4, 4)
    bone transforms, in plain torch: for the few thousand vertices a fitting step poses this is several
    times faster than Anny's Warp kernel, whose per-call overhead dominates at that size."""
    T = (transforms[:, indices] * weights[None, ..., None, None]).sum(2)  # (B, V, 4, 4)
    return (T[..., :3, :3] @ vertices[..., None])[..., 0] + T[..., :3, 3]
