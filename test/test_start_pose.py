"""The built-in initializer's start pose: elbows flexed, so that a forearm the image shows end-on or
across the body is not left where a straight arm's singular start holds it."""

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from smplify3d_ros.config import load_config
from smplify3d_ros.eval.synthetic import default_intrinsics, sample_surface
from smplify3d_ros.fitting.fitter import Fitter
from smplify3d_ros.fitting.init import builtin_hypotheses, image_trunk_start, pitched_root_orient, upright_root_orient
from smplify3d_ros.fitting.losses import project
from smplify3d_ros.fitting.visibility import front_facing
from smplify3d_ros.types import BodyParams, PersonObservation

ELBOWS = ("left_elbow", "right_elbow")


def _init_fitter(model, **init) -> Fitter:
    """A fitter with these `fitting.init` settings over the defaults."""
    return Fitter(load_config(overrides={"fitting": {"init": init}}).fitting, model)


def _fitter(model, flexion_deg: float) -> Fitter:
    return _init_fitter(model, start_elbow_flexion_deg=flexion_deg)


@pytest.mark.parametrize("flexion_deg", [0.0, 90.0])
def test_the_start_pose_is_the_anatomical_neutral_with_the_elbows_flexed(anny_model, flexion_deg):
    start = torch.as_tensor(_fitter(anny_model, flexion_deg)._start_pose)[None]
    angles = (anny_model.pose_to_anatomical(start) + anny_model.anat_rest.to(start.dtype))[0].numpy()
    elbows = [anny_model.joint_names.index(name) for name in ELBOWS]
    np.testing.assert_allclose(angles[elbows, 0], np.deg2rad(flexion_deg), atol=1e-6)
    rest = np.delete(angles, elbows, axis=0)
    np.testing.assert_allclose(rest, 0.0, atol=1e-6)  # every other angle at the neutral, elbow's others too
    np.testing.assert_allclose(np.delete(angles[elbows], 0, axis=1), 0.0, atol=1e-6)


def _facing_person(model, rng, flexed: tuple[str, ...], degrees: float, transl: tuple[float, float, float],
                   root: np.ndarray | None = None, n_points: int = 300):
    """A person at `transl` with the joints `flexed` by `degrees` from the anatomical neutral, facing the
    camera unless `root` turns them: perfect keypoints, `n_points` points over the surface facing the
    sensor."""
    angles = torch.zeros(1, len(model.joint_names), 3, dtype=torch.float64)
    for name in flexed:
        angles[0, model.joint_names.index(name), 0] = np.deg2rad(degrees)
    pose = model.anatomical_to_pose(angles, from_neutral=True)[0].numpy()
    root = upright_root_orient(0.0) if root is None else root
    truth = BodyParams(model.name, np.full(len(model.shape_names), 0.5), pose, root, np.array(transl))
    body = model.posed([truth])[0]
    K = default_intrinsics()
    uv = project(torch.as_tensor(body.keypoints3d)[None], torch.as_tensor(K))[0].numpy()
    keypoints = np.concatenate([uv, np.ones((17, 1))], axis=1)
    faces = model.faces.cpu().numpy()
    front = front_facing(body.vertices, faces, np.zeros(3), 0.0) & (model.part_of_face.cpu().numpy() >= 0)
    points = sample_surface(body.vertices, faces[front], n_points, 0.005, rng).astype(np.float32)
    return PersonObservation(0, keypoints, np.array([*uv.min(0), *uv.max(0)]), points), K, body


def _carrying_person(model, rng):
    """A person 3 m in front of the camera holding both forearms forward, pointing at it (the image sees
    them end-on)."""
    return _facing_person(model, rng, ELBOWS, 95.0, (0.0, 0.3, 3.0))


def test_forearms_held_towards_the_camera_are_found_from_the_bent_start(anny_model, rng):
    obs, K, body = _carrying_person(anny_model, rng)
    wrists = [9, 10]
    error = {}
    for flexion in (0.0, 90.0):
        fit = _fitter(anny_model, flexion).fit([obs], K)[0]
        error[flexion] = float(np.linalg.norm(fit.keypoints3d[wrists] - body.keypoints3d[wrists], axis=1).mean())
    # measured: 0.54 m from the straight start (the arms left hanging), 0.10 m from the bent one
    assert error[90.0] < 0.15
    assert error[90.0] < 0.3 * error[0.0]


