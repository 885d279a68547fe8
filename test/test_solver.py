"""The Levenberg-Marquardt solver: its Jacobians against autodiff, and that it converges where Adam's
fixed steps do not."""

import dataclasses

import numpy as np
import pytest
import torch

from smplify3d_ros.body.base import BodyModel, left_jacobian_so3
from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, make_person, perturb
from smplify3d_ros.fitting import solver
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.fitting.options import FitOptions
from smplify3d_ros.fitting.problem import FitState
from smplify3d_ros.fitting.stages import StageSpec, run_stage, stage_loss


def _random_body(model, B=2, seed=0):
    g = torch.Generator().manual_seed(seed)
    dt = model.dtype
    shape = torch.rand(B, len(model.shape_names), generator=g, dtype=dt)
    pose = 0.5 * torch.randn(B, len(model.joint_names), 3, generator=g, dtype=dt)
    root = torch.randn(B, 3, generator=g, dtype=dt)
    transl = torch.tensor([[0.3, 0.1, 5.0], [-1.0, 0.2, 3.0]], dtype=dt)[:B]
    return shape, pose, root, transl


@pytest.mark.parametrize("per_row", [False, True])
def test_anny_analytic_jacobians_match_autodiff(anny_model, per_row):
    shape, pose, root, transl = _random_body(anny_model)
    g = torch.Generator().manual_seed(1)
    index = torch.randperm(13718, generator=g)[:200]
    if per_row:  # a vertex set per body, as the fitter passes them
        index = torch.stack([index, torch.randperm(13718, generator=g)[:200]])
    analytic = anny_model.linearize(shape, pose, root, transl, index)
    generic = BodyModel.linearize(anny_model, shape, pose, root, transl, index)
    rows = torch.arange(200).expand(2, -1)
    assert torch.allclose(analytic.vertices, generic.vertices, atol=1e-5)
    assert torch.allclose(analytic.keypoints, generic.keypoints, atol=1e-5)
    assert torch.allclose(analytic.d_keypoints, generic.d_keypoints, atol=1e-4)
    assert torch.allclose(analytic.vertex_jacobian(rows), generic.vertex_jacobian(rows), atol=1e-4)
    assert analytic.vertex_jacobian(rows).abs().max() > 0.1  # not trivially zero


def test_left_jacobian_matches_finite_differences():
    theta = torch.tensor([0.3, -1.2, 0.7], dtype=torch.float64)
    import roma

    R = roma.rotvec_to_rotmat(theta)
    Jl = left_jacobian_so3(theta)
    for k in range(3):
        d = torch.zeros(3, dtype=torch.float64)
        d[k] = 1e-6
        omega_hat = (roma.rotvec_to_rotmat(theta + d) @ R.T - torch.eye(3, dtype=torch.float64)) / 1e-6
        omega = torch.stack([omega_hat[2, 1], omega_hat[0, 2], omega_hat[1, 0]])
        assert torch.allclose(omega, Jl[:, k], atol=1e-5)


def test_prior_jacobians_match_autodiff(anny_model):
    model = anny_model
    _, pose, _, _ = _random_body(model)
    pose = pose.double()
    init = 0.5 * torch.randn(pose.shape, generator=torch.Generator().manual_seed(3), dtype=torch.float64)
    mask = (torch.rand(pose.shape[:2], generator=torch.Generator().manual_seed(4)) > 0.5).double()
    cases = {
        "range": lambda p: solver.range_prior_linearized(model, p),
        "bend": lambda p: solver.bending_linearized(model, p),
        "neutral": lambda p: solver.neutral_linearized(model, p),
        "neutral_robust": lambda p: solver.neutral_linearized(model, p, 0.5),  # ψ(r), rows times dψ/dr
        "held": lambda p: solver.held_linearized(p, init, mask),
    }
    up = torch.tensor([[0.05, -1.0, 0.1], [0.0, -1.0, 0.0]], dtype=torch.float64)
    up = up / up.norm(dim=-1, keepdim=True)
    cases["upright"] = lambda p: solver.upright_linearized(p[:, 0], up)  # the first row stands in for a root
    B = pose.shape[0]
    for name, fn in cases.items():
        r, J = fn(pose)
        auto = torch.autograd.functional.jacobian(lambda x, fn=fn: fn(x.reshape(pose.shape))[0],
                                                  pose.reshape(B, -1))
        auto = auto[torch.arange(B), :, torch.arange(B)]
        if name == "upright":
            auto = auto[..., :3]
        assert torch.allclose(J.double(), auto, atol=1e-6), name
    r, blocks = solver.held_linearized(pose, init)  # unmasked: per-joint blocks, masked by the caller
    masked_r, masked_J = solver.held_linearized(pose, init, mask)
    root = mask.sqrt()
    assert torch.allclose((r.unflatten(1, (-1, 3)) * root[..., None]).flatten(1), masked_r)
    assert torch.allclose(solver._block_diagonal(blocks * root[..., None, None]), masked_J)
    # the residuals' squares are the priors the Adam path uses
    assert torch.allclose((solver.range_prior_linearized(model, pose)[0] ** 2).sum(-1), model.pose_prior(pose))
    assert torch.allclose((solver.bending_linearized(model, pose)[0] ** 2).sum(-1), model.bending_prior(pose))


