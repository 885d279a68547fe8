"""The optimizer: SMPLify-3D's single-stage scheme (Eq. 2) and the robust three-stage scheme (Eq. 11-14).

All people of a frame are one batch: each row of every tensor is one person, each person keeps its own
loss, and a person whose loss turns non-finite or explodes is frozen at its best finite state and
flagged, without stopping the others.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch

from smplify3d_ros.body.base import BodyModel, BodyOutput
from smplify3d_ros.fitting import free_space, losses, solver
from smplify3d_ros.fitting.config import LossWeights, OptimizerProfile
from smplify3d_ros.fitting.problem import PARAM_NAMES, FitProblem, FitState, posed_rows


@dataclass
class StageSpec:
    """What one stage optimizes and which terms it uses."""

    name: str
    params: tuple[str, ...]
    iterations: int
    align: str | None  # keypoint alignment of L_J (Eq. 11-12: `hips`, `centroid`), None: none
    sigma_px: float
    chamfer_weight: float  # λ_3D of this stage (0: no 3D term)
    priors: bool  # pose, bending, shape and occlusion priors
    shape_only_prior: bool = False  # stage 1: only L_β beside L_J
    hold: bool = True  # with `priors`: L_θocc and the init-pose prior (False: nothing to hold, built-in init)
    keypoint_depth_weight: float = 0.0  # weight of the limb-depth targets (`FitProblem.keypoint_depth`)
    keypoint_depth_sigma: float = 0.1  # m, their Geman-McClure scale
    points_gain: bool = False  # λ_3D² × each person's `FitProblem.lidar_gain` (the stages that fit pose and place)


@dataclass
class StageReport:
    iterations: dict[str, int] = field(default_factory=dict)
    final_loss: torch.Tensor | None = None  # (B,)
    diverged: torch.Tensor | None = None  # (B,) bool


def _w(weight: float, profile: OptimizerProfile) -> float:
    return weight**2 if profile.square_weights else weight


class _Translated:
    """Stand-in for the body model in a translation-only stage: every model is translation-equivariant
    (`transl` is added last), so the posed body is computed once and only shifted afterwards."""

    def __init__(self, model: BodyModel, state: FitState, problem: FitProblem) -> None:
        self.model = model
        self.transl0 = state.transl.detach().clone()
        with torch.no_grad():
            self.base = posed_rows(model, state.body_args(model), problem, problem.vertex_index.shape[1] > 0)

    def __call__(self, shape, pose, root_orient, transl) -> BodyOutput:
        shift = (transl - self.transl0)[:, None]
        return BodyOutput(self.base.vertices + shift, self.base.joints + shift, self.base.keypoints + shift)


class _Posed:
    """Stand-in for the body model that returns a body already posed (a `solver.Linearized`): the loss of
    the state a step is linearized at, without posing it twice."""

    def __init__(self, body: solver.Linearized) -> None:
        self.body = body

    def __call__(self, shape, pose, root_orient, transl) -> BodyOutput:
        return BodyOutput(self.body.vertices, self.body.keypoints, self.body.keypoints)  # joints: unused


def stage_loss(
    model: BodyModel, state: FitState, problem: FitProblem, stage: StageSpec, profile: OptimizerProfile,
    body=None,
) -> torch.Tensor:
    """(B,) total loss of one stage. `body` replaces `model`'s forward (see `_Translated`)."""
    weights: LossWeights = profile.weights
    use_chamfer = solver.uses_chamfer(stage, problem)
    shape = model.shape_from_free(state.shape)
    args = (shape, state.pose, state.root_orient, state.transl)
    out = body(*args) if body is not None else posed_rows(model, args, problem, use_chamfer)
    projected = losses.project(out.keypoints, problem.K)
    loss = losses.reprojection_loss(
        projected, problem.keypoints, problem.confidence, stage.sigma_px, align=stage.align,
        scale=problem.pixel_scale,
    )
    if stage.priors or stage.shape_only_prior:
        loss = loss + _w(weights.shape, profile) * model.shape_prior(shape)
    if stage.priors:
        loss = loss + _w(weights.pose, profile) * model.pose_prior(state.pose)
        loss = loss + _w(weights.bend, profile) * model.bending_prior(state.pose)
        if weights.neutral > 0:
            neutral, _ = losses.robust_residuals(model.neutral_residuals(state.pose), profile.neutral_robust_scale)
            loss = loss + _w(solver.neutral_weight(weights, problem), profile) * (neutral**2).sum(-1)
        if weights.upright > 0 and problem.up is not None:
            loss = loss + _w(weights.upright, profile) * (losses.upright_residuals(
                state.root_orient, problem.up) ** 2).sum(-1)
    if stage.priors and stage.hold:  # L_θocc on occluded parts' joints, the init-pose hold on the others
        held = losses.held_rotation(state.pose, problem.init_pose)
        occluded = problem.occluded_joints
        loss = loss + _w(weights.occlusion, profile) * (held * occluded).sum(-1)
        if weights.init_pose > 0:
            loss = loss + _w(weights.init_pose, profile) * (held * (1.0 - occluded)).sum(-1)
    hold = solver.depth_hold_weights(problem, profile) if "transl" in stage.params else None
    if hold is not None:
        loss = loss + losses.depth_hold_residuals(state.transl, problem.init_transl, hold) ** 2
    bound = solver.depth_bound_weights(problem, profile) if "transl" in stage.params else None
    if bound is not None:
        loss = loss + losses.depth_bound_residuals(state.transl, problem.depth_bound, bound) ** 2
    loss = loss + motion_hold_loss(state, problem, stage, profile)
    loss = loss + joint_motion_loss(out.keypoints, problem, stage, profile)
    if stage.keypoint_depth_weight > 0 and problem.keypoint_depth is not None:
        loss = loss + _w(stage.keypoint_depth_weight, profile) * losses.keypoint_depth_loss(
            out.keypoints, problem.keypoint_depth, stage.keypoint_depth_sigma)
    if use_chamfer:
        indices = body.body.nearest(problem, profile.chamfer_vertex_weight > 0) if isinstance(body, _Posed) else None
        chamfer = losses.chamfer_loss(out.vertices, problem.vertex_mask, problem.points, problem.point_mask,
                                      profile.chamfer_vertex_weight, indices)
        gain = solver.chamfer_gain(stage, problem)
        loss = loss + _w(stage.chamfer_weight, profile) * chamfer * problem.use_lidar * gain
    if solver.uses_free_space(stage, problem, profile) and problem.blocked is not None:
        loss = loss + _w(weights.free_space, profile) * problem.use_lidar * free_space.free_space_loss(
            out.vertices, problem.blocked, problem.lidar_origin, problem.point_mask)
    return loss


