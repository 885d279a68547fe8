"""Both body-model backends: Anny (embedded) and SMPL through a made-up SMPL-format file."""

import codecs
import pickle
import struct
import sys
import types

import numpy as np
import pytest
import roma
import scipy.sparse
import torch

from smplify3d_ros.body.base import BodyOutput
from smplify3d_ros.body.joints import BODY_JOINTS
from smplify3d_ros.body.smpl_model import SmplBody, SmplFileError, load_arrays
from smplify3d_ros.fitting.init import upright_root_orient
from smplify3d_ros.keypoints import KP, PART_NAMES


def _run(model, pose=None, root=None, transl=(0.0, 0.0, 5.0), shape=None):
    dt = model.anat_frames.dtype
    pose = torch.zeros(1, len(BODY_JOINTS), 3, dtype=dt) if pose is None else pose
    root = torch.as_tensor(upright_root_orient(0.0) if root is None else root, dtype=dt)[None]
    shape = model.mean_shape() if shape is None else shape
    with torch.no_grad():
        return model(shape[None].to(dt), pose, root, torch.tensor([transl], dtype=dt))


def test_anny_upright_facing_camera(anny_model):
    out = _run(anny_model)
    kp = out.keypoints[0].numpy()
    assert kp[KP["nose"], 1] < kp[KP["left_hip"], 1] < kp[KP["left_ankle"], 1]  # head up (y down)
    assert kp[KP["left_shoulder"], 0] > kp[KP["right_shoulder"], 0]  # facing: left on image right
    assert kp[KP["nose"], 2] < 5.0  # the face is towards the camera
    height = kp[:, 1].max() - kp[:, 1].min()
    assert 1.3 < height < 1.9
    assert out.vertices.shape == (1, 13718, 3)


def test_anny_subset_forward_matches_the_full_one(anny_model):
    """The fitting steps pose only the vertices they use (own rest shaping and skinning), and the full
    forward poses every vertex the same way: the same vertices, joints and keypoints as Anny's own
    forward (its shaping and skinning, the keypoints regressed from every vertex), and the same gradients."""
    g = torch.Generator().manual_seed(0)
    dt = anny_model.anat_frames.dtype
    B, J = 2, len(BODY_JOINTS)
    shape = (0.5 + 0.3 * (torch.rand(B, len(anny_model.shape_names), generator=g, dtype=dt) - 0.5))
    pose = 0.4 * (torch.rand(B, J, 3, generator=g, dtype=dt) - 0.5)
    root = torch.as_tensor(np.stack([upright_root_orient(0.4), upright_root_orient(-2.0)]), dtype=dt)
    transl = torch.tensor([[0.3, -0.1, 4.0], [-1.0, 0.2, 7.0]], dtype=dt)
    subset = torch.randperm(13718, generator=g)[:700]
    outputs = []
    for index in ("anny", None, subset):
        s, p = shape.clone().requires_grad_(True), pose.clone().requires_grad_(True)
        if index == "anny":
            verts, joints, _ = anny_model._posed_canonical(s, p)  # Anny's forward: no subset
            keypoints = torch.einsum("kv,bvd->bkd", anny_model.kp_weights.to(verts.dtype), verts)
            R = roma.rotvec_to_rotmat(root).transpose(1, 2)
            out = BodyOutput(*(x @ R + transl[:, None] for x in (verts, joints, keypoints)))
        else:
            out = anny_model(s, p, root, transl, index)
        vertices = out.vertices if index is subset else out.vertices[:, subset]
        (vertices.square().sum() + out.keypoints.square().sum()).backward()
        outputs.append((vertices, out.joints, out.keypoints, s.grad, p.grad))
    for reference, full, part in zip(*outputs, strict=True):
        assert torch.allclose(reference, full, atol=1e-4, rtol=1e-4)
        assert torch.allclose(reference, part, atol=1e-4, rtol=1e-4)