def _problem_and_start(model, seed=5):
    """A synthetic person, the fitter's problem for it, and a start 20° off on every limb, 0.3 m deep."""
    cfg = load_config().fitting
    fitter = Fitter(cfg, model)
    rng = np.random.default_rng(seed)
    K = default_intrinsics()
    person = make_person(model, rng, K, distance=5.0, yaw=0.3, n_points=300, point_noise=0.01,
                         keypoint_noise_px=2.0)
    person.observation.init = perturb(model, person.truth, rng, depth_m=0.3, limb_deg=20.0)
    batch = fitter._start([person.observation], K, None, FitOptions())
    fitter._initialize(batch)
    return fitter, fitter._problem(batch), batch.state, person


def test_lm_reaches_in_ten_steps_what_adam_does_not(anny_model):
    fitter, problem, start, _ = _problem_and_start(anny_model)
    profile = fitter.config.optimizer
    spec = StageSpec("mesh", ("pose", "root_orient", "transl"), 10, None, 100.0, 600.0, priors=True)
    losses = {}
    for name in ("lm", "adam"):
        state = start.clone()
        prof = dataclasses.replace(profile, optimizer=name, early_stop_rel_tol=0.0)
        _, final = run_stage(anny_model, state, problem, spec, prof, 1000.0, torch.zeros(1, dtype=torch.bool))
        losses[name] = float(final[0])
    with torch.no_grad():
        initial = float(stage_loss(anny_model, start, problem, spec, profile)[0])
    print(losses, initial)
    assert losses["lm"] < 0.5 * losses["adam"] < initial


def test_lm_never_ends_worse_and_freezes_a_non_finite_person(anny_model):
    fitter, problem, start, _ = _problem_and_start(anny_model)
    problem.keypoints = problem.keypoints.clone()
    spec = StageSpec("mesh", ("pose", "root_orient"), 5, "centroid", 100.0, 600.0, priors=True)
    state = start.clone()
    with torch.no_grad():
        before = stage_loss(anny_model, state, problem, spec, fitter.config.optimizer)
    diverged = torch.zeros(1, dtype=torch.bool)
    _, after = run_stage(anny_model, state, problem, spec, fitter.config.optimizer, 1000.0, diverged)
    assert after[0] <= before[0] and not diverged[0]
    problem.keypoints[0, 3, 0] = float("inf")
    frozen = start.clone()
    run_stage(anny_model, frozen, problem, spec, fitter.config.optimizer, 1000.0, diverged)
    assert diverged[0]
    assert torch.equal(frozen.pose, start.pose)


def test_shape_stays_inside_its_range_under_any_step(anny_model):
    state = FitState(anny_model.shape_to_free(torch.full((1, 6), 0.99)), torch.zeros(1, 19, 3),
                     torch.zeros(1, 3), torch.zeros(1, 3))
    layout = solver.Layout.of(anny_model, ("shape",), "cpu")
    step = torch.zeros(1, layout.size)
    step[0, -6:] = 50.0  # far beyond the phenotype range in any linear parameterization
    shape = state.body_args(anny_model)[0]
    moved = solver.apply_step(state, step, layout).body_args(anny_model)[0]
    assert ((moved >= 0) & (moved <= 1)).all() and (moved > shape).all()


def test_the_motion_hold_keeps_a_tracked_translation_near_its_prediction(anny_model):
    """A warm start's translation is where the track predicted the person; `weights.motion` holds the
    fit there against what the data cannot tell apart, in both solvers, and leaves people without a
    prediction (NaN row) free."""
    fitter, problem, start, _ = _problem_and_start(anny_model)
    spec = StageSpec("image", ("transl",), 10, None, 50.0, 0.0, priors=False)
    predicted = start.transl + torch.tensor([[0.0, 0.0, 0.4]], dtype=start.transl.dtype)

    def fitted(weight: float, prediction: torch.Tensor | None, optimizer: str = "lm") -> torch.Tensor:
        profile = fitter.config.optimizer
        profile = dataclasses.replace(profile, optimizer=optimizer, early_stop_rel_tol=0.0, lr=0.05,
                                      weights=dataclasses.replace(profile.weights, motion=weight))
        state = start.clone()
        run_stage(anny_model, state, dataclasses.replace(problem, predicted_transl=prediction), spec, profile,
                  1000.0, torch.zeros(1, dtype=torch.bool))
        return state.transl.detach()[0]

    free = fitted(0.0, predicted)
    held = fitted(3000.0, predicted)
    assert (free - predicted[0]).norm() > 0.2  # the image puts the person elsewhere
    assert (held - predicted[0]).norm() < 0.02
    assert (fitted(3000.0, predicted, "adam") - predicted[0]).norm() < (free - predicted[0]).norm() - 0.05
    assert torch.allclose(fitted(3000.0, torch.full_like(predicted, float("nan"))), free)
    # the LM's linearization is the stage loss's term: Jᵀr is half its gradient in the translation
    profile = dataclasses.replace(fitter.config.optimizer,
                                  weights=dataclasses.replace(fitter.config.optimizer.weights, motion=3000.0))
    held_problem = dataclasses.replace(problem, predicted_transl=predicted)
    layout = solver.Layout.of(anny_model, spec.params, "cpu")
    acc = solver.Residuals(1, layout.size, "cpu")
    solver.motion_hold_block(start, held_problem, spec, profile, layout, acc)
    state = start.clone()
    state.transl.requires_grad_(True)
    term = stage_loss(anny_model, state, held_problem, spec, profile) - stage_loss(anny_model, state, problem,
                                                                                    spec, profile)
    (grad,) = torch.autograd.grad(term.sum(), state.transl)
    t0 = 3 * layout.joints + 3
    assert torch.allclose(acc.Jtr[0, t0 : t0 + 3], 0.5 * grad[0].double(), rtol=1e-4)
    assert float(acc.Jtr.abs().sum()) > 0