LEGS = ("left_hip", "right_hip", "left_knee", "right_knee")


def _legs_fitter(model, hypotheses: int, **init) -> Fitter:
    init = {"flexed_leg_hypotheses": hypotheses, "bent_trunk_hypotheses": 0, **init}  # the leg starts alone
    return _init_fitter(model, **init)


def test_the_flexed_leg_start_flexes_hips_and_knees_only(anny_model):
    fitter = _legs_fitter(anny_model, 2)
    init = fitter.config.init
    flexed = torch.as_tensor(fitter._flexed_start_pose)[None]
    angles = (anny_model.pose_to_anatomical(flexed) + anny_model.anat_rest.to(flexed.dtype))[0].numpy()
    index = {name: anny_model.joint_names.index(name) for name in (*LEGS, *ELBOWS)}
    for name, degrees in (("hip", init.start_hip_flexion_deg), ("knee", init.start_knee_flexion_deg),
                          ("elbow", init.start_elbow_flexion_deg)):
        for side in ("left", "right"):
            np.testing.assert_allclose(angles[index[f"{side}_{name}"], 0], np.deg2rad(degrees), atol=1e-6)
    others = np.delete(angles, list(index.values()), axis=0)
    np.testing.assert_allclose(others, 0.0, atol=1e-6)


def _sitting_person(model, rng):
    """A person 3.5 m in front of the camera, sitting (hips and knees flexed 90°, no chair drawn), facing
    it: the thighs point at the camera, which sees them end-on."""
    return _facing_person(model, rng, LEGS, 90.0, (0.0, 0.4, 3.5))


def test_thighs_pointing_at_the_camera_are_found_from_the_flexed_leg_start(anny_model, rng):
    obs, K, body = _sitting_person(anny_model, rng)
    knees = [13, 14]
    error = {}
    for hypotheses in (0, 2):
        fit = _legs_fitter(anny_model, hypotheses).fit([obs], K)[0]
        error[hypotheses] = float(np.linalg.norm(fit.keypoints3d[knees] - body.keypoints3d[knees], axis=1).mean())
    print(f"knee error: standing starts only {1000 * error[0]:.0f} mm, with flexed-leg starts {1000 * error[2]:.0f} mm")
    assert error[2] < 0.08 and error[0] > 2 * error[2], error  # measured: 370 mm against 38 mm


def _starts(fitter: Fitter, obs, K) -> int:
    from smplify3d_ros.fitting.options import FitOptions

    batch = fitter._start([obs], K, None, FitOptions())
    fitter._initialize(batch)
    return len(batch.hypotheses[0])


def test_no_flexed_leg_start_where_neither_the_image_nor_the_points_can_tell(anny_model, rng):
    """No thigh seen: the flexed starts are tried only where both knees are seen, with the person's points,
    and for a person tall enough in the image (`init.flexed_leg_min_px`) for those to tell them apart."""
    import dataclasses

    obs, K, _ = _sitting_person(anny_model, rng)

    def scored(joints: list[int], score: float, points: bool = True):
        keypoints = obs.keypoints.copy()
        keypoints[joints, 2] = score
        return dataclasses.replace(obs, keypoints=keypoints, points=obs.points if points else obs.points[:0])

    low_hips = scored([11, 12], 0.5)  # the thighs hide the hips; the knees are seen
    knee_hidden = scored([11, 12, 14], 0.1)
    tall_px = float(K[0, 0]) * 1.70 / 3.5  # about 150 px at 3.5 m
    near, far = (_legs_fitter(anny_model, 2, flexed_leg_min_px=k * tall_px) for k in (0.5, 2.0))
    headings = _starts(near, scored([11, 12], 0.5, points=False), K)  # no points: the standing starts alone
    flexed = headings + min(2, headings)
    assert _starts(near, obs, K) == flexed  # a thigh seen
    assert _starts(far, obs, K) == flexed  # ... whatever the person's size
    assert _starts(near, low_hips, K) == flexed  # no thigh, but both knees and points, on a person this tall
    assert _starts(far, low_hips, K) == headings  # ... too small in the image for them to tell
    assert _starts(near, knee_hidden, K) == headings  # a knee hidden: the leg is the priors' guess
    thigh_only = _legs_fitter(anny_model, 2, flexed_leg_min_px=0.0)
    assert _starts(thigh_only, low_hips, K) == headings  # 0: a thigh must be seen


