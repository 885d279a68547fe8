"""The interface every body model implements, and the priors they share.

Convention for all models: `forward(shape, pose, root_orient, transl)` takes batch-first tensors
(B, S), (B, J, 3), (B, 3), (B, 3) and returns a `BodyOutput` in the camera frame. `pose` rows follow
`joint_names` (see `body.joints.BODY_JOINTS`), axis-angle in the canonical body axes (x: body left,
y: up, z: forward); `root_orient` rotates those axes into the camera frame.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from smplify3d_ros.body.joints import BENDING_JOINTS, BODY_JOINTS, AnatomicalFrames, anatomical_frames
from smplify3d_ros.keypoints import PART_DRIVING_JOINTS, PART_NAMES
from smplify3d_ros.types import BodyParams

PARAM_FIELDS = ("shape", "pose", "root_orient", "transl")  # BodyParams fields, in `forward`'s order


@dataclass
class BodyOutput:
    vertices: torch.Tensor  # (B, V, 3) m, camera frame
    joints: torch.Tensor  # (B, J, 3) positions of `joint_names`, m, camera frame
    keypoints: torch.Tensor  # (B, 17, 3) COCO-17 keypoints, m, camera frame


@dataclass
class BodyLinearization:
    """A posed body and its first derivatives, for Gauss-Newton solvers (`fitting.solver`).

    Columns of the Jacobians: the pose (J x 3, row-major as `pose`), then root_orient (3), then transl
    (3). Shape derivatives are not included (the solver takes them by finite differences: a handful of
    phenotypes or betas, against 63 rotation parameters). Vertex Jacobians come by row
    (`vertex_jacobian`), since a solver needs those of the few vertices its residuals touch.
    """

    vertices: torch.Tensor  # (B, n, 3) the requested vertices, camera frame
    keypoints: torch.Tensor  # (B, 17, 3) COCO-17, camera frame
    d_keypoints: torch.Tensor  # (B, 17, 3, P) d keypoints / d [pose, root_orient, transl]
    vertex_jacobian: Callable[[torch.Tensor], torch.Tensor]  # (B, r) rows of `vertices` -> (B, r, 3, P)


def left_jacobian_so3(rotvec: torch.Tensor) -> torch.Tensor:
    """(..., 3) axis-angle -> (..., 3, 3) left Jacobian J_l of SO(3): d exp(θ + dθ) = [J_l dθ]x exp(θ).

    J_l = I + (1 - cos t)/t² [θ]x + (t - sin t)/t³ [θ]x², with Taylor series near t = 0 where the closed
    form loses precision.
    """
    t2 = (rotvec**2).sum(-1, keepdim=True)[..., None]  # (..., 1, 1)
    t = t2.clamp(min=1e-12).sqrt()
    small = t2 < 1e-6
    a = torch.where(small, 0.5 - t2 / 24.0, (1.0 - torch.cos(t)) / t2.clamp(min=1e-12))
    b = torch.where(small, 1.0 / 6.0 - t2 / 120.0, (t - torch.sin(t)) / (t2 * t).clamp(min=1e-18))
    x, y, z = rotvec.unbind(-1)
    zero = torch.zeros_like(x)
    skew = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], -1).reshape(*rotvec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device).expand_as(skew)
    return eye + a * skew + b * (skew @ skew)


@dataclass
class PosedBody:
    """One body's geometry in numpy (float64), camera frame, m."""

    vertices: np.ndarray  # (V, 3)
    joints: np.ndarray  # (J, 3) positions of the model's `joint_names`
    keypoints3d: np.ndarray  # (17, 3) COCO-17
    rotation_center: np.ndarray  # (3,) the point `root_orient` rotates the body about