def motion_hold_loss(state: FitState, problem: FitProblem, stage: StageSpec, profile: OptimizerProfile
                     ) -> torch.Tensor | float:
    """(B,) the motion hold's term of the stage's loss (`weights.motion`), 0 where it has none."""
    if problem.predicted_transl is None or "transl" not in stage.params:
        return 0.0
    return (losses.motion_hold_residuals(state.transl, problem.predicted_transl,
                                         _w(profile.weights.motion, profile)) ** 2).sum(-1)


def joint_motion_loss(keypoints: torch.Tensor, problem: FitProblem, stage: StageSpec, profile: OptimizerProfile
                      ) -> torch.Tensor | float:
    """(B,) the joint motion hold's term of the stage's loss (`weights.joint_motion`) at the bodies'
    keypoints (B, 17, 3), 0 where it has none."""
    weight = _w(profile.weights.joint_motion, profile)
    if weight <= 0 or not solver.holds_joints(problem, stage):
        return 0.0
    return (losses.joint_motion_residuals(keypoints, problem.predicted_keypoints, weight,
                                          profile.joint_motion_relative) ** 2).sum((-1, -2))


def run_stage(
    model: BodyModel,
    state: FitState,
    problem: FitProblem,
    stage: StageSpec,
    profile: OptimizerProfile,
    divergence_factor: float,
    diverged: torch.Tensor,
) -> tuple[int, torch.Tensor]:
    """Optimize `stage.params` of `state` in place with Adam; returns (iterations run, final (B,) loss).

    Each person keeps the best finite state the stage reached. `diverged` (B,) is updated in place:
    a person whose loss becomes non-finite or exceeds `divergence_factor` times its start is frozen.
    A stage with L_free casts the beams against the body as it starts (`FitProblem.cast_beams`).
    """
    if solver.uses_free_space(stage, problem, profile):
        problem.blocked = problem.cast_beams(state)
    if stage.iterations == 0:
        with torch.no_grad():
            return 0, stage_loss(model, state, problem, stage, profile)
    body = _Translated(model, state, problem) if stage.params == ("transl",) else None
    if profile.optimizer == "lm":
        return _run_lm(model, state, problem, stage, profile, diverged, body)
    tensors = [getattr(state, n) for n in stage.params]
    for t in tensors:
        t.requires_grad_(True)
    optimizer = torch.optim.Adam(tensors, lr=profile.lr, betas=profile.betas)
    best = state.clone()
    best_loss = torch.full_like(problem.use_lidar, float("inf"), dtype=state.pose.dtype)
    start_loss: torch.Tensor | None = None
    previous: torch.Tensor | None = None
    calm = torch.zeros_like(problem.use_lidar, dtype=torch.int64)  # iterations each person barely improved
    iterations = 0
    for _ in range(stage.iterations):
        optimizer.zero_grad(set_to_none=True)
        loss = stage_loss(model, state, problem, stage, profile, body)
        detached = loss.detach()
        if start_loss is None:
            start_loss = detached.abs().clamp(min=1e-6)
        bad = ~torch.isfinite(detached) | (detached > divergence_factor * start_loss)
        diverged |= bad
        improved = ~diverged & (detached < best_loss)
        if improved.any():
            best.copy_rows_from(state, improved)
            best_loss = torch.where(improved, detached, best_loss)
        active = ~diverged
        if not active.any():
            break
        torch.where(active, loss, torch.zeros_like(loss)).sum().backward()
        for t in tensors:  # frozen people get no update at all (Adam's momentum included)
            if t.grad is not None:
                t.grad[~active] = 0.0
        optimizer.step()
        state.copy_rows_from(best, diverged)
        iterations += 1
        if profile.early_stop_rel_tol > 0:  # stop once every active person has converged
            if previous is not None:
                slow = previous - detached < profile.early_stop_rel_tol * previous.abs()
                calm = torch.where(slow, calm + 1, torch.zeros_like(calm))
                if bool((calm[active] >= profile.early_stop_patience).all()):
                    break
            previous = detached
    for t in tensors:
        t.requires_grad_(False)
    with torch.no_grad():
        final = stage_loss(model, state, problem, stage, profile, body)
        worse = ~torch.isfinite(final) | (final > best_loss)
        state.copy_rows_from(best, worse)
        final = torch.where(worse, best_loss, final)
    return iterations, final