HIPS = ("left_hip", "right_hip")


def _trunk_fitter(model, hypotheses: int) -> Fitter:
    return _init_fitter(model, bent_trunk_hypotheses=hypotheses)


def test_the_bent_start_pitches_the_pelvis_forward_and_keeps_the_legs_upright(anny_model):
    fitter = _trunk_fitter(anny_model, 1)
    pitch = np.deg2rad(fitter.config.init.start_trunk_pitch_deg)
    bent_pose = fitter._pitched_start_pose(fitter.config.init.start_trunk_pitch_deg)
    bent = torch.as_tensor(bent_pose)[None]
    angles = (anny_model.pose_to_anatomical(bent) + anny_model.anat_rest.to(bent.dtype))[0].numpy()
    hips = [anny_model.joint_names.index(name) for name in HIPS]
    np.testing.assert_allclose(angles[hips, 0], pitch, atol=1e-6)  # the hips flexed by the pitch ...
    yaw = 0.7
    root = pitched_root_orient(upright_root_orient(yaw), pitch)
    up = Rotation.from_rotvec(root).as_matrix()[:, 1]  # the body's up in the camera frame (y down)
    forward = np.array([np.sin(yaw), 0.0, -np.cos(yaw)])  # where the upright body faces
    np.testing.assert_allclose(up @ forward, np.sin(pitch), atol=1e-9)  # ... the pelvis leans forward
    body = anny_model.posed([BodyParams(anny_model.name, np.full(len(anny_model.shape_names), 0.5),
                                        bent_pose, root, np.zeros(3))])[0]
    index = {name: anny_model.joint_names.index(name) for name in ("left_hip", "left_ankle", "neck")}
    leg = body.joints[index["left_ankle"]] - body.joints[index["left_hip"]]
    assert np.degrees(np.arccos(leg @ np.array([0.0, 1.0, 0.0]) / np.linalg.norm(leg))) < 5  # legs upright
    trunk = body.joints[index["neck"]] - body.joints[index["left_hip"]]
    assert trunk @ forward > 0.3  # the neck well ahead of the hips


def _bent_person(model, rng, degrees: float = 60.0):
    """A person 5 m in front of the camera, side-on to it, bent over at the hips by `degrees`, 60 points on
    the surface facing the sensor (a VLP-16's at about that range): from a standing start the solver folds
    the spine or leans the whole body instead."""
    root = pitched_root_orient(upright_root_orient(np.pi / 2), np.deg2rad(degrees))
    return _facing_person(model, rng, HIPS, degrees, (0.0, 0.5, 5.0), root=root, n_points=60)


def test_a_person_bent_over_is_found_from_the_bent_start(anny_model, rng):
    """Counterfactual without the hypotheses' review (`init.hypothesis_review_iterations` 0), which finds
    this person from a standing start too (36 mm): its visible vertices, picked again from a body that has
    begun to bend, draw the trunk down to the points."""
    obs, K, body = _bent_person(anny_model, rng)
    error = {}
    for hypotheses in (0, 1):
        fitter = _init_fitter(anny_model, bent_trunk_hypotheses=hypotheses, hypothesis_review_iterations=0,
                              image_trunk_max_pitch_deg=0.0)  # the start the image reads finds it too (30 mm)
        fit = fitter.fit([obs], K)[0]
        error[hypotheses] = float(np.linalg.norm(fit.joints - body.joints, axis=1).mean())
    print(f"MPJPE: without the bent start {1000 * error[0]:.0f} mm, with it {1000 * error[1]:.0f} mm")
    assert error[1] < 0.06 and error[0] > 2 * error[1], error  # measured: 181 mm against 28 mm
    fit = _trunk_fitter(anny_model, 1).fit([obs], K)[0]  # with the review (the default)
    assert float(np.linalg.norm(fit.joints - body.joints, axis=1).mean()) < 0.06


