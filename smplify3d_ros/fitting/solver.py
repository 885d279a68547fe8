"""Levenberg-Marquardt for the fitting stages: the same objective as Adam's (`stages.stage_loss`), solved
by damped Gauss-Newton steps on its residuals.

Why: from the built-in initializer (limbs off by tens of degrees, the body by decimetres) Adam needs
hundreds of steps of a fixed size, and the priors that keep it from wandering also keep it from
arriving. A Gauss-Newton step jumps to the minimum of the local quadratic model, so a few steps reach
what a hundred Adam steps do not, and the damping (Marquardt: μ times the diagonal of JᵀJ, raised when a
step fails, lowered when it succeeds) keeps it safe far from the minimum.

Every term of `stage_loss` is written as residuals whose squares sum to it:
- L_J: per keypoint coordinate c·√w·e, e the (aligned, size-normalised) pixel error and w = σ⁴/(σ²+e²)²
  the Geman-McClure weight at e (iteratively reweighted least squares: Σ c² w e² = Σ c² ρ(e) at e);
- L_3D: each point's offset from its nearest visible vertex (and, with `chamfer_vertex_weight`, each
  vertex's offset from its nearest point), correspondences found again at every step (as ICP does);
- priors: the joint-range excesses, exp(−flexion/2) for L_a, the shape prior's terms, and for L_θocc the
  vector part of q₀⁻¹q, whose squared norm is 1 − ⟨q, q₀⟩².
Jacobians: the body model's own (`BodyModel.linearize`: analytic for Anny) for pose, root orientation
and translation; finite differences for the shape (a few coordinates); forward-mode autodiff for the
priors. Steps are accepted only when the exact stage loss decreases, so LM never ends worse than it
started; each person has its own damping and stops on its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import roma
import torch

from smplify3d_ros.body.base import BodyModel
from smplify3d_ros.fitting import free_space, losses
from smplify3d_ros.fitting.config import OptimizerProfile
from smplify3d_ros.fitting.problem import posed_rows

SHAPE_STEP = 1e-2  # finite-difference step on the unconstrained shape coordinates (logits for Anny)
DAMPING_UP, DAMPING_DOWN, DAMPING_MAX = 10.0, 3.0, 1e6  # μ after a failed / successful step; give up above
RIDGE = 1e-2  # fixed damping, as a fraction of the mean curvature (see `damped_step`)
MAX_ROTATION_STEP = 0.5  # rad: no step turns a joint (or the root) by more
MAX_TRANSLATION_STEP = 0.5  # m: no step moves the body by more


@dataclass
class Layout:
    """Columns of one person's parameter vector: pose (3J), root_orient (3), transl (3), shape (S)."""

    joints: int
    shapes: int
    active: torch.Tensor  # (P,) bool: the columns the stage optimizes

    @classmethod
    def of(cls, model: BodyModel, params: tuple[str, ...], device) -> Layout:
        J, S = len(model.joint_names), len(model.shape_names)
        active = torch.zeros(3 * J + 6 + S, dtype=torch.bool, device=device)
        spans = {"pose": (0, 3 * J), "root_orient": (3 * J, 3 * J + 3), "transl": (3 * J + 3, 3 * J + 6),
                 "shape": (3 * J + 6, 3 * J + 6 + S)}
        for name in params:
            a, b = spans[name]
            active[a:b] = True
        return cls(J, S, active)

    @property
    def size(self) -> int:
        return 3 * self.joints + 6 + self.shapes

    @property
    def shape_active(self) -> bool:
        return bool(self.active[3 * self.joints + 6 :].any())


class Residuals:
    """Accumulates JᵀJ and Jᵀr (float64) over residual blocks (B, R) with Jacobians (B, R, P)."""

    def __init__(self, batch: int, size: int, device) -> None:
        self.JtJ = torch.zeros(batch, size, size, dtype=torch.float64, device=device)
        self.Jtr = torch.zeros(batch, size, dtype=torch.float64, device=device)

    def add(self, r: torch.Tensor, J: torch.Tensor) -> None:
        r, J = r.double(), J.double()
        self.JtJ += J.transpose(1, 2) @ J
        self.Jtr += (J.transpose(1, 2) @ r[..., None])[..., 0]


