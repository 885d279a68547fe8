"""Evaluation metrics on hand-computed cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from smplify3d_ros.eval.metrics import (
    lidar_density,
    mesh_edges,
    mpere,
    mpjpe,
    pa_mpjpe,
    procrustes_align,
    projected_area,
    pve,
    root_aligned,
)


def test_pve_and_mpjpe_of_a_translation():
    gt = np.random.default_rng(0).normal(size=(20, 3))
    pred = gt + np.array([0.003, 0.004, 0.0])  # 5 mm for every point
    assert pve(pred, gt) == pytest.approx(5.0)
    assert mpjpe(pred, gt) == pytest.approx(5.0)
    batch = mpjpe(np.stack([pred, gt]), np.stack([gt, gt]))
    np.testing.assert_allclose(batch, [5.0, 0.0], atol=1e-9)


def test_mpjpe_hand_case():
    gt = np.zeros((4, 3))
    pred = np.array([[0.0, 0, 0], [0.1, 0, 0], [0, 0.2, 0], [0, 0, 0.3]])
    assert mpjpe(pred, gt) == pytest.approx((0 + 100 + 200 + 300) / 4)


def test_root_alignment_removes_translation_only():
    gt = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    pred = gt + [0.5, -0.2, 3.0]
    pred[2] += [0.0, 0.0, 0.1]  # one joint also 100 mm off
    aligned = root_aligned(pred, gt, 0)
    assert mpjpe(aligned, gt) == pytest.approx(100.0 / 3)
    # the root as the mean of two rows (the hips)
    aligned2 = root_aligned(pred, gt, (0, 1))
    np.testing.assert_allclose(aligned2[:2], gt[:2], atol=1e-12)


def test_pa_mpjpe_ignores_similarity_transforms():
    gt = np.random.default_rng(1).normal(size=(17, 3))
    R = Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix()
    pred = 1.7 * gt @ R.T + [1.0, 2.0, 3.0]
    assert pa_mpjpe(pred, gt) == pytest.approx(0.0, abs=1e-6)
    assert mpjpe(pred, gt) > 1000.0


def test_pa_mpjpe_hand_case():
    # After the optimal similarity (identity here), two of four points stay 1 m off: 500 mm.
    gt = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0]])
    pred = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 0, 0], [0, 0, 0]])
    np.testing.assert_allclose(procrustes_align(pred, gt), pred, atol=1e-12)
    assert pa_mpjpe(pred, gt) == pytest.approx(500.0)


def test_pa_does_not_reflect():
    gt = np.array([[1.0, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, 0]])
    mirrored = gt * [-1, 1, 1]
    assert pa_mpjpe(mirrored, gt) > 100.0  # a reflection is not a rotation


def test_mpere_hand_cases():
    faces = np.array([[0, 1, 2]])
    gt = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    assert mpere(1.1 * gt, gt, faces) == pytest.approx(0.1)
    stretched = gt.copy()
    stretched[1] = [2.0, 0, 0]  # edge 0-1: 1 -> 2 (100 %), edge 1-2: sqrt2 -> sqrt5, edge 0-2 unchanged
    expected = (1.0 + (np.sqrt(5) - np.sqrt(2)) / np.sqrt(2) + 0.0) / 3
    assert mpere(stretched, gt, faces) == pytest.approx(expected)
    assert mpere(gt + 5.0, gt, faces) == pytest.approx(0.0)


def test_mesh_edges_are_unique():
    box = trimesh.creation.box()
    assert len(mesh_edges(box.faces)) == len(box.edges_unique)


def test_projected_area_of_a_box():
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    up = [0.0, 0.0, 1.0]
    assert projected_area(box.vertices, box.faces, [1.0, 0, 0], up) == pytest.approx(6.0, rel=0.01)
    assert projected_area(box.vertices, box.faces, [0, -1.0, 0], up) == pytest.approx(3.0, rel=0.01)
    diagonal = 3.0 * (1.0 + 2.0) / np.sqrt(2.0)  # width across a 45 deg view: (1 + 2) / sqrt 2
    assert projected_area(box.vertices, box.faces, [1.0, 1.0, 0.3], up) == pytest.approx(diagonal, rel=0.01)


def test_projected_area_of_a_sphere_counts_overlaps_once():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    assert projected_area(sphere.vertices, sphere.faces, [0, 0, 1.0], [0, -1.0, 0]) == pytest.approx(
        np.pi * 0.25, rel=0.02
    )


def test_lidar_density():
    box = trimesh.creation.box(extents=[1.0, 2.0, 3.0])
    box.apply_translation([10.0, 0.0, 1.5])
    density = lidar_density(600, box.vertices, box.faces, sensor_position=[0.0, 0.0, 0.5], up=[0, 0, 1.0])
    assert density == pytest.approx(100.0, rel=0.01)
    # camera-frame convention: up is -y
    box_cam = trimesh.creation.box(extents=[2.0, 3.0, 1.0])
    box_cam.apply_translation([0.0, 0.0, 10.0])
    assert lidar_density(600, box_cam.vertices, box_cam.faces, [0, 0, 0], [0, -1.0, 0]) == pytest.approx(
        100.0, rel=0.01
    )


def test_shape_mismatch_is_an_error():
    with pytest.raises(ValueError):
        mpjpe(np.zeros((3, 3)), np.zeros((4, 3)))