def _run_lm(
    model: BodyModel, state: FitState, problem: FitProblem, stage: StageSpec, profile: OptimizerProfile,
    diverged: torch.Tensor, body: _Translated | None,
) -> tuple[int, torch.Tensor]:
    """`run_stage` with Levenberg-Marquardt steps (`fitting.solver`): a step is kept only where it lowers
    the person's exact stage loss, so nobody ends worse than they started; a non-finite start freezes
    the person (flagged diverged). Each person stops once its loss fell by less than `early_stop_rel_tol`
    over the last `early_stop_patience` iterations, or once no step with a bearable damping lowers it."""
    layout = solver.Layout.of(model, stage.params, state.pose.device)
    # Each candidate is linearized where its loss is taken: an accepted step's linearization is the next
    # iteration's (one body pass per iteration instead of two), its neighbour search the loss's. A
    # translation-only stage poses no body: its linearization shifts the one posed at its start.
    with torch.no_grad():
        here = solver.linearize_stage(model, state, problem, stage, layout, body)
        cost = stage_loss(model, state, problem, stage, profile, _Posed(here))
    diverged |= ~torch.isfinite(cost)
    active = ~diverged.clone()
    damping = torch.full_like(cost, profile.lm_damping)
    history = [cost]  # each iteration's loss, accepted steps or not
    iterations = 0
    for _ in range(stage.iterations):
        if not active.any():
            break
        system = solver.normal_equations(model, state, problem, stage, profile, layout, body, here)
        step = solver.damped_step(system, layout, damping) * active[:, None]  # people done keep their state
        candidate = solver.apply_step(state, step, layout)
        with torch.no_grad():
            there = solver.linearize_stage(model, candidate, problem, stage, layout, body)
            new_cost = stage_loss(model, candidate, problem, stage, profile, _Posed(there))
        better = active & torch.isfinite(new_cost) & (new_cost < cost)
        state.copy_rows_from(candidate, better)
        if bool(better.any()):  # no step taken: `here` still linearizes the state
            # where every active person stepped (the others did not move) the state is the candidate;
            # after a mix of taken and refused steps it is neither, and the next iteration linearizes it
            here = there if bool((better | ~active).all()) else None
        cost = torch.where(better, new_cost, cost)
        damping = torch.where(better, damping / solver.DAMPING_DOWN, damping * solver.DAMPING_UP)
        history.append(cost)
        iterations += 1
        if len(history) > profile.early_stop_patience:
            before = history[-1 - profile.early_stop_patience]
            active &= before - cost >= profile.early_stop_rel_tol * before.abs()
        active &= damping < solver.DAMPING_MAX
    return iterations, cost