# -- the body and its derivatives ------------------------------------------------------------------------
@dataclass
class Linearized:
    """The body at the current state, with derivatives over the whole layout (shape included)."""

    vertices: torch.Tensor  # (B, n, 3) each person's L_3D vertices (`FitProblem.vertex_ids`)
    keypoints: torch.Tensor  # (B, 17, 3)
    d_keypoints: torch.Tensor  # (B, 17, 3, P)
    rows: Callable[[torch.Tensor], torch.Tensor] | None  # (B, r) positions in `vertices` -> (B, r, 3, P63)
    shape_rows: Callable[[torch.Tensor], torch.Tensor] | None  # (B, r) -> (B, r, 3, S); None: shape fixed
    translation_only: bool
    _nearest: tuple | None = None  # `nearest`'s result, found once per linearization

    def nearest(self, problem, both: bool) -> tuple[torch.Tensor, torch.Tensor | None]:
        """`losses.nearest_indices` of the problem's points and these vertices (and back, with `both`):
        the stage loss of a candidate and the normal equations at it share them."""
        if self._nearest is None or (both and self._nearest[1] is None):
            self._nearest = losses.nearest_indices(problem.points, self.vertices, problem.vertex_mask,
                                                   problem.point_mask if both else None)
        return self._nearest if both else (self._nearest[0], None)

    def vertex_jacobian(self, rows: torch.Tensor, layout: Layout) -> torch.Tensor:
        """(B, r) positions in `vertices` -> (B, r, 3, P)."""
        B, r = rows.shape
        if self.translation_only:
            J = self.vertices.new_zeros(B, r, 3, layout.size)
            J[..., 3 * layout.joints + 3 : 3 * layout.joints + 6] = torch.eye(3, dtype=J.dtype, device=J.device)
            return J
        J = self.rows(rows)
        if self.shape_rows is None:
            return torch.cat([J, J.new_zeros(B, r, 3, layout.shapes)], -1)
        return torch.cat([J, self.shape_rows(rows)], -1)


def linearize(model: BodyModel, state, problem, use_chamfer: bool, layout: Layout,
              translated=None) -> Linearized:
    """The body and its Jacobians. `translated` (a `stages._Translated`): the stage moves the
    translation only, the posed body is fixed and its Jacobian the identity."""
    args = state.body_args(model)
    B = args[1].shape[0]
    if translated is not None:
        with torch.no_grad():
            out = translated(*args)
        d_kp = out.keypoints.new_zeros(B, 17, 3, layout.size)
        d_kp[..., 3 * layout.joints + 3 : 3 * layout.joints + 6] = torch.eye(3, dtype=d_kp.dtype)
        return Linearized(out.vertices, out.keypoints, d_kp, None, None, True)
    with torch.no_grad():
        if not use_chamfer:
            lin = model.linearize(*args, problem.empty_subset)
            vertices, rows = lin.vertices, lin.vertex_jacobian
        elif model.vertices_per_row:
            lin = model.linearize(*args, problem.vertex_ids)
            vertices, rows = lin.vertices, lin.vertex_jacobian
        else:  # the union, each person's rows picked from it
            lin = model.linearize(*args, problem.vertex_subset)
            index = problem.vertex_index
            vertices = torch.gather(lin.vertices, 1, index[..., None].expand(-1, -1, 3))

            def rows(r: torch.Tensor, lin=lin, index=index) -> torch.Tensor:
                return lin.vertex_jacobian(torch.gather(index, 1, r))
        d_kp = torch.cat([lin.d_keypoints, lin.d_keypoints.new_zeros(B, 17, 3, layout.shapes)], -1)
        shape_rows = None
        if layout.shape_active:
            shape_rows, d_kp_shape = _shape_jacobian(model, state, problem, use_chamfer, vertices, lin.keypoints)
            d_kp[..., 3 * layout.joints + 6 :] = d_kp_shape
    return Linearized(vertices, lin.keypoints, d_kp, rows, shape_rows, False)


