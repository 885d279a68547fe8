"""L_free: the LiDAR's beams cast against the body, and the fit moving a limb out of the space they crossed."""

import numpy as np
import pytest
import torch

from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, sample_surface
from smplify3d_ros.fitting import free_space
from smplify3d_ros.fitting.fitter import FitOptions, Fitter
from smplify3d_ros.fitting.init import upright_root_orient
from smplify3d_ros.fitting.losses import project
from smplify3d_ros.fitting.visibility import front_facing, visible_vertices
from smplify3d_ros.types import BodyParams, PersonObservation

SENSOR = np.zeros(3)
MARGIN = 0.05


def test_vertex_faces_lists_the_faces_around_each_vertex():
    faces = np.array([[0, 1, 2], [0, 2, 3], [3, 2, 4]])
    around = free_space.vertex_faces(faces, 6)
    assert around.shape == (6, 3)
    for v in range(6):
        assert sorted(f for f in around[v] if f >= 0) == [f for f in range(3) if v in faces[f]]


def test_first_hits_finds_the_nearest_crossed_face_and_where_on_it():
    # two unit squares facing the sensor, at 2 m and at 3 m
    vertices = np.array([[-1, -1, 2], [1, -1, 2], [1, 1, 2], [-1, 1, 2]], float)
    vertices = np.concatenate([vertices, vertices + [0, 0, 1]])
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    directions = np.array([[0.1, 0.2, 1.0], [0.3, 0.0, 1.0], [0.0, 0.0, -1.0]])
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    candidates = np.array([[2, 3, 0, 1], [2, 3, -1, -1], [0, 1, 2, 3]])
    face, reach, bary = free_space.first_hits(vertices, faces, candidates, SENSOR, directions)
    assert face[0] in (0, 1) and reach[0] == pytest.approx(2.0 / directions[0, 2])
    hit = (bary[0][:, None] * vertices[faces[face[0]]]).sum(0)
    np.testing.assert_allclose(hit, directions[0] * reach[0], atol=1e-12)
    assert face[1] in (2, 3) and reach[1] == pytest.approx(3.0 / directions[1, 2])  # the near square: no candidate
    assert face[2] == -1 and np.isinf(reach[2])  # behind the sensor


def _body(model, right_shoulder_flexion_deg=0.0, transl=(0.0, 0.3, 3.0)) -> BodyParams:
    """A standing body facing the sensor, its right arm raised forward by the given flexion."""
    angles = torch.zeros(1, len(model.joint_names), 3, dtype=torch.float64)
    angles[0, model.joint_names.index("right_shoulder"), 0] = np.deg2rad(right_shoulder_flexion_deg)
    pose = model.anatomical_to_pose(angles, from_neutral=True)[0].numpy()
    return BodyParams(model.name, np.full(len(model.shape_names), 0.5), pose, upright_root_orient(0.0),
                      np.asarray(transl, float))


def _cast(model, body, points):
    faces = model.faces.cpu().numpy()
    visible = visible_vertices(body.vertices, faces, model.part_of_face.cpu().numpy(), SENSOR, 0.2,
                               np.zeros(10, dtype=bool))
    return free_space.blocked_beams(body.vertices, faces, free_space.vertex_faces(faces, len(body.vertices)),
                                    visible, points, SENSOR, MARGIN)


def _scan(model, body, rng, n=400):
    """Points over the body's surface that faces the sensor, with 5 mm of noise."""
    faces = model.faces.cpu().numpy()
    front = front_facing(body.vertices, faces, SENSOR, 0.0) & (model.part_of_face.cpu().numpy() >= 0)
    return sample_surface(body.vertices, faces[front], n, 0.005, rng)


def test_a_body_where_its_points_are_blocks_almost_none_of_their_beams(anny_model, rng):
    body = anny_model.posed([_body(anny_model)])[0]
    hits, _, _ = _cast(anny_model, body, _scan(anny_model, body, rng))
    assert len(hits) <= 8  # of 400: a point sampled on a face the sensor sees only past another