def test_no_bent_start_from_the_image_alone(anny_model, rng):
    """Without LiDAR a trunk bent towards the camera projects as a short upright one: no bent start."""
    import dataclasses

    obs, K, _ = _bent_person(anny_model, rng)
    fitter = _trunk_fitter(anny_model, 1)
    without = _trunk_fitter(anny_model, 0)
    assert _starts(fitter, obs, K) == _starts(without, obs, K) + 1
    image_only = dataclasses.replace(obs, points=obs.points[:0])
    assert _starts(fitter, image_only, K) == _starts(without, image_only, K)


def _bent_towards(model, rng, yaw: float, degrees: float, distance: float, n_points: int):
    """A person bent over at the hips by `degrees`, turned by `yaw` from facing the camera, the pelvis
    0.45 m above the camera (a Jackal's) `distance` m out, `n_points` points on the surface facing it."""
    root = pitched_root_orient(upright_root_orient(yaw), np.deg2rad(degrees))
    return _facing_person(model, rng, HIPS, degrees, (0.0, -0.45, distance), root=root, n_points=n_points)


def _read(obs, K, cfg):
    hypotheses = builtin_hypotheses(obs, K, cfg.init, True, True)
    return image_trunk_start(obs, K, cfg.init, [root for root, _ in hypotheses], hypotheses[0][1])


def _trunk_forward(root: np.ndarray) -> np.ndarray:
    """Where the body's trunk points (its up axis), camera frame."""
    return Rotation.from_rotvec(root).as_matrix()[:, 1]


@pytest.mark.parametrize(("yaw", "degrees", "distance"), [(np.pi / 2, 90.0, 6.0), (-np.pi / 2, 80.0, 4.0),
                                                          (np.pi / 2 + 0.4, 60.0, 8.0)])
def test_the_image_reads_a_trunk_bent_over_side_on(anny_model, rng, yaw, degrees, distance):
    """Side-on, the trunk's line in the image says how far the person leans, and which way: so which
    way they face."""
    obs, K, body = _bent_towards(anny_model, rng, yaw, degrees, distance, 200)
    cfg = load_config().fitting
    read = _read(obs, K, cfg)
    truth = _trunk_forward(pitched_root_orient(upright_root_orient(yaw), np.deg2rad(degrees)))
    angle = np.degrees(np.arccos(np.clip(_trunk_forward(read.root_orient) @ truth, -1.0, 1.0)))
    print(f"read pitch {read.pitch_deg:.0f} deg (truth {degrees:.0f}), trunk {angle:.0f} deg off")
    assert angle < 20.0 and abs(read.pitch_deg - degrees) <= 20.0


def test_a_person_bent_towards_the_camera_is_found_from_the_start_the_image_reads(anny_model, rng):
    """From the fixed bent start (55 deg, the first heading) and the standing ones, a trunk bent 85 deg
    towards the camera 2.6 m out is fitted standing, its pelvis where the trunk's points are."""
    obs, K, body = _bent_towards(anny_model, rng, 0.3, 85.0, 2.6, 300)
    error = {}
    for max_pitch in (0.0, 100.0):
        fit = _init_fitter(anny_model, image_trunk_max_pitch_deg=max_pitch).fit([obs], K)[0]
        error[max_pitch] = float(np.linalg.norm(fit.joints - body.joints, axis=1).mean())
    print(f"MPJPE: without the read start {1000 * error[0.0]:.0f} mm, with it {1000 * error[100.0]:.0f} mm")
    assert error[100.0] < 0.07 and error[0.0] > 3 * error[100.0], error  # measured: 314 mm against 41 mm


def test_no_start_read_from_an_upright_trunk(anny_model, rng):
    obs, K, _ = _facing_person(anny_model, rng, (), 0.0, (0.0, -0.45, 4.0), root=upright_root_orient(0.8))
    cfg = load_config().fitting
    assert _read(obs, K, cfg) is None