def _shape_jacobian(model: BodyModel, state, problem, use_chamfer: bool, vertices: torch.Tensor,
                    keypoints: torch.Tensor):
    """Forward differences in the unconstrained shape coordinates: the keypoints' now, in one batched
    pass of keypoints only; the vertices' by row, when a residual block asks (a per-row model poses
    just those rows, a few dozen for a VLP-16, instead of the whole L_3D set six times)."""

    B, S = state.shape.shape
    free = state.shape[:, None, :] + SHAPE_STEP * torch.eye(S, dtype=state.shape.dtype, device=state.shape.device)
    shapes = model.shape_from_free(free.reshape(B * S, S))
    rep = [t.repeat_interleave(S, 0) for t in (state.pose, state.root_orient, state.transl)]
    repeated = problem.repeated(S)
    per_row = model.vertices_per_row
    out = posed_rows(model, (shapes, *rep), repeated, use_chamfer and not per_row)
    d_kp = ((out.keypoints.reshape(B, S, -1, 3) - keypoints[:, None]) / SHAPE_STEP).permute(0, 2, 3, 1)

    def rows(index: torch.Tensor) -> torch.Tensor:
        base = torch.gather(vertices, 1, index[..., None].expand(-1, -1, 3))
        if per_row:
            ids = torch.gather(problem.vertex_ids, 1, index).repeat_interleave(S, 0)
            moved = model(shapes, *rep, ids).vertices
        else:
            moved = torch.gather(out.vertices, 1, index.repeat_interleave(S, 0)[..., None].expand(-1, -1, 3))
        d = (moved.reshape(B, S, -1, 3) - base[:, None]) / SHAPE_STEP
        return d.permute(0, 2, 3, 1)

    return rows, d_kp


# -- residual blocks -------------------------------------------------------------------------------------
def keypoint_block(body: Linearized, problem, stage, acc: Residuals) -> None:
    """L_J's IRLS residuals (module docstring)."""
    X = body.keypoints
    K = problem.K if problem.K.dim() == 3 else problem.K[None]
    fx, fy = K[:, 0, 0][:, None], K[:, 1, 1][:, None]
    z = X[..., 2].clamp(min=1e-3)
    projected = losses.project(X, problem.K)
    d_proj = X.new_zeros(*X.shape[:2], 2, 3)  # (B, 17, 2, 3)
    d_proj[..., 0, 0] = fx / z
    d_proj[..., 0, 2] = -fx * X[..., 0] / z**2
    d_proj[..., 1, 1] = fy / z
    d_proj[..., 1, 2] = -fy * X[..., 1] / z**2
    J = d_proj @ body.d_keypoints  # (B, 17, 2, P)
    e = projected - problem.keypoints
    c = problem.confidence
    if stage.align is not None:
        weights = _alignment_weights(c, stage.align)  # (B, 17): e_aligned = e − Σ_j a_j e_j
        e = e - (weights[..., None] * e).sum(1, keepdim=True)
        J = J - (weights[..., None, None] * J).sum(1, keepdim=True)
    if problem.pixel_scale is not None:
        e = e * problem.pixel_scale[:, None, None]
        J = J * problem.pixel_scale[:, None, None, None]
    sigma2 = stage.sigma_px**2
    root_w = sigma2 / (sigma2 + e**2)  # √(σ⁴ / (σ² + e²)²)
    scale = c[..., None] * root_w
    acc.add((scale * e).flatten(1), (scale[..., None] * J).flatten(1, 2))


def _alignment_weights(confidence: torch.Tensor, align: str) -> torch.Tensor:
    """The weights a_j with which `losses.alignment_shift` averages the keypoint offsets."""
    if align == "hips":
        w = torch.zeros_like(confidence)
        w[:, 11] = w[:, 12] = 0.5
        return w
    w = confidence**2
    return w / w.sum(-1, keepdim=True).clamp(min=torch.finfo(w.dtype).tiny)


def chamfer_block(body: Linearized, problem, stage, profile: OptimizerProfile, layout: Layout,
                  acc: Residuals) -> None:
    """L_3D's residuals: each point to its nearest visible vertex (and back, with the vertex weight)."""
    if not uses_chamfer(stage, problem):
        return
    weight = _w(stage.chamfer_weight, profile) * problem.use_lidar.to(body.vertices.dtype)  # (B,)
    weight = weight * chamfer_gain(stage, problem)
    vmask, points, pmask = problem.vertex_mask, problem.points, problem.point_mask
    visible = body.vertices
    has = (vmask.any(-1) & pmask.any(-1)).to(weight.dtype)
    want_back = profile.chamfer_vertex_weight > 0
    p_index, v_index = body.nearest(problem, want_back)
    m = pmask.sum(-1).clamp(min=1).to(weight.dtype)
    scale = ((weight * has / m).sqrt()[:, None] * pmask)[..., None]  # (B, m, 1)
    r = scale * (torch.gather(visible, 1, p_index[..., None].expand(-1, -1, 3)) - points)
    J = scale[..., None] * body.vertex_jacobian(p_index, layout)
    acc.add(r.flatten(1), J.flatten(1, 2))
    if want_back:
        n = vmask.sum(-1).clamp(min=1).to(weight.dtype)
        scale = ((weight * has * profile.chamfer_vertex_weight / n).sqrt()[:, None] * vmask)[..., None]
        r = scale * (visible - torch.gather(points, 1, v_index[..., None].expand(-1, -1, 3)))
        all_rows = torch.arange(visible.shape[1], device=visible.device).expand(visible.shape[0], -1)
        J = scale[..., None] * body.vertex_jacobian(all_rows, layout)
        acc.add(r.flatten(1), J.flatten(1, 2))