class BodyModel(torch.nn.Module):
    """Base class: subclasses set the attributes below and implement `forward` and `shape_prior`."""

    name: str
    joint_names: tuple[str, ...] = BODY_JOINTS
    # True: `forward` and `linearize` take a (B, n) `vertex_index`, one vertex set per body, and return
    # those; False: one (n,) set for the whole batch (callers pass the union and pick their rows)
    vertices_per_row: bool = False
    shape_names: tuple[str, ...]
    faces: torch.Tensor  # (F, 3) int64
    part_of_face: torch.Tensor  # (F,) int64 index into keypoints.PART_NAMES, -1 for faces never used

    # -- set by `_init_anatomy` from the rest joint positions --------------------------------------
    anatomy: AnatomicalFrames

    def _init_anatomy(self, rest_joints_canonical: np.ndarray) -> None:
        self.anatomy = anatomical_frames(rest_joints_canonical)
        dtype = torch.get_default_dtype()
        self.register_buffer("anat_frames", torch.as_tensor(self.anatomy.frames, dtype=dtype))
        self.register_buffer("anat_ranges", torch.as_tensor(self.anatomy.ranges, dtype=dtype))
        self.register_buffer("anat_rest", torch.as_tensor(self.anatomy.rest_offset, dtype=dtype))
        self.bending_index = [self.joint_names.index(n) for n in BENDING_JOINTS]
        # joints driving each part, as indices (for the occlusion prior)
        self.part_joint_index = [
            [self.joint_names.index(j) for j in PART_DRIVING_JOINTS[p]] for p in PART_NAMES
        ]

    @property
    def joint_ranges(self) -> torch.Tensor:
        """(J, 3, 2) rad: [min, max] of [flexion, twist, abduction] relative to the rest pose."""
        return self.anat_ranges

    def mean_shape(self) -> torch.Tensor:
        """The shape prior's mean, from which built-in fits start."""
        raise NotImplementedError

    def reference_shape(self) -> torch.Tensor:
        """A fixed body of the model, independent of the prior's settings (the simulator's HMR shrinks
        its shapes towards it); by default the mean."""
        return self.mean_shape()

    def rotation_center(self, shape: torch.Tensor, transl: torch.Tensor) -> torch.Tensor:
        """(B, 3) camera-frame point that `root_orient` rotates the body about (Anny: the pelvis,
        which `transl` places; SMPL: its root joint j0(β) + transl)."""
        return transl

    def shape_prior(self, shape: torch.Tensor) -> torch.Tensor:
        """(B, S) -> (B,) L_β."""
        raise NotImplementedError

    def shape_prior_residuals(self, shape: torch.Tensor) -> torch.Tensor:
        """(B, S) -> (B, R) residuals whose squares sum to `shape_prior` (for least-squares solvers).
        This fallback is the square root of the prior itself; models with a sum-of-squares prior return
        its terms."""
        return self.shape_prior(shape).clamp(min=0.0).sqrt()[:, None]

    # The optimizers work on unconstrained shape coordinates: a model whose shape parameters live in a
    # bounded range (Anny's phenotypes in [0, 1]) maps them through a bijection, so that no step, however
    # large, leaves the range. The default is the identity (SMPL's betas are unbounded).
    def shape_from_free(self, free: torch.Tensor) -> torch.Tensor:
        """Unconstrained coordinates -> the model's shape parameters."""
        return free

    def shape_to_free(self, shape: torch.Tensor) -> torch.Tensor:
        """The model's shape parameters -> unconstrained coordinates (inverse of `shape_from_free`)."""
        return shape

    def forward(  # noqa: D401 - torch signature
        self,
        shape: torch.Tensor,
        pose: torch.Tensor,
        root_orient: torch.Tensor,
        transl: torch.Tensor,
        vertex_index: torch.Tensor | None = None,
    ) -> BodyOutput:
        """With `vertex_index` (n,), `vertices` holds only those vertices, (B, n, 3): a model may then
        skip the others (Anny does), which makes optimizer iterations several times cheaper."""
        raise NotImplementedError

    def linearize(
        self,
        shape: torch.Tensor,
        pose: torch.Tensor,
        root_orient: torch.Tensor,
        transl: torch.Tensor,
        vertex_index: torch.Tensor,
    ) -> BodyLinearization:
        """The body at these parameters with its Jacobians (`BodyLinearization`), for the vertices
        `vertex_index` (n,). This generic version differentiates `forward` in forward mode, one pass per
        parameter: correct for any model, but tens of times slower than a model's own (Anny's is analytic)."""
        B, J = pose.shape[:2]

        def flat(x: torch.Tensor) -> torch.Tensor:
            p, r, t = x[..., : 3 * J].reshape(-1, J, 3), x[..., 3 * J : 3 * J + 3], x[..., 3 * J + 3 :]
            out = self(shape, p, r.reshape(-1, 3), t.reshape(-1, 3), vertex_index)
            return torch.cat([out.vertices, out.keypoints], 1)

        x = torch.cat([pose.reshape(B, -1), root_orient, transl], -1).detach()
        with torch.no_grad():
            values = flat(x)
        jac = torch.func.jacfwd(flat)(x)  # (B, n + 17, 3, B, P): rows of other people are zero
        jac = jac[torch.arange(B), :, :, torch.arange(B)]  # (B, n + 17, 3, P)
        n = vertex_index.shape[-1]  # (n,) or, for a per-row model, (B, n)
        d_vertices = jac[:, :n]

        def rows(index: torch.Tensor) -> torch.Tensor:
            return torch.gather(d_vertices, 1, index[..., None, None].expand(-1, -1, *d_vertices.shape[2:]))

        return BodyLinearization(values[:, :n], values[:, n:], jac[:, n:], rows)

    # -- BodyParams in, numpy out -------------------------------------------------------------------
    @property
    def dtype(self) -> torch.dtype:
        return self.anat_frames.dtype

    @property
    def device(self) -> torch.device:
        return self.anat_frames.device

    def params_tensors(self, params: Sequence[BodyParams]) -> list[torch.Tensor]:
        """(shape, pose, root_orient, transl) of several bodies as (B, ...) tensors in the model's dtype
        and on its device."""
        return [torch.as_tensor(np.stack([np.asarray(getattr(p, f), np.float64) for p in params]),
                                dtype=self.dtype, device=self.device) for f in PARAM_FIELDS]

    def forward_params(self, params: Sequence[BodyParams]) -> BodyOutput:
        """The batched forward of several bodies' parameters, without gradients."""
        with torch.no_grad():
            return self(*self.params_tensors(params))

    def posed(self, params: Sequence[BodyParams]) -> list[PosedBody]:
        """Geometry of each body, in numpy (float64)."""
        if not params:
            return []
        out = self.forward_params(params)
        shape, _, _, transl = self.params_tensors(params)
        with torch.no_grad():
            centers = self.rotation_center(shape, transl)
        as_np = [t.cpu().double().numpy() for t in (out.vertices, out.joints, out.keypoints, centers)]
        return [PosedBody(*(a[i] for a in as_np)) for i in range(len(params))]

    # -- anatomical coordinates --------------------------------------------------------------------
    def pose_to_anatomical(self, pose: torch.Tensor) -> torch.Tensor:
        """(B, J, 3) axis-angle -> (B, J, 3) [flexion, twist, abduction] rad relative to rest
        (exact for rotations about one anatomical axis, a first-order approximation otherwise)."""
        return torch.einsum("jab,...jb->...ja", self.anat_frames.to(pose.dtype), pose)

    def anatomical_to_pose(self, angles: torch.Tensor, from_neutral: bool = False) -> torch.Tensor:
        """Inverse of `pose_to_anatomical`. With `from_neutral`, angles are measured from the
        anatomical neutral (limbs straight and hanging) instead of the model's rest pose."""
        if from_neutral:
            angles = angles - self.anat_rest.to(angles.dtype)
        return torch.einsum("jba,...jb->...ja", self.anat_frames.to(angles.dtype), angles)

    # -- priors shared by all models -----------------------------------------------------------------
    def joint_range_prior(self, pose: torch.Tensor) -> torch.Tensor:
        """(B, J, 3) -> (B,): squared excess (rad²) of each anatomical angle outside its range."""
        anat = self.pose_to_anatomical(pose)
        lo, hi = self.anat_ranges[..., 0].to(pose.dtype), self.anat_ranges[..., 1].to(pose.dtype)
        excess = torch.relu(lo - anat) + torch.relu(anat - hi)
        return (excess**2).sum(dim=(-1, -2))

    def pose_prior(self, pose: torch.Tensor) -> torch.Tensor:
        """L_θ: the anatomical joint-range prior (models with a learned prior override this)."""
        return self.joint_range_prior(pose)

    def pose_prior_residuals(self, pose: torch.Tensor) -> torch.Tensor:
        """(B, J, 3) -> (B, R) residuals whose squares sum to `pose_prior`: the joint-range excesses, or
        the square root of a model's own prior (SMPL's GMM), a one-residual fallback."""
        if type(self).pose_prior is not BodyModel.pose_prior and getattr(self, "gmm", None) is not None:
            return self.pose_prior(pose).clamp(min=0.0).sqrt()[:, None]
        anat = self.pose_to_anatomical(pose)
        lo, hi = self.anat_ranges[..., 0].to(pose.dtype), self.anat_ranges[..., 1].to(pose.dtype)
        return (torch.relu(lo - anat) + torch.relu(anat - hi)).flatten(1)

    def neutral_residuals(self, pose: torch.Tensor) -> torch.Tensor:
        """(B, J, 3) -> (B, 3J): each anatomical angle's distance from the anatomical neutral (standing,
        limbs straight and hanging) in units of its range of motion, so that a stiff joint (a knee's
        twist) is held more than a loose one (a shoulder's flexion). Its squared sum is a Gaussian prior
        on the pose: for a limb the image sees end-on it picks the least turned of the poses that project
        alike. Linear in the axis-angle (`pose_to_anatomical`)."""
        anat = self.pose_to_anatomical(pose) + self.anat_rest.to(pose.dtype)
        width = (self.anat_ranges[..., 1] - self.anat_ranges[..., 0]).to(pose.dtype).clamp(min=1e-3)
        return (anat / width).flatten(1)

    def bending_prior(self, pose: torch.Tensor) -> torch.Tensor:
        """L_a (Eq. 5): Σ exp(−flexion) over elbows and knees, flexion measured from straight, so that
        hyper-extension (negative flexion) is penalised exponentially."""
        return (self.bending_residuals(pose) ** 2).sum(dim=-1)

    def bending_residuals(self, pose: torch.Tensor) -> torch.Tensor:
        """(B, 4) exp(−flexion / 2): residuals whose squares sum to `bending_prior`."""
        index = self.bending_index
        flexion_axes = self.anat_frames[index, 0].to(pose.dtype)  # (4, 3)
        flexion = (pose[:, index] * flexion_axes).sum(-1) + self.anat_rest[index, 0].to(pose.dtype)
        return torch.exp(-0.5 * flexion)