def stage_plan(profile: OptimizerProfile) -> list[StageSpec]:
    """The stages of the profile's scheme, with their terms (Eq. 2 or Eq. 11-14)."""
    w = profile.weights
    if profile.scheme == "single_stage":
        return [
            StageSpec("single", PARAM_NAMES, profile.single_stage_iterations, None, w.sigma_px,
                      w.chamfer, priors=True),
        ]
    n1, n2, n3 = profile.iterations
    align = profile.keypoint_alignment
    return [
        # with L_3D, stage 1 moves the body to its points while it scales it: the size the image sees is
        # then measured at the depth the LiDAR sees, rather than at a depth the later stages must undo
        StageSpec("scale", ("shape", "transl") if w.chamfer_scale > 0 else ("shape",), n1, align, w.sigma_px,
                  w.chamfer_scale, priors=False, shape_only_prior=True),
        StageSpec("mesh", ("pose", "shape", "root_orient") if profile.mesh_shape else ("pose", "root_orient"), n2,
                  align, w.sigma_px, w.chamfer, priors=True, points_gain=True),
        StageSpec("image", ("transl",), n3, None, w.sigma_px_final, w.chamfer_final, priors=False, points_gain=True),
    ]


def optimize(
    model: BodyModel, state: FitState, problem: FitProblem, profile: OptimizerProfile, divergence_factor: float
) -> StageReport:
    report = StageReport()
    diverged = torch.zeros_like(problem.use_lidar)
    final = None
    plan = stage_plan(profile)
    for k, stage in enumerate(plan):
        if stage.iterations == 0 and k < len(plan) - 1:  # nothing to run; a later stage gives the loss
            report.iterations[stage.name] = 0
            continue
        report.iterations[stage.name], final = run_stage(
            model, state, problem, stage, profile, divergence_factor, diverged
        )
    if final is not None:
        # the motion holds are left out: the final loss says how well the body explains this frame, and a
        # tracked person's refresh compares it with a cold fit's, which has no prediction to be held to
        with torch.no_grad():
            final = final - motion_hold_loss(state, problem, plan[-1], profile)
            if solver.holds_joints(problem, plan[-1]) and profile.weights.joint_motion > 0:
                keypoints = model(*state.body_args(model), problem.empty_subset).keypoints
                final = final - joint_motion_loss(keypoints, problem, plan[-1], profile)
    report.final_loss = final
    report.diverged = diverged
    return report