def uses_free_space(stage, problem, profile: OptimizerProfile) -> bool:
    """The stage keeps the body out of the beams' free space: it has L_3D, beams to cast and moves the
    pose. Only the limbs answer a blocked beam: in a stage that moves the translation alone, the whole
    body stepped back from a hand held towards the sensor (tuning seed 1: 18 cm, off its points)."""
    return (profile.weights.free_space > 0 and problem.cast_beams is not None and "pose" in stage.params
            and uses_chamfer(stage, problem))


def free_space_block(body: Linearized, problem, stage, profile: OptimizerProfile, layout: Layout,
                     acc: Residuals) -> None:
    """L_free's residuals: each blocked beam's shortfall (`free_space.shortfall`), its Jacobian its
    vertex's along the beam."""
    if not uses_free_space(stage, problem, profile) or problem.blocked is None:
        return
    beams = problem.blocked
    weight = _w(profile.weights.free_space, profile) * problem.use_lidar.to(body.vertices.dtype)
    m = problem.point_mask.sum(-1).clamp(min=1).to(weight.dtype)
    short = free_space.shortfall(body.vertices, beams, problem.lidar_origin)  # (B, k)
    scale = (weight / m).sqrt()[:, None] * (short < 0)
    J = scale[..., None] * torch.einsum("bkc,bkcp->bkp", beams.direction, body.vertex_jacobian(beams.rows, layout))
    acc.add(scale * short, J)


def prior_block(model: BodyModel, state, problem, stage, profile: OptimizerProfile, layout: Layout,
                acc: Residuals) -> None:
    """The priors' residuals and their Jacobians (they depend on pose and shape only)."""
    if not (stage.priors or stage.shape_only_prior):
        return
    w = profile.weights
    J3 = 3 * layout.joints
    B = state.pose.shape[0]
    r, d_free = shape_prior_linearized(model, state.shape)
    J = r.new_zeros(B, r.shape[1], layout.size)
    J[..., J3 + 6 :] = d_free
    acc.add(_w(w.shape, profile) ** 0.5 * r, _w(w.shape, profile) ** 0.5 * J)
    if not stage.priors:
        return
    if w.upright > 0 and problem.up is not None:
        r, d_root = upright_linearized(state.root_orient, problem.up)
        J = r.new_zeros(B, 3, layout.size)
        J[..., J3 : J3 + 3] = d_root
        acc.add(_w(w.upright, profile) ** 0.5 * r, _w(w.upright, profile) ** 0.5 * J)
    pose = state.pose
    terms = [(w.pose, *range_prior_linearized(model, pose)), (w.bend, *bending_linearized(model, pose))]
    if w.neutral > 0:
        terms.append((neutral_weight(w, problem), *neutral_linearized(model, pose, profile.neutral_robust_scale)))
    if not stage.hold:
        _add_pose_terms(terms, B, layout, profile, acc)
        return
    occluded = problem.occluded_joints
    r, d = held_linearized(pose, problem.init_pose)  # both holds share the rotations, not the joints
    for weight, mask in ((w.occlusion, occluded), (w.init_pose, 1.0 - occluded)):
        if weight > 0:
            terms.append((weight, *_masked_hold(r, d, mask)))
    _add_pose_terms(terms, B, layout, profile, acc)


def neutral_weight(weights, problem) -> float | torch.Tensor:
    """The neutral-pose prior's weight: the profile's, or (B,) per person with `problem.neutral_scale`."""
    return weights.neutral if problem.neutral_scale is None else weights.neutral * problem.neutral_scale