def test_a_body_in_front_of_its_points_blocks_their_beams_short_by_the_gap(anny_model, rng):
    truth = anny_model.posed([_body(anny_model)])[0]
    points = _scan(anny_model, truth, rng)
    nearer = anny_model.posed([_body(anny_model, transl=(0.0, 0.3, 2.8))])[0]
    hits, direction, limit = _cast(anny_model, nearer, points)
    assert len(hits) >= 0.9 * len(points)
    reach = np.linalg.norm(hits - SENSOR, axis=1)
    assert np.median(limit - reach) == pytest.approx(0.2 - MARGIN, abs=0.03)  # 20 cm nearer, less the margin
    np.testing.assert_allclose(np.linalg.norm(direction, axis=1), 1.0)


def test_an_arm_raised_towards_the_sensor_blocks_the_beams_behind_it(anny_model, rng):
    truth = anny_model.posed([_body(anny_model)])[0]
    points = _scan(anny_model, truth, rng)
    raised = anny_model.posed([_body(anny_model, right_shoulder_flexion_deg=80.0)])[0]
    hits, _, limit = _cast(anny_model, raised, points)
    already = len(_cast(anny_model, truth, points)[0])
    # the beams the raised arm blocks: within its reach of the right shoulder and well in front of it
    shoulder = raised.keypoints3d[6]
    by_arm = (np.linalg.norm(hits - shoulder, axis=1) < 0.75) & (hits[:, 2] < shoulder[2] - 0.1)
    assert by_arm.sum() >= 5 and len(hits) - by_arm.sum() <= already
    assert np.all(limit > np.linalg.norm(hits, axis=1))


def _arm_forward_person(model, rng):
    """Keypoints of a body with its right arm raised towards the sensor, points of the same body with
    the arm hanging: the image agrees with the start, the LiDAR says the arm is not there."""
    K = default_intrinsics()
    start = _body(model, right_shoulder_flexion_deg=80.0)
    raised = model.posed([start])[0]
    uv = project(torch.as_tensor(raised.keypoints3d)[None], torch.as_tensor(K))[0].numpy()
    keypoints = np.concatenate([uv, np.ones((17, 1))], axis=1)
    points = _scan(model, model.posed([_body(model)])[0], rng).astype(np.float32)
    obs = PersonObservation(0, keypoints, np.array([*uv.min(0), *uv.max(0)]), points, init=start)
    return obs, K


def test_the_mesh_stage_moves_an_arm_out_of_the_space_its_beams_crossed(anny_model, rng):
    obs, K = _arm_forward_person(anny_model, rng)
    wrist_z = {}
    for weight in (0.0, 600.0):
        config = load_config(overrides={"fitting": {"profiles": {"robot": {"weights": {"free_space": weight}}}}})
        fit = Fitter(config.fitting, anny_model).fit([obs], K, options=FitOptions(use_icp=False))[0]
        wrist_z[weight] = float(fit.keypoints3d[10, 2])
    start_z = float(anny_model.posed([obs.init])[0].keypoints3d[10, 2])
    print(f"right wrist depth: start {start_z:.3f} m, fitted without L_free {wrist_z[0.0]:.3f}, "
          f"with {wrist_z[600.0]:.3f}")
    assert wrist_z[600.0] > wrist_z[0.0] + 0.05  # pushed back, away from the sensor


def test_the_init_refinement_casts_the_beams_with_its_own_weight_alone(anny_model, rng, monkeypatch):
    # init.refine_free_space works whatever the profile's own free-space weight is
    obs, K = _arm_forward_person(anny_model, rng)
    obs = PersonObservation(obs.person_id, obs.keypoints, obs.bbox, obs.points)  # the built-in init
    casts = []
    cast = Fitter._blocked_beams
    monkeypatch.setattr(Fitter, "_blocked_beams", lambda self, *args: casts.append(1) or cast(self, *args))
    for refine in (0.0, 600.0):
        casts.clear()
        config = load_config(overrides={"fitting": {"profiles": {"robot": {"weights": {"free_space": 0.0}}},
                                                     "init": {"refine_free_space": refine}}})
        Fitter(config.fitting, anny_model).fit([obs], K)
        assert bool(casts) == (refine > 0)
