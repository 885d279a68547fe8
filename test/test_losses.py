"""Each loss term of Eq. 3-8 on cases computed by hand."""

import math

import numpy as np
import pytest
import roma
import torch

from smplify3d_ros.fitting import losses


def test_geman_mcclure_values():
    x = torch.tensor([0.0, 1.0, 10.0, -10.0])
    out = losses.geman_mcclure(x, sigma=10.0)
    # σ²x²/(σ²+x²): 0, 100/101, 100*100/200 = 50, 50
    assert torch.allclose(out, torch.tensor([0.0, 100.0 / 101.0, 50.0, 50.0]))
    # bounded by σ² for huge residuals
    assert losses.geman_mcclure(torch.tensor([1e6]), 3.0).item() < 9.0 + 1e-6


def test_project_pinhole():
    K = torch.tensor([[500.0, 0, 320], [0, 400.0, 240], [0, 0, 1]])
    pts = torch.tensor([[[0.0, 0.0, 2.0], [1.0, -0.5, 2.0]]])
    uv = losses.project(pts, K)
    assert torch.allclose(uv, torch.tensor([[[320.0, 240.0], [570.0, 140.0]]]))


def test_reprojection_loss_hand_case():
    proj = torch.zeros(1, 17, 2)
    target = torch.zeros(1, 17, 2)
    target[0, 0] = torch.tensor([3.0, 4.0])  # one joint off by (3, 4)
    conf = torch.full((1, 17), 0.5)
    sigma = 100.0
    expected = 0.25 * (sigma**2 * 9 / (sigma**2 + 9) + sigma**2 * 16 / (sigma**2 + 16))
    out = losses.reprojection_loss(proj, target, conf, sigma)
    assert math.isclose(out.item(), expected, rel_tol=1e-5)


@pytest.mark.parametrize("align", losses.ALIGNMENTS)
def test_keypoint_alignment_removes_a_pure_shift(align):
    proj = torch.rand(2, 17, 2) * 100
    target = proj + torch.tensor([25.0, -40.0])
    conf = torch.rand(2, 17) + 0.1
    assert losses.reprojection_loss(proj, target, conf, 50.0, align=align).abs().max() < 1e-3
    assert losses.reprojection_loss(proj, target, conf, 50.0).min() > 100


def test_alignment_shift_hand_cases():
    proj = torch.zeros(1, 17, 2)
    target = torch.zeros(1, 17, 2)
    target[0, 11] = torch.tensor([10.0, 0.0])  # one hip detected 10 px to the right
    conf = torch.ones(1, 17)
    # hips: the midpoint moves 5 px, so the whole skeleton is shifted 5 px left
    assert torch.allclose(losses.alignment_shift(proj, target, conf, "hips"), torch.tensor([[-5.0, 0.0]]))
    # centroid: the mean offset over 17 equally confident keypoints
    assert torch.allclose(losses.alignment_shift(proj, target, conf, "centroid"), torch.tensor([[-10.0 / 17, 0.0]]))
    # a zero-confidence keypoint does not count; confidence enters squared
    conf[0, 11] = 0.0
    assert torch.allclose(losses.alignment_shift(proj, target, conf, "centroid"), torch.zeros(1, 2))
    target[0, 0] = torch.tensor([0.0, 12.0])
    conf[0, 0] = 2.0  # weight 4 against 15 others of weight 1
    assert torch.allclose(losses.alignment_shift(proj, target, conf, "centroid"), torch.tensor([[0.0, -48.0 / 19]]))
    with pytest.raises(ValueError, match="alignment"):
        losses.alignment_shift(proj, target, conf, "pelvis")


def test_chamfer_hand_case():
    verts = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0], [9.0, 9, 9]]])
    vmask = torch.tensor([[True, True, False]])  # the third vertex is padding
    pts = torch.tensor([[[0.0, 0, 0.1], [1.0, 0, 0.3]]])
    pmask = torch.ones(1, 2, dtype=torch.bool)
    # v->p: 0.01, 0.09 -> mean 0.05; p->v: 0.01, 0.09 -> mean 0.05
    assert math.isclose(losses.chamfer_loss(verts, vmask, pts, pmask).item(), 0.1, rel_tol=1e-5)
    # without the vertex-to-point half (robot profile): p->v only
    assert math.isclose(losses.chamfer_loss(verts, vmask, pts, pmask, 0.0).item(), 0.05, rel_tol=1e-5)