def test_anny_rows_of_many_hypotheses_are_rows_of_their_shapes_meshes(anny_model):
    """Per-row vertex sets of a few shapes over many rows (the built-in init's hypotheses) are shaped
    as whole meshes, one per shape, and their rows taken: the same vertices as each row posed alone."""
    g = torch.Generator().manual_seed(1)
    dt = anny_model.anat_frames.dtype
    J, n = len(BODY_JOINTS), 3000
    shapes = 0.5 + 0.3 * (torch.rand(2, len(anny_model.shape_names), generator=g, dtype=dt) - 0.5)
    shape = shapes[torch.tensor([0, 1, 0, 0, 1, 1, 0, 1, 0, 0])]  # 10 rows, 2 shapes: 2 meshes < 30,000 rows
    B = len(shape)
    pose = 0.4 * (torch.rand(B, J, 3, generator=g, dtype=dt) - 0.5)
    root = torch.zeros(B, 3, dtype=dt)
    transl = torch.tensor([0.0, 0.0, 5.0], dtype=dt).expand(B, 3)
    index = torch.stack([torch.randperm(13718, generator=g)[:n] for _ in range(B)])
    assert anny_model._rows_of_meshes(anny_model._coefficients(shape), anny_model._subset(index)) is not None
    together = anny_model(shape, pose, root, transl, index).vertices
    for b in range(B):
        alone = anny_model(shape[b:b + 1], pose[b:b + 1], root[b:b + 1], transl[b:b + 1], None).vertices[0, index[b]]
        assert torch.allclose(together[b], alone, atol=1e-6), b


def test_anny_parts_cover_every_part(anny_model):
    parts = anny_model.part_of_face.numpy()
    assert set(parts[parts >= 0]) == set(range(len(PART_NAMES)))


def test_anatomical_round_trip_and_knee_flexion(anny_model):
    angles = torch.zeros(1, len(BODY_JOINTS), 3, dtype=anny_model.anat_frames.dtype)
    angles[0, BODY_JOINTS.index("left_knee"), 0] = np.pi / 2
    pose = anny_model.anatomical_to_pose(angles, from_neutral=True)
    back = anny_model.pose_to_anatomical(pose) + anny_model.anat_rest
    assert torch.allclose(back, angles + 0 * back, atol=1e-5)
    out = _run(anny_model, pose=pose, root=np.zeros(3), transl=(0.0, 0.0, 0.0))
    kp = out.keypoints[0].numpy()  # canonical axes: y up, z forward
    knee, ankle = kp[KP["left_knee"]], kp[KP["left_ankle"]]
    assert ankle[2] < knee[2] - 0.25  # a flexed knee sends the foot backwards
    assert abs(ankle[1] - knee[1]) < 0.1


def test_priors_penalise_out_of_range_and_hyperextension(anny_model):
    dt = anny_model.anat_frames.dtype
    zero = torch.zeros(1, len(BODY_JOINTS), 3, dtype=dt)
    assert anny_model.joint_range_prior(zero).item() == 0.0
    bad = torch.zeros_like(zero)
    bad[0, BODY_JOINTS.index("left_knee"), 0] = -1.0  # knee bent the wrong way
    bad_pose = anny_model.anatomical_to_pose(bad)
    assert anny_model.joint_range_prior(bad_pose).item() > 0.5
    assert anny_model.bending_prior(bad_pose).item() > anny_model.bending_prior(zero).item()
    shape = anny_model.mean_shape()[None]
    assert anny_model.shape_prior(shape).item() == 0.0
    assert anny_model.shape_prior(shape + 0.7).item() > anny_model.shape_prior(shape + 0.3).item()


def _stature(model, shape):
    return float(np.ptp(_run(model, shape=shape).vertices[0, :, 1].numpy()))


def test_anny_prior_mean_is_its_shipped_population_at_the_reference_stature(anny_model):
    """The default prior mean (`fitting.body.anny_shape_mean`) is the mean of the population Anny ships
    (its WHO-calibrated sampler, ages 0-90) for every phenotype but height, which gives the stature of
    Anny's middle body (every phenotype 0.5, the former mean: a teenager's proportions)."""
    from anny.shape_distribution import SimpleShapeDistribution

    torch.manual_seed(0)
    _, samples = SimpleShapeDistribution(anny_model.anny).sample(20000)
    mean = anny_model.mean_shape()
    for k, name in enumerate(anny_model.shape_names):
        if name != "height":
            assert abs(float(mean[k]) - float(samples[name].mean())) < 0.02, name
    assert anny_model.shape_prior(mean[None]).item() == 0.0
    assert anny_model.shape_prior(anny_model.reference_shape()[None]).item() > 0.5
    assert abs(_stature(anny_model, mean) - _stature(anny_model, anny_model.reference_shape())) < 0.01


def test_anny_anatomy_does_not_follow_the_prior_mean(anny_model, config):
    """The pose priors' anatomical frames come from the reference body whatever the shape prior's mean."""
    import dataclasses

    from smplify3d_ros.body import load_body_model

    other = load_body_model("anny", dataclasses.replace(config.fitting.body, anny_shape_mean=[0.5] * 6))
    assert torch.allclose(other.mean_shape(), other.reference_shape())
    assert not torch.allclose(anny_model.mean_shape(), other.mean_shape())
    assert torch.equal(other.anat_frames, anny_model.anat_frames)
    assert torch.equal(other.anat_ranges, anny_model.anat_ranges)


