"""The warm solve's joint motion hold (`fitting.profiles.*.weights.joint_motion`): its LM block is the stage
loss's term, it holds a solve's joints near their prediction, it is left out of the final loss, weight 0
changes nothing; the tracker's prediction of the joints (`tracking.joint_prediction`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, make_person, perturb
from smplify3d_ros.fitting import losses, solver
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.fitting.options import FitOptions
from smplify3d_ros.fitting.stages import StageSpec, optimize, run_stage, stage_loss, stage_plan
from smplify3d_ros.tracking.tracker import Tracker
from smplify3d_ros.types import FLAG_WARM_START, BodyFit, BodyParams, FitQuality, PersonObservation

NS = 100_000_000  # 10 Hz


def _setup(model, weight: float, seed: int = 5):
    """The warm profile with `weight`, a synthetic person's problem, and a start 20° off on every limb."""
    cfg = load_config().fitting
    cfg = dataclasses.replace(cfg, profile="warm")
    profile = cfg.optimizer
    profile = dataclasses.replace(profile, weights=dataclasses.replace(profile.weights, joint_motion=weight))
    cfg = dataclasses.replace(cfg, profiles={**cfg.profiles, "warm": profile})
    fitter = Fitter(cfg, model)
    rng = np.random.default_rng(seed)
    K = default_intrinsics()
    person = make_person(model, rng, K, distance=5.0, yaw=0.3, n_points=300, point_noise=0.01,
                         keypoint_noise_px=2.0)
    person.observation.init = perturb(model, person.truth, rng, depth_m=0.1, limb_deg=20.0)
    batch = fitter._start([person.observation], K, None, FitOptions())
    fitter._initialize(batch)
    return fitter, fitter._problem(batch), batch.state, person


def _keypoints(model, state) -> torch.Tensor:
    with torch.no_grad():
        return model(*state.body_args(model)).keypoints


MESH = StageSpec("mesh", ("pose", "root_orient", "transl"), 10, None, 100.0, 600.0, priors=True)


@pytest.mark.parametrize("relative", [False, True])
def test_the_block_is_the_stage_losss_term(anny_model, relative):
    """Jᵀr of the LM block is half the gradient of the stage loss's joint term, in every column the
    keypoints depend on (pose, root, translation), held where the joints are or about their hip midpoint
    (`joint_motion_relative`); NaN joints add nothing."""
    fitter, problem, start, _ = _setup(anny_model, 300.0)
    profile = dataclasses.replace(fitter.config.optimizer, joint_motion_relative=relative)
    offset = 0.05 * torch.randn(1, 17, 3, generator=torch.Generator().manual_seed(0), dtype=start.pose.dtype)
    predicted = _keypoints(anny_model, start) + offset
    predicted[:, 3] = float("nan")  # one joint without a prediction
    held = dataclasses.replace(problem, predicted_keypoints=predicted)
    layout = solver.Layout.of(anny_model, MESH.params, "cpu")
    body = solver.linearize_stage(anny_model, start, held, MESH, layout)
    acc = solver.Residuals(1, layout.size, "cpu")
    solver.joint_motion_block(body, held, MESH, profile, acc)
    state = start.clone()
    tensors = [state.pose, state.root_orient, state.transl]
    for t in tensors:
        t.requires_grad_(True)
    term = stage_loss(anny_model, state, held, MESH, profile) - stage_loss(anny_model, state, problem, MESH, profile)
    grads = torch.autograd.grad(term.sum(), tensors)
    gradient = torch.cat([g.reshape(1, -1) for g in grads], -1)[0].double()
    J3 = 3 * layout.joints
    assert torch.allclose(acc.Jtr[0, : J3 + 6], 0.5 * gradient, rtol=1e-3, atol=1e-3 * float(gradient.abs().max()))
    assert float(acc.Jtr.abs().sum()) > 0
    if relative:  # a rigid shift of the body changes nothing
        assert float(acc.Jtr[0, J3 + 3 : J3 + 6].abs().max()) < 1e-6 * float(acc.Jtr.abs().max())
        return
    # the residuals' squares are the term itself: w · the mean over the predicted joints
    r = losses.joint_motion_residuals(body.keypoints, predicted, 300.0**2)
    expected = 300.0**2 * ((body.keypoints - predicted)[:, [k for k in range(17) if k != 3]] ** 2).sum(-1).mean()
    assert torch.allclose((r**2).sum(), expected.to(r.dtype), rtol=1e-4)
    assert torch.allclose(term.detach(), (r**2).sum((-1, -2)), rtol=1e-3)


def test_the_hold_keeps_a_warm_solves_joints_near_their_prediction(anny_model):
    """Predicted where the start's joints are, the mesh stage's joints stay nearer to them with the hold
    than without, in both solvers; a person without a prediction (NaN) is fitted as without the hold."""
    fitter, problem, start, _ = _setup(anny_model, 0.0)
    predicted = _keypoints(anny_model, start)

    def fitted(weight: float, prediction: torch.Tensor | None, optimizer: str = "lm") -> torch.Tensor:
        profile = fitter.config.optimizer
        profile = dataclasses.replace(profile, optimizer=optimizer, early_stop_rel_tol=0.0, lr=0.02,
                                      weights=dataclasses.replace(profile.weights, joint_motion=weight))
        state = start.clone()
        run_stage(anny_model, state, dataclasses.replace(problem, predicted_keypoints=prediction), MESH, profile,
                  1000.0, torch.zeros(1, dtype=torch.bool))
        return _keypoints(anny_model, state)

    def off(joints: torch.Tensor) -> float:
        return float((joints - predicted).norm(dim=-1).mean())

    free = fitted(0.0, predicted)
    assert off(free) > 0.03  # the data move the joints from the start
    assert off(fitted(1000.0, predicted)) < 0.5 * off(free)
    assert off(fitted(1000.0, predicted, "adam")) < off(fitted(0.0, predicted, "adam"))
    assert torch.allclose(fitted(1000.0, torch.full_like(predicted, float("nan"))), free)