def _add_pose_terms(terms, B: int, layout: Layout, profile: OptimizerProfile, acc: Residuals) -> None:
    for weight, r, d_pose in terms:
        J = r.new_zeros(B, r.shape[1], layout.size)
        J[..., : 3 * layout.joints] = d_pose
        root = _w(weight, profile) ** 0.5
        if isinstance(root, torch.Tensor):  # per person
            root = root.to(r.dtype)[:, None]
            acc.add(root * r, root[..., None] * J)
        else:
            acc.add(root * r, root * J)


def keypoint_depth_block(body: Linearized, problem, stage, profile: OptimizerProfile, acc: Residuals) -> None:
    """The limb-depth targets' IRLS residuals √w · √(GM weight) · (z_k − target_k)
    (`losses.keypoint_depth_loss`, as for the keypoints)."""
    if stage.keypoint_depth_weight <= 0 or problem.keypoint_depth is None:
        return
    valid = torch.isfinite(problem.keypoint_depth).to(body.keypoints.dtype)
    e = valid * (body.keypoints[..., 2] - torch.nan_to_num(problem.keypoint_depth))
    sigma2 = stage.keypoint_depth_sigma**2
    scale = _w(stage.keypoint_depth_weight, profile) ** 0.5 * valid * sigma2 / (sigma2 + e**2)
    acc.add(scale * e, scale[..., None] * body.d_keypoints[..., 2, :])