# -- SMPL through a made-up file ------------------------------------------------------------------
V_SMALL = 300


def _made_up_smpl(rng, n_verts=V_SMALL):
    """Correct SMPL structure, made-up values: a column of vertices skinned to a 24-joint tree."""
    parents = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]
    joints = rng.normal(0, 0.3, (24, 3))
    v = rng.normal(0, 0.3, (n_verts, 3))
    J_reg = np.zeros((24, n_verts))
    for j in range(24):
        J_reg[j, rng.choice(n_verts, 5, replace=False)] = 0.2
    weights = rng.random((n_verts, 24))
    weights /= weights.sum(1, keepdims=True)
    faces = np.stack([np.arange(n_verts - 2), np.arange(1, n_verts - 1), np.arange(2, n_verts)], 1)
    del joints
    return {
        "v_template": v,
        "shapedirs": rng.normal(0, 0.01, (n_verts, 3, 10)),
        "posedirs": rng.normal(0, 0.001, (n_verts, 3, 207)),
        "J_regressor": J_reg,
        "weights": weights,
        "kintree_table": np.stack([np.array([2**32 - 1] + parents[1:]), np.arange(24)]).astype(np.int64),
        "f": faces.astype(np.int64),
    }


def _smpl_config(tmp_path, model_path, regressor_path="", gmm_path=""):
    from smplify3d_ros.fitting.config import BodyConfig

    return BodyConfig("smpl", str(model_path), str(regressor_path), str(gmm_path), smpl_num_betas=10,
                      anny_shape_sigma=0.25, anny_shape_mean=[0.5] * 6, anny_keypoint_support=64,
                      shape_bound_weight=100.0)


def test_smpl_npz_with_regressor_and_gmm(tmp_path, rng):
    arrays = _made_up_smpl(rng)
    np.savez(tmp_path / "smpl.npz", **arrays)
    reg = rng.random((17, V_SMALL))
    reg /= reg.sum(1, keepdims=True)
    np.save(tmp_path / "coco.npy", reg)
    gmm = {"means": rng.normal(0, 0.1, (8, 69)), "covars": np.stack([np.eye(69) * 0.1] * 8),
           "weights": np.full(8, 1 / 8)}
    with open(tmp_path / "gmm.pkl", "wb") as fh:
        pickle.dump(gmm, fh)
    model = SmplBody.from_config(_smpl_config(tmp_path, tmp_path / "smpl.npz", tmp_path / "coco.npy",
                                              tmp_path / "gmm.pkl"))
    out = _run(model)
    assert out.vertices.shape == (1, V_SMALL, 3) and out.keypoints.shape == (1, 17, 3)
    assert torch.isfinite(out.vertices).all()
    assert torch.allclose(out.keypoints[0], torch.as_tensor(reg, dtype=out.vertices.dtype) @ out.vertices[0],
                          atol=1e-4)
    dt = model.anat_frames.dtype
    zero = torch.zeros(1, 19, 3, dtype=dt)
    far = torch.full((1, 19, 3), 0.8, dtype=dt)
    assert model.pose_prior(far).item() > model.pose_prior(zero).item()  # GMM prior is used
    assert model.gmm is not None


def test_smpl_translation_and_rotation_centre(tmp_path, rng):
    np.savez(tmp_path / "smpl.npz", **_made_up_smpl(rng))
    np.save(tmp_path / "coco.npy", np.full((17, V_SMALL), 1.0 / V_SMALL))
    model = SmplBody.from_config(_smpl_config(tmp_path, tmp_path / "smpl.npz", tmp_path / "coco.npy"))
    a = _run(model, transl=(0.0, 0.0, 0.0)).vertices
    b = _run(model, transl=(1.0, 2.0, 3.0)).vertices
    assert torch.allclose(b - a, torch.tensor([1.0, 2.0, 3.0], dtype=a.dtype).expand_as(a), atol=1e-5)


