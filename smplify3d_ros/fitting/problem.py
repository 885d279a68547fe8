"""What one batched fit works on: the bodies' parameters being optimized (`FitState`) and the people's
observations (`FitProblem`), row i of every tensor being person i; `posed_rows` poses them for a loss."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from smplify3d_ros.body.base import PARAM_FIELDS, BodyModel, BodyOutput
from smplify3d_ros.fitting.free_space import BlockedBeams

PARAM_NAMES = PARAM_FIELDS  # FitState fields, in BodyModel.forward order


@dataclass
class FitState:
    """Batched body parameters being optimized, (B, ...) each.

    `shape` holds the model's unconstrained shape coordinates (`BodyModel.shape_from_free`: Anny's
    phenotype logits), so that no optimizer step can leave the model's shape range.
    """

    shape: torch.Tensor
    pose: torch.Tensor
    root_orient: torch.Tensor
    transl: torch.Tensor

    @classmethod
    def from_params(cls, model: BodyModel, params) -> FitState:
        shape, pose, root_orient, transl = model.params_tensors(params)
        return cls(model.shape_to_free(shape), pose, root_orient, transl)

    def body_args(self, model: BodyModel) -> tuple[torch.Tensor, ...]:
        """(shape, pose, root_orient, transl) as the model takes them."""
        return model.shape_from_free(self.shape), self.pose, self.root_orient, self.transl

    def clone(self) -> FitState:
        return FitState(*(getattr(self, n).detach().clone() for n in PARAM_NAMES))

    def take(self, rows: torch.Tensor) -> FitState:
        """A copy of the people `rows` (int64 positions)."""
        return FitState(*(getattr(self, n).detach()[rows].clone() for n in PARAM_NAMES))

    def copy_rows_from_subset(self, other: FitState, rows: torch.Tensor) -> None:
        """Rows `rows` of this state from `other`'s rows 0..len(rows)-1 (the inverse of `take`)."""
        with torch.no_grad():
            for n in PARAM_NAMES:
                getattr(self, n)[rows] = getattr(other, n)

    def copy_rows_from(self, other: FitState, rows: torch.Tensor) -> None:
        with torch.no_grad():
            for n in PARAM_NAMES:
                getattr(self, n)[rows] = getattr(other, n)[rows]


@dataclass
class FitProblem:
    """The batched observations, (B, ...) each; B people of one frame."""

    K: torch.Tensor  # (3, 3) intrinsics of the undistorted image
    keypoints: torch.Tensor  # (B, 17, 2) px
    confidence: torch.Tensor  # (B, 17)
    points: torch.Tensor  # (B, m, 3) the person's LiDAR points (padded)
    point_mask: torch.Tensor  # (B, m)
    vertex_subset: torch.Tensor  # (s,) every vertex any person's L_3D uses: the only ones posed per step
    vertex_index: torch.Tensor  # (B, n) each person's L_3D vertices, as positions in `vertex_subset`
    vertex_mask: torch.Tensor  # (B, n)
    occluded_joints: torch.Tensor  # (B, J) joints driving image-occluded parts (L_θocc)
    init_pose: torch.Tensor  # (B, J, 3) the pose L_θocc holds occluded parts to
    use_lidar: torch.Tensor  # (B,) bool: enough points for the 3D term
    pixel_scale: torch.Tensor | None = None  # (B,) factor on each person's pixel residuals (None: 1)
    neutral_scale: torch.Tensor | None = None  # (B,) factor on weights.neutral per person (None: 1)
    lidar_gain: torch.Tensor | None = None  # (B,) factor on λ_3D² per person where a stage takes it (None: 1)
    empty_subset: torch.Tensor | None = None  # (0,) int64: no vertex (one tensor, so model caches hold)
    keypoint_depth: torch.Tensor | None = None  # (B, 17) camera-z targets of limb keypoints (NaN: none)
    vertex_ids: torch.Tensor | None = None  # (B, n) each person's L_3D vertices as model vertex ids
    up: torch.Tensor | None = None  # (B, 3) the world's up in the camera frame (ground normal, else −y)
    _copies: dict = field(default_factory=dict, repr=False)  # `repeated`'s problems, by count
    init_transl: torch.Tensor | None = None  # (B, 3) the translation at the start (image-only depth hold)
    depth_measured: torch.Tensor | None = None  # (B,) bool: people without L_3D whose few points gave the depth
    depth_bound: torch.Tensor | None = None  # (B,) depth the scan bounds people without L_3D to (inf: none)
    predicted_transl: torch.Tensor | None = None  # (B, 3) the motion hold's translations (NaN rows: none)
    predicted_keypoints: torch.Tensor | None = None  # (B, 17, 3) the joint motion hold's joints (NaN rows: none)
    lidar_origin: torch.Tensor | None = None  # (3,) the LiDAR in the camera frame: where its beams start
    # (state) -> the beams its bodies block short of their points (`weights.free_space`), None: not cast
    cast_beams: Callable[[FitState], BlockedBeams | None] | None = None
    blocked: BlockedBeams | None = None  # the beams the last cast found blocked

    def __post_init__(self) -> None:
        if self.empty_subset is None:
            self.empty_subset = self.vertex_subset[:0].clone()
        if self.vertex_ids is None:
            self.vertex_ids = self.vertex_subset[self.vertex_index] if len(self.vertex_subset) else self.vertex_index


    def repeated(self, count: int) -> FitProblem:
        """Every person `count` times in a row (the shape Jacobian's perturbed copies), made once: the same
        tensors on every step keep the body model's vertex-set caches valid."""
        if count not in self._copies:
            self._copies[count] = self.take(torch.arange(len(self.use_lidar), device=self.K.device
                                                         ).repeat_interleave(count))
        return self._copies[count]

    def take(self, rows: torch.Tensor) -> FitProblem:
        """The problem of the people `rows` (repeats allowed): the shape Jacobian's perturbed copies."""
        shared = ("K", "vertex_subset", "empty_subset", "lidar_origin", "cast_beams")
        picked = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "_copies"}
        for name, value in picked.items():
            if name not in shared and value is not None:
                picked[name] = value[rows]
        return FitProblem(**picked)


def posed_rows(model: BodyModel, args: tuple[torch.Tensor, ...], problem: FitProblem, with_vertices: bool
               ) -> BodyOutput:
    """The bodies of `args` with, as `vertices`, each person's own L_3D vertices (B, n, 3) (none without
    `with_vertices`): a model that poses a vertex set per body does so directly, another poses the
    batch's union and each person picks theirs."""
    if not with_vertices:
        return model(*args, problem.empty_subset)
    if model.vertices_per_row:
        return model(*args, problem.vertex_ids)
    out = model(*args, problem.vertex_subset)
    rows = torch.gather(out.vertices, 1, problem.vertex_index[..., None].expand(-1, -1, 3))
    return BodyOutput(rows, out.joints, out.keypoints)