def shape_prior_linearized(model: BodyModel, free: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The shape prior's residuals (B, R) and their derivatives in the free coordinates (B, R, S), by
    finite differences of the (tiny) prior itself."""
    S = free.shape[1]
    with torch.no_grad():
        r = model.shape_prior_residuals(model.shape_from_free(free))
        moved = free[:, None, :] + SHAPE_STEP * torch.eye(S, dtype=free.dtype, device=free.device)
        r_moved = model.shape_prior_residuals(model.shape_from_free(moved.reshape(-1, S)))
    d = (r_moved.reshape(free.shape[0], S, -1) - r[:, None]) / SHAPE_STEP
    return r, d.transpose(1, 2)


def range_prior_linearized(model: BodyModel, pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Joint-range excesses (B, 3J) and their Jacobian (B, 3J, 3J): anatomical angles are linear in the
    axis-angle (`pose_to_anatomical`), so each excess is ± one row of a joint's frame."""
    if type(model).pose_prior is not BodyModel.pose_prior and getattr(model, "gmm", None) is not None:
        return _scalar_linearized(model.pose_prior, pose)
    anat = model.pose_to_anatomical(pose)
    frames = model.anat_frames.to(pose.dtype)  # (J, 3 anatomical, 3 axis-angle)
    lo, hi = model.anat_ranges[..., 0].to(pose.dtype), model.anat_ranges[..., 1].to(pose.dtype)
    r = (torch.relu(lo - anat) + torch.relu(anat - hi)).flatten(1)
    sign = ((anat > hi).to(pose.dtype) - (anat < lo).to(pose.dtype))  # (B, J, 3)
    return r, _block_diagonal(sign[..., None] * frames)


def upright_linearized(root_orient: torch.Tensor, up: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """`losses.upright_residuals` (B, 3) and their Jacobian in the root's axis-angle (B, 3, 3): the body's
    up axis a turns by ω × a, ω = J_l(root) dr."""
    from smplify3d_ros.body.base import left_jacobian_so3

    a = roma.rotvec_to_rotmat(root_orient)[..., :, 1]  # (B, 3)
    omega = left_jacobian_so3(root_orient).transpose(-1, -2)  # (B, 3 columns, 3)
    da = torch.cross(omega, a[:, None].expand_as(omega), dim=-1)
    d = torch.cross(da, up[:, None].expand_as(da), dim=-1)  # (B, 3 columns, 3 residuals)
    return torch.cross(a, up, dim=-1), d.transpose(-1, -2)


def neutral_linearized(model: BodyModel, pose: torch.Tensor, robust_scale: float = 0.0
                       ) -> tuple[torch.Tensor, torch.Tensor]:
    """`BodyModel.neutral_residuals` (B, 3J), made robust with `robust_scale` (`losses.robust_residuals`),
    and their Jacobian (B, 3J, 3J): each joint's frame rows over its range widths, times dψ/dr."""
    r, slope = losses.robust_residuals(model.neutral_residuals(pose), robust_scale)
    width = (model.anat_ranges[..., 1] - model.anat_ranges[..., 0]).to(pose.dtype).clamp(min=1e-3)
    blocks = model.anat_frames.to(pose.dtype) / width[..., None]  # (J, 3, 3)
    blocks = blocks * slope.unflatten(1, (-1, 3))[..., None]  # row (joint, anatomical angle) scaled
    return r, _block_diagonal(blocks)


def bending_linearized(model: BodyModel, pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """exp(−flexion/2) of elbows and knees (B, 4) and its Jacobian (B, 4, 3J)."""
    r = model.bending_residuals(pose)
    axes = model.anat_frames[model.bending_index, 0].to(pose.dtype)  # (4, 3)
    J = r.new_zeros(*r.shape, pose.shape[1], 3)
    for i, joint in enumerate(model.bending_index):
        J[:, i, joint] = -0.5 * r[:, i, None] * axes[i]
    return r, J.flatten(2)


def held_linearized(pose: torch.Tensor, init_pose: torch.Tensor, mask: torch.Tensor | None = None):
    """√mask · vec(q₀⁻¹ q) (B, 3J), whose squared norms are 1 − ⟨q, q₀⟩² (`losses.occlusion_prior`), and
    the Jacobian: q(θ + dθ) = (½ J_l dθ, 0) ⊗ q to first order. With `mask` (B, J) the Jacobian is
    (B, 3J, 3J); without, the residuals are unmasked and the Jacobian is its per-joint blocks
    (B, J, 3, 3), for the caller to mask."""
    from smplify3d_ros.body.base import left_jacobian_so3

    q = roma.rotvec_to_unitquat(pose)  # (B, J, 4) xyzw
    q0_inv = roma.quat_conjugation(roma.rotvec_to_unitquat(init_pose))
    r = roma.quat_product(q0_inv, q)[..., :3]
    omega = 0.5 * left_jacobian_so3(pose).transpose(-1, -2)  # (B, J, 3 columns, 3)
    omega_q = torch.cat([omega, torch.zeros_like(omega[..., :1])], -1)  # pure quaternions
    d = roma.quat_product(q0_inv[:, :, None], roma.quat_product(omega_q, q[:, :, None].expand_as(omega_q)))
    d = d[..., :3].transpose(-1, -2)  # (B, J, 3 residual, 3 column)
    return (r.flatten(1), d) if mask is None else _masked_hold(r.flatten(1), d, mask)


def _masked_hold(r: torch.Tensor, blocks: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A hold's unmasked residuals (B, 3J) and per-joint blocks (B, J, 3, 3) on the joints `mask` (B, J)
    weights: √mask · r (B, 3J) and its Jacobian (B, 3J, 3J)."""
    root = mask.sqrt()[..., None]
    return (r.unflatten(1, (-1, 3)) * root).flatten(1), _block_diagonal(blocks * root[..., None])


def _block_diagonal(blocks: torch.Tensor) -> torch.Tensor:
    """(B, J, 3, 3) per-joint blocks -> (B, 3J, 3J)."""
    B, J = blocks.shape[:2]
    out = blocks.new_zeros(B, J, 3, J, 3)
    idx = torch.arange(J, device=blocks.device)
    out[:, idx, :, idx] = blocks.transpose(0, 1)
    return out.reshape(B, 3 * J, 3 * J)


def _scalar_linearized(prior, pose: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """A prior without a sum-of-squares form (SMPL's GMM) as one residual √L, gradient ∇L / (2√L)."""
    x = pose.detach().clone().requires_grad_(True)
    with torch.enable_grad():
        value = prior(x).clamp(min=1e-12)
        (grad,) = torch.autograd.grad(value.sum(), x)
    r = value.detach().sqrt()
    return r[:, None], (grad.flatten(1) / (2.0 * r[:, None]))[:, None]


def _w(weight: float, profile: OptimizerProfile) -> float:
    return weight**2 if profile.square_weights else weight


# -- the iterations --------------------------------------------------------------------------------------
def uses_chamfer(stage, problem) -> bool:
    """Whether the stage has L_3D: a weight, and vertices to pose for it."""
    return stage.chamfer_weight > 0 and problem.vertex_index.shape[1] > 0


def chamfer_gain(stage, problem) -> torch.Tensor | float:
    """(B,) the factor on each person's λ_3D² in this stage (`FitProblem.lidar_gain` where the stage takes
    it, `StageSpec.points_gain`), else 1: the loss and the residuals share it."""
    return problem.lidar_gain if stage.points_gain and problem.lidar_gain is not None else 1.0


def linearize_stage(model: BodyModel, state, problem, stage, layout: Layout, translated=None) -> Linearized:
    """`linearize` with the vertices the stage's L_3D uses (none without it)."""
    return linearize(model, state, problem, uses_chamfer(stage, problem), layout, translated)


def normal_equations(model: BodyModel, state, problem, stage, profile: OptimizerProfile, layout: Layout,
                     translated=None, body: Linearized | None = None) -> Residuals:
    """JᵀJ and Jᵀr of the stage at `state`; `body`: its linearization there, when already made."""
    use_chamfer = uses_chamfer(stage, problem)
    if body is None:
        body = linearize_stage(model, state, problem, stage, layout, translated)
    acc = Residuals(state.pose.shape[0], layout.size, state.pose.device)
    keypoint_block(body, problem, stage, acc)
    if use_chamfer:
        chamfer_block(body, problem, stage, profile, layout, acc)
        free_space_block(body, problem, stage, profile, layout, acc)
    keypoint_depth_block(body, problem, stage, profile, acc)
    depth_hold_block(state, problem, stage, profile, layout, acc)
    depth_bound_block(state, problem, stage, profile, layout, acc)
    motion_hold_block(state, problem, stage, profile, layout, acc)
    joint_motion_block(body, problem, stage, profile, acc)
    prior_block(model, state, problem, stage, profile, layout, acc)
    return acc


def depth_hold_weights(problem, profile: OptimizerProfile) -> torch.Tensor | None:
    """(B,) weight of each person's depth hold: `image_depth` for people fitted from the image alone,
    `points_depth` for those of them whose few points measured the depth, 0 with L_3D; None: no hold."""
    weights = profile.weights
    if problem.init_transl is None or (weights.image_depth <= 0 and weights.points_depth <= 0):
        return None
    dtype = problem.init_transl.dtype
    measured = problem.depth_measured if problem.depth_measured is not None else torch.zeros_like(problem.use_lidar)
    weight = torch.where(measured, torch.tensor(_w(weights.points_depth, profile), dtype=dtype),
                         torch.tensor(_w(weights.image_depth, profile), dtype=dtype))
    return torch.where(problem.use_lidar, torch.zeros_like(weight), weight)


def depth_hold_block(state, problem, stage, profile: OptimizerProfile, layout: Layout, acc: Residuals) -> None:
    """`losses.depth_hold_residuals`, linear in the translation's z."""
    weight = depth_hold_weights(problem, profile) if "transl" in stage.params else None
    if weight is None:
        return
    r = losses.depth_hold_residuals(state.transl, problem.init_transl, weight)
    _add_depth_rows(r, weight.sqrt() / problem.init_transl[:, 2].clamp(min=0.3), layout, acc)


def _add_depth_rows(r: torch.Tensor, dr_dz: torch.Tensor, layout: Layout, acc: Residuals) -> None:
    """(B,) residuals that depend on the translation's z alone, with their derivative dr/dz (B,)."""
    J = r.new_zeros(r.shape[0], 1, layout.size)
    J[:, 0, 3 * layout.joints + 5] = dr_dz
    acc.add(r[:, None], J)


def depth_bound_weights(problem, profile: OptimizerProfile) -> torch.Tensor | None:
    """(B,) weight of each person's depth bound: that of a depth the scan measured (`points_depth`), for
    the people `problem.depth_bound` bounds; None: no bound."""
    bound = problem.depth_bound
    if bound is None or profile.weights.points_depth <= 0 or not bool(torch.isfinite(bound).any()):
        return None
    return torch.full_like(bound, _w(profile.weights.points_depth, profile))


def depth_bound_block(state, problem, stage, profile: OptimizerProfile, layout: Layout, acc: Residuals) -> None:
    """`losses.depth_bound_residuals`, linear in the translation's z where the bound is passed."""
    weight = depth_bound_weights(problem, profile) if "transl" in stage.params else None
    if weight is None:
        return
    r = losses.depth_bound_residuals(state.transl, problem.depth_bound, weight)
    passed = (r > 0).to(r.dtype)
    _add_depth_rows(r, passed * weight.sqrt() / problem.depth_bound.clamp(min=0.3, max=1e6), layout, acc)


def motion_hold_block(state, problem, stage, profile: OptimizerProfile, layout: Layout, acc: Residuals) -> None:
    """`losses.motion_hold_residuals`, linear in the translation."""
    if problem.predicted_transl is None or "transl" not in stage.params:
        return
    weight = _w(profile.weights.motion, profile)
    r = losses.motion_hold_residuals(state.transl, problem.predicted_transl, weight)
    valid = torch.isfinite(problem.predicted_transl).to(r.dtype)  # (B, 3)
    J = r.new_zeros(r.shape[0], 3, layout.size)
    t0 = 3 * layout.joints + 3  # the translation's columns follow the pose's and the root's
    J[:, :, t0 : t0 + 3] = weight**0.5 * torch.diag_embed(valid)
    acc.add(r, J)


def holds_joints(problem, stage) -> bool:
    """Whether the stage has the joint motion hold: a prediction, and a stage that moves the body."""
    return problem.predicted_keypoints is not None and any(
        name in stage.params for name in ("pose", "root_orient", "transl"))


def joint_motion_block(body: Linearized, problem, stage, profile: OptimizerProfile, acc: Residuals) -> None:
    """`losses.joint_motion_residuals`, through the keypoints' Jacobian."""
    weight = _w(profile.weights.joint_motion, profile)
    if weight <= 0 or not holds_joints(problem, stage):
        return
    relative = profile.joint_motion_relative
    predicted = losses.root_relative(problem.predicted_keypoints) if relative else problem.predicted_keypoints
    r = losses.joint_motion_residuals(body.keypoints, problem.predicted_keypoints, weight, relative)  # (B, K, 3)
    valid = torch.isfinite(predicted).all(-1).to(r.dtype)  # (B, K)
    scale = (weight / valid.sum(-1).clamp(min=1)).sqrt()[:, None] * valid  # (B, K)
    d_keypoints = losses.root_relative(body.d_keypoints) if relative else body.d_keypoints
    J = scale[..., None, None] * d_keypoints  # (B, K, 3, P)
    acc.add(r.flatten(1), J.flatten(1, 2))


def damped_step(acc: Residuals, layout: Layout, damping: torch.Tensor) -> torch.Tensor:
    """(B, P) the LM step −(JᵀJ + μ D + ε m I)⁻¹ Jᵀr on the active columns (zero elsewhere).

    D is JᵀJ's diagonal (Marquardt: invariant to the parameters' units); ε m I (m the mean of D, ε
    `RIDGE`) is a fixed ridge, so that a combination of joints nothing observes (an upper arm's twist
    against its forearm's) gets no step instead of an arbitrary one; each joint's (and the root's)
    rotation step is then clipped to `MAX_ROTATION_STEP`, the translation's to `MAX_TRANSLATION_STEP`
    (acceptance by the exact loss follows either way)."""
    inactive = ~layout.active
    A = acc.JtJ.clone()
    A[:, inactive, :] = 0.0
    A[:, :, inactive] = 0.0
    diag = torch.diagonal(A, dim1=-2, dim2=-1)
    mean = diag[:, layout.active].mean(-1, keepdim=True).clamp(min=1e-12)
    damp = damping.double()[:, None] * diag + RIDGE * mean
    A = A + torch.diag_embed(torch.where(inactive, torch.ones_like(damp), damp))
    rhs = torch.where(inactive, torch.zeros_like(acc.Jtr), -acc.Jtr)
    step = torch.linalg.solve(A, rhs[..., None])[..., 0]
    step = torch.where(torch.isfinite(step), step, torch.zeros_like(step))
    J3 = 3 * layout.joints
    rotations = step[:, : J3 + 3].reshape(step.shape[0], -1, 3)
    norms = rotations.norm(dim=-1, keepdim=True)
    rotations = rotations * (MAX_ROTATION_STEP / norms.clamp(min=MAX_ROTATION_STEP))
    transl = step[:, J3 + 3 : J3 + 6]
    transl = transl * (MAX_TRANSLATION_STEP / transl.norm(dim=-1, keepdim=True).clamp(min=MAX_TRANSLATION_STEP))
    return torch.cat([rotations.flatten(1), transl, step[:, J3 + 6 :]], -1)


def apply_step(state, step: torch.Tensor, layout: Layout):
    """A new state: the current one plus the step (axis-angles add; the Jacobians are theirs)."""
    J3 = 3 * layout.joints
    out = state.clone()
    step = step.to(state.pose.dtype)
    with torch.no_grad():
        out.pose += step[:, :J3].reshape(out.pose.shape)
        out.root_orient += step[:, J3 : J3 + 3]
        out.transl += step[:, J3 + 3 : J3 + 6]
        out.shape += step[:, J3 + 6 :]
    return out