def test_smpl_official_pickle_without_chumpy(tmp_path, rng, monkeypatch):
    """The official .pkl stores arrays as chumpy objects; we load it with chumpy absent."""
    arrays = _made_up_smpl(rng, n_verts=6890)
    fake = types.ModuleType("chumpy.ch")

    class Ch:  # what chumpy pickles: an object whose state holds the array in 'x'
        def __init__(self, x):
            self.x = x

        def __getstate__(self):
            return {"x": self.x, "_dirty_vars": set()}

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    fake.Ch = Ch
    monkeypatch.setitem(sys.modules, "chumpy", types.ModuleType("chumpy"))
    monkeypatch.setitem(sys.modules, "chumpy.ch", fake)
    data = dict(arrays)
    data["shapedirs"] = Ch(arrays["shapedirs"])
    data["v_template"] = Ch(arrays["v_template"])
    data["bs_style"] = "lbs"
    with open(tmp_path / "SMPL_NEUTRAL.pkl", "wb") as fh:
        pickle.dump(data, fh, protocol=2)
    monkeypatch.delitem(sys.modules, "chumpy")
    monkeypatch.delitem(sys.modules, "chumpy.ch")
    loaded = load_arrays(tmp_path / "SMPL_NEUTRAL.pkl")
    assert np.allclose(loaded["shapedirs"], arrays["shapedirs"])
    model = SmplBody.from_config(_smpl_config(tmp_path, tmp_path / "SMPL_NEUTRAL.pkl"))
    out = _run(model)  # documented fallback regressor: fixed face vertices + SMPL joints
    assert torch.allclose(out.keypoints[0, KP["nose"]], out.vertices[0, 332])
    pose = torch.full((1, 19, 3), 0.3)
    assert model.gmm is None and model.pose_prior(pose).item() == model.joint_range_prior(pose).item()


class _Python2Pickler(pickle._Pickler):
    """Writes bytes as Python 2's str (STRING / BINSTRING opcodes), as the official files hold them."""

    dispatch = dict(pickle._Pickler.dispatch)

    def save_bytes(self, obj: bytes) -> None:
        if self.proto == 0:
            self.write(b"S'" + codecs.escape_encode(obj)[0] + b"'\n")
        elif len(obj) < 256:
            self.write(b"U" + bytes([len(obj)]) + obj)
        else:
            self.write(b"T" + struct.pack("<i", len(obj)) + obj)
        self.memoize(obj)

    dispatch[bytes] = save_bytes


def _python2_era_pickle(data: dict, protocol: int) -> bytes:
    """What Python 2 with numpy 1 / scipy < 1.8 wrote: py2 str keys and array bytes, numpy.core and
    scipy.sparse.csc module paths, __builtin__ / copy_reg names."""
    buffer = __import__("io").BytesIO()
    _Python2Pickler(buffer, protocol).dump({k.encode(): v for k, v in data.items()})
    raw = buffer.getvalue()
    assert b"numpy._core." in raw and b"scipy.sparse._csc" in raw  # the paths we rewrite are there
    return raw.replace(b"numpy._core.", b"numpy.core.").replace(b"scipy.sparse._", b"scipy.sparse.")


@pytest.mark.parametrize("protocol", [0, 2])
def test_smpl_python2_era_pickle_with_sparse_regressor(tmp_path, rng, protocol):
    """The official file's layout: sparse J_regressor, chumpy-free arrays of several dtypes, strings and a
    dict the model does not need; it loads through the allowlist and, with SMPL's 6,890 vertices and
    protocol 2 (the official files'), builds the model. Protocol 0 (text: 1.5 s to write that size) is
    read from a smaller file: once loaded, the arrays are the same whatever the protocol."""
    arrays = _made_up_smpl(rng, n_verts=6890 if protocol == 2 else V_SMALL)
    data = dict(arrays, J_regressor=scipy.sparse.csc_matrix(arrays["J_regressor"]), bs_style="lbs",
                f=arrays["f"].astype(np.uint32), pose_training_info={"num_poses": 1786})
    path = tmp_path / f"basicModel_p{protocol}.pkl"
    path.write_bytes(_python2_era_pickle(data, protocol))
    skipped: list[str] = []
    loaded = load_arrays(path, skipped)
    assert sorted(skipped) == ["bs_style", "pose_training_info"]
    np.testing.assert_array_equal(loaded["J_regressor"], arrays["J_regressor"])
    np.testing.assert_array_equal(loaded["posedirs"], arrays["posedirs"])
    assert loaded["f"].dtype == np.uint32
    if protocol == 2:
        model = SmplBody.from_config(_smpl_config(tmp_path, path))
        assert torch.isfinite(_run(model).vertices).all()