def test_chamfer_empty_person_is_zero_and_has_gradient_elsewhere():
    verts = torch.rand(2, 5, 3, requires_grad=True)
    vmask = torch.tensor([[True] * 5, [False] * 5])
    pts = torch.rand(2, 4, 3)
    pmask = torch.ones(2, 4, dtype=torch.bool)
    loss = losses.chamfer_loss(verts, vmask, pts, pmask)
    assert loss[1].item() == 0.0 and loss[0].item() > 0
    loss.sum().backward()
    assert verts.grad[0].abs().sum() > 0 and verts.grad[1].abs().sum() == 0


def test_occlusion_prior():
    pose = torch.zeros(1, 3, 3)
    pose[0, 0] = torch.tensor([0.0, 0.0, 1.0])  # 1 rad about z on joint 0
    init = torch.zeros(1, 3, 3)
    mask = torch.tensor([[1.0, 0.0, 0.0]])
    # 1 - cos²(θ/2) = sin²(θ/2)
    out = losses.occlusion_prior(pose, init, mask)
    assert math.isclose(out.item(), math.sin(0.5) ** 2, rel_tol=1e-5)
    # an unmasked joint contributes nothing
    assert losses.occlusion_prior(pose, init, torch.tensor([[0.0, 1.0, 1.0]])).item() == 0.0


def test_occlusion_prior_sign_invariant():
    rotvec = torch.tensor([[[0.3, -0.2, 0.5]]])
    q = roma.rotvec_to_unitquat(rotvec)
    assert torch.allclose(roma.unitquat_to_rotvec(-q), rotvec, atol=1e-5)
    assert losses.occlusion_prior(rotvec, rotvec, torch.ones(1, 1)).item() < 1e-6


def test_nearest_sq_distances_matches_brute_force(rng):
    src = torch.as_tensor(rng.random((1, 50, 3)))
    dst = torch.as_tensor(rng.random((1, 40, 3)))
    mask = torch.ones(1, 40, dtype=torch.bool)
    got = losses.nearest_sq_distances(src, dst, mask)
    brute = ((src[0, :, None] - dst[0, None]) ** 2).sum(-1).min(-1).values
    assert np.allclose(got[0].numpy(), brute.numpy())


def test_nearest_indices_both_ways_with_masks_empty_rows_and_a_diverged_body(rng):
    """The k-d tree search gives the brute-force neighbours among the valid targets, both ways; a person
    without a valid target gets index 0 (as the distance matrix did), and NaN coordinates (a diverged
    body) neither stop the search nor become anyone's neighbour."""
    a = torch.as_tensor(rng.normal(0, 1, (3, 60, 3)) + [0.0, 0.0, 5.0])
    b = torch.as_tensor(rng.normal(0, 1, (3, 45, 3)) + [0.0, 0.0, 5.0])
    b_mask = torch.as_tensor(rng.random((3, 45)) < 0.7)
    a_mask = torch.as_tensor(rng.random((3, 60)) < 0.8)
    b_mask[2] = False  # person 2: nothing valid on the b side
    b[1, 0] = float("nan")  # person 1: a diverged vertex, masked valid
    b_mask[1, 0] = True
    a_to_b, b_to_a = losses.nearest_indices(a, b, b_mask, a_mask)
    for k in range(2):
        d = ((a[k, :, None] - b[k, None]) ** 2).sum(-1).nan_to_num(float("inf"))
        expected_ab = d.masked_fill(~b_mask[k][None], float("inf")).argmin(-1)
        expected_ba = d.masked_fill(~a_mask[k][:, None], float("inf")).argmin(0)
        finite = torch.isfinite(b[k]).all(-1)  # a NaN vertex's own neighbour means nothing
        assert torch.equal(a_to_b[k], expected_ab) and torch.equal(b_to_a[k][finite], expected_ba[finite])
    assert (a_to_b[2] == 0).all()
    assert not (a_to_b[1] == 0).any(), "the NaN vertex is nobody's neighbour"


def test_chamfer_vertex_weight_scales_only_the_vertex_half():
    verts = torch.tensor([[[0.0, 0, 0], [1.0, 0, 0]]])
    pts = torch.tensor([[[0.0, 0, 0.1]]])
    vmask = torch.ones(1, 2, dtype=torch.bool)
    pmask = torch.ones(1, 1, dtype=torch.bool)
    # v->p: (0.01 + 1.01) / 2 = 0.51; p->v: 0.01
    full = losses.chamfer_loss(verts, vmask, pts, pmask)
    points_only = losses.chamfer_loss(verts, vmask, pts, pmask, vertex_weight=0.0)
    assert math.isclose(full.item(), 0.52, rel_tol=1e-5)
    assert math.isclose(points_only.item(), 0.01, rel_tol=1e-4)