def test_the_final_loss_leaves_the_hold_out(anny_model):
    """A refresh compares the warm fit's final loss with a cold fit's, which has no prediction: the hold
    is not in it."""
    fitter, problem, start, _ = _setup(anny_model, 1000.0)
    profile = fitter.config.optimizer
    predicted = _keypoints(anny_model, start) + 0.05
    held = dataclasses.replace(problem, predicted_keypoints=predicted, predicted_transl=None)
    state = start.clone()
    report = optimize(anny_model, state, held, profile, 1000.0)
    with torch.no_grad():
        unheld = stage_loss(anny_model, state, dataclasses.replace(held, predicted_keypoints=None),
                            stage_plan(profile)[-1], profile)
        total = stage_loss(anny_model, state, held, stage_plan(profile)[-1], profile)
    assert torch.allclose(report.final_loss, unheld, rtol=1e-4)
    assert float(total[0] - unheld[0]) > 0  # there was a hold to leave out


def test_weight_zero_leaves_the_fit_unchanged(anny_model):
    """With `joint_motion` 0 (the default) a prediction that comes with the warm start changes nothing."""
    fitter, _, _, person = _setup(anny_model, 0.0)
    K = default_intrinsics()
    obs = dataclasses.replace(person.observation, predicted_pelvis=np.asarray(person.observation.init.transl))
    plain = fitter.fit([obs], K)[0]
    predicted = np.asarray(plain.keypoints3d, np.float64) + np.array([0.0, 0.1, 0.0])
    with_prediction = fitter.fit([dataclasses.replace(obs, predicted_keypoints=predicted)], K)[0]
    assert np.array_equal(plain.keypoints3d, with_prediction.keypoints3d)
    assert plain.quality.final_loss == with_prediction.quality.final_loss
    held = _setup(anny_model, 1000.0)[0].fit([dataclasses.replace(obs, predicted_keypoints=predicted)], K)[0]
    assert not np.array_equal(plain.keypoints3d, held.keypoints3d)  # ... which a weight would


# -- the tracker's prediction -----------------------------------------------------------------------------
def _fit(pid: int, keypoints: np.ndarray, warm: bool) -> BodyFit:
    x = keypoints[[11, 12]].mean(0)
    params = BodyParams("anny", np.full(6, 0.5), np.zeros((19, 3)), np.zeros(3), x.copy())
    return BodyFit(pid, params, ["j"] * 19, np.zeros((4, 3), np.float32), keypoints.astype(np.float32),
                   np.zeros((19, 3), np.float32), FitQuality(2.0, 0.02, 50, [], True, 0.1),
                   flags={FLAG_WARM_START} if warm else set())


def _observation(pid: int, x: float) -> PersonObservation:
    points = np.array([x, 0.0, 5.0]) + 0.05 * np.random.default_rng(0).standard_normal((50, 3))
    return PersonObservation(pid, np.zeros((17, 3)), np.array([300.0, 100.0, 340.0, 300.0]),
                             points.astype(np.float32))


def _tracked(mode: str, warm: bool = True) -> tuple[Tracker, np.ndarray, np.ndarray]:
    """A track with two fits 0.1 s apart whose joints moved by `velocity` (m per frame), the second
    one warm or not."""
    tracker = Tracker(dataclasses.replace(load_config().tracking, joint_prediction=mode))
    rng = np.random.default_rng(1)
    first = np.array([0.0, 0.0, 5.0]) + 0.3 * rng.standard_normal((17, 3))
    velocity = 0.02 * rng.standard_normal((17, 3))
    for frame, keypoints in ((0, first), (1, first + velocity)):
        people = tracker.assign([_observation(2, 0.0)], frame * NS)
        tracker.update([_fit(2, keypoints, warm=warm and frame == 1)], people, frame * NS)
    return tracker, first + velocity, velocity


def test_the_tracker_predicts_each_joint_at_its_velocity():
    tracker, last, velocity = _tracked("constant_velocity")
    start = tracker.warm_start(2, 2 * NS)
    assert np.allclose(start.keypoints, last + velocity, atol=1e-5)
    assert np.allclose(tracker.warm_start(2, 3 * NS).keypoints, last + 2 * velocity, atol=1e-5)  # two frames on
    # `filtered`: the same motion about the hip midpoint, which goes where the motion filter predicts it
    tracker, last, velocity = _tracked("filtered")
    start = tracker.warm_start(2, 2 * NS)
    hips = [11, 12]
    relative = last - last[hips].mean(0) + velocity - velocity[hips].mean(0)
    assert np.allclose(start.keypoints, start.pelvis + relative, atol=1e-5)
    # `last_pose`, and after a fit that was not warm (a cold fit's change is no motion): the last pose at
    # the predicted pelvis
    for tracker, last, _ in (_tracked("last_pose"), _tracked("constant_velocity", warm=False)):
        start = tracker.warm_start(2, 2 * NS)
        assert np.allclose(start.keypoints, last - last[hips].mean(0) + start.pelvis, atol=1e-5)