def test_smpl_sparse_matrix_with_bad_indices_is_refused(tmp_path):
    """scipy's own toarray trusts the indices; the stand-in checks them before densifying."""
    matrix = scipy.sparse.csr_matrix(np.eye(3))
    matrix.indices = np.array([0, 1, 7], dtype=matrix.indices.dtype)  # column 7 of a 3-column matrix
    (tmp_path / "bad.pkl").write_bytes(pickle.dumps({"J_regressor": matrix}))
    with pytest.raises(SmplFileError, match="'J_regressor': sparse matrix: indices out of range"):
        load_arrays(tmp_path / "bad.pkl")


def test_smpl_bad_files_raise_clear_errors(tmp_path, rng):
    with pytest.raises(SmplFileError, match="not found"):
        load_arrays(tmp_path / "missing.pkl")
    arrays = _made_up_smpl(rng)
    del arrays["J_regressor"]
    np.savez(tmp_path / "broken.npz", **arrays)
    with pytest.raises(SmplFileError, match="J_regressor"):
        SmplBody.from_config(_smpl_config(tmp_path, tmp_path / "broken.npz"))
    np.savez(tmp_path / "small.npz", **_made_up_smpl(rng))
    with pytest.raises(SmplFileError, match="COCO regressor"):
        SmplBody.from_config(_smpl_config(tmp_path, tmp_path / "small.npz"))
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps({"f": __import__("os").getcwd}))
    with pytest.raises(SmplFileError, match="refusing"):
        load_arrays(tmp_path / "evil.pkl")


# -- smplify3d smpl-to-npz --------------------------------------------------------------------------------
def test_smpl_to_npz_round_trip(tmp_path, rng, capsys):
    """pkl -> npz keeps every numeric array bit for bit, the npz loads without pickle and gives the
    same model."""
    from smplify3d_ros.cli import main

    data = dict(_made_up_smpl(rng, n_verts=6890), bs_style="lbs")
    data["J_regressor"] = scipy.sparse.csc_matrix(data["J_regressor"])
    pkl = tmp_path / "SMPL_NEUTRAL.pkl"
    pkl.write_bytes(_python2_era_pickle(data, 2))
    assert main(["smpl-to-npz", str(pkl)]) == 0
    assert capsys.readouterr().out.strip() == f"wrote {tmp_path / 'SMPL_NEUTRAL.npz'}; left out (not numeric " \
                                              "arrays): bs_style"
    from_pkl = load_arrays(pkl)
    with np.load(tmp_path / "SMPL_NEUTRAL.npz", allow_pickle=False) as npz:
        assert sorted(npz.files) == sorted(from_pkl)
        for key, value in from_pkl.items():
            assert npz[key].dtype == value.dtype and np.array_equal(npz[key], value), key
    outputs = [_run(SmplBody.from_config(_smpl_config(tmp_path, tmp_path / name))).vertices
               for name in ("SMPL_NEUTRAL.pkl", "SMPL_NEUTRAL.npz")]
    assert torch.equal(*outputs)
    assert main(["smpl-to-npz", str(pkl), "-o", str(tmp_path / "other.npz")]) == 0  # -o names the output
    assert (tmp_path / "other.npz").is_file()


@pytest.mark.parametrize("args,message", [
    (["{tmp}/missing.pkl"], "file not found: {tmp}/missing.pkl"),
    (["{tmp}/model.npz"], "{tmp}/model.npz: expected a .pkl file"),
    (["{tmp}/model.pkl", "-o", "{tmp}/model.zip"], "{tmp}/model.zip: the output must be a .npz file"),
    (["{tmp}/model.pkl", "-o", "{tmp}/no/dir/out.npz"], "{tmp}/no/dir: no such directory"),
    (["{tmp}/model.pkl", "-o", "{tmp}/exists.npz"], "{tmp}/exists.npz exists (--force replaces it)"),
    (["{tmp}/broken.pkl"], "{tmp}/broken.pkl: cannot read"),
])
def test_smpl_to_npz_bad_paths(tmp_path, rng, capsys, args, message):
    """One line on stderr naming the file, exit code 2, no traceback, nothing written."""
    from smplify3d_ros.cli import main

    np.savez(tmp_path / "model.npz", **_made_up_smpl(rng))
    (tmp_path / "model.pkl").write_bytes(pickle.dumps(_made_up_smpl(rng)))
    (tmp_path / "exists.npz").write_bytes(b"keep me")
    (tmp_path / "broken.pkl").write_bytes(b"\x80\x04not a pickle")
    before = sorted(p.name for p in tmp_path.iterdir())
    assert main(["smpl-to-npz", *(a.format(tmp=tmp_path) for a in args)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("smplify3d smpl-to-npz: " + message.format(tmp=tmp_path))
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert (tmp_path / "exists.npz").read_bytes() == b"keep me"
