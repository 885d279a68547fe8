"""SMPL from a user-given model file (SMPL files are licensed: none ships with the project).

Loads an `.npz` (preferred: no pickle at all; `smplify3d smpl-to-npz` converts) or the official `.pkl`
with the same keys (v_template, shapedirs, posedirs, J_regressor, weights, kintree_table, f). A pickle can
name any function to run; ours hands out only an exact allowlist of array-building names (numpy arrays,
stand-ins for chumpy and scipy sparse matrices) and refuses everything else before it runs (docs/smpl.md).
Forward kinematics follow smplx's `lbs` (blend shapes, joint regression, rigid chain, skinning), written
as small pure functions. `transl` keeps SMPL's meaning (v = R (v − j0) + j0 + t), so the output of any
SMPL-compatible image HMR (CLIFF...) can be used as it is.

COCO-17 keypoints: from a user-given regressor (a (17, 6890) array in .npy/.npz) or, by default, the
documented fallback: face keypoints from fixed vertices (smplx's SMPL vertex ids: nose 332, eyes 6260 /
2800, ears 4071 / 583) and body keypoints from SMPL joints (shoulders, elbows, wrists, hips, knees,
ankles). SMPL's hip joints sit about 3 cm more medial and higher than COCO's annotated hips.

Pose prior: SMPLify's 8-component Gaussian mixture (`gmm_08.pkl`, keys means / covars / weights) from a
user-given file; without it, the anatomical joint-range prior shared with Anny.
"""

from __future__ import annotations

import copyreg
import importlib
import pickle
from pathlib import Path

import numpy as np
import roma
import torch

from smplify3d_ros.body.base import BodyModel, BodyOutput
from smplify3d_ros.body.joints import BODY_JOINTS
from smplify3d_ros.keypoints import KP, NUM_KEYPOINTS, PART_INDEX

# SMPL joint index of each of our body joints (feet 10, 11 and hands 22, 23 stay at rest).
SMPL_JOINT_INDEX = {
    "left_hip": 1, "right_hip": 2, "spine1": 3, "left_knee": 4, "right_knee": 5, "spine2": 6,
    "left_ankle": 7, "right_ankle": 8, "spine3": 9, "neck": 12, "left_collar": 13, "right_collar": 14,
    "head": 15, "left_shoulder": 16, "right_shoulder": 17, "left_elbow": 18, "right_elbow": 19,
    "left_wrist": 20, "right_wrist": 21,
}
NUM_SMPL_JOINTS = 24
# Fallback COCO regressor: vertex ids for face keypoints, SMPL joints for the others.
FALLBACK_FACE_VERTICES = {"nose": 332, "left_eye": 2800, "right_eye": 6260, "left_ear": 583, "right_ear": 4071}
FALLBACK_BODY_JOINTS = {
    "left_shoulder": 16, "right_shoulder": 17, "left_elbow": 18, "right_elbow": 19,
    "left_wrist": 20, "right_wrist": 21, "left_hip": 1, "right_hip": 2, "left_knee": 4,
    "right_knee": 5, "left_ankle": 7, "right_ankle": 8,
}
# SMPL joint -> body part (for the face -> part map through skinning weights).
SMPL_JOINT_PART = {
    0: "torso", 3: "torso", 6: "torso", 9: "torso", 13: "torso", 14: "torso",
    12: "head", 15: "head",
    1: "left_upper_leg", 4: "left_lower_leg", 7: "left_lower_leg", 10: "left_lower_leg",
    2: "right_upper_leg", 5: "right_lower_leg", 8: "right_lower_leg", 11: "right_lower_leg",
    16: "left_upper_arm", 18: "left_lower_arm", 20: "left_lower_arm", 22: "left_lower_arm",
    17: "right_upper_arm", 19: "right_lower_arm", 21: "right_lower_arm", 23: "right_lower_arm",
}
REQUIRED_KEYS = ("v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f")


class SmplFileError(ValueError):
    """The SMPL model (or regressor, or prior) file is missing, unreadable or malformed."""


def _one_line(text: object, n: int = 100) -> str:
    """Text from a file or an exception, shortened to one line for an error message."""
    text = " ".join(str(text).split())
    return text if len(text) <= n else text[:n] + "..."


# -- chumpy-free, code-free loading -------------------------------------------------------------------
# A pickle names the callables it wants run; the unpickler below hands out only these. The official SMPL
# / SMPLify files (written by Python 2) and pickles written by Python 3 (protocols 0 to 5) need nothing
# else: numpy arrays, dtypes and scalars, scipy sparse matrices (old and new module paths), chumpy arrays,
# sets (chumpy's state), copy_reg's reconstructor (protocols 0/1) and _codecs.encode (bytes, protocol <3).
_NUMPY_NAMES = {
    ("numpy", "ndarray"), ("numpy", "dtype"),
    ("numpy.core.multiarray", "_reconstruct"), ("numpy._core.multiarray", "_reconstruct"),
    ("numpy.core.multiarray", "scalar"), ("numpy._core.multiarray", "scalar"),
    ("numpy.core.numeric", "_frombuffer"), ("numpy._core.numeric", "_frombuffer"),  # protocol 5
}
_SPARSE_FORMATS = {"csc_matrix": "csc", "csr_matrix": "csr", "coo_matrix": "coo"}
_SPARSE_NAMES = {
    (f"scipy.sparse{sep}{fmt}", cls): fmt
    for cls, fmt in _SPARSE_FORMATS.items() for sep in (".", "._")
}
_BUILTIN_NAMES = {"object", "set"}  # object: copy_reg._reconstructor's base; set: chumpy's _dirty_vars
_MAX_SPARSE_CELLS = 10**8  # a dense (24, 6890) J_regressor has 1.7e5; refuse absurd shapes before allocating


class _ChumpyStandIn:
    """Replaces chumpy.Ch while unpickling: keeps the wrapped array (`x`) and nothing else."""

    def __init__(self, *args, **kwargs) -> None:
        self.state = {}

    def __setstate__(self, state) -> None:
        self.state = state if isinstance(state, dict) else {"x": state}

    def __array__(self, dtype=None, copy=None):
        return np.asarray(getattr(self, "state", {}).get("x"), dtype=dtype)


class _SparseStandIn:
    """Replaces a scipy sparse matrix while unpickling: keeps its arrays, densified by `toarray` with
    numpy after checking them (scipy's own toarray trusts the indices: a bad file could write out of
    bounds)."""

    format = ""

    def __init__(self, *args, **kwargs) -> None:
        self.state = {}

    def __setstate__(self, state) -> None:
        self.state = state  # checked by toarray, where errors can name the key

    def toarray(self) -> np.ndarray:
        state = getattr(self, "state", {})
        if not isinstance(state, dict):
            raise SmplFileError(f"a {self.format} sparse matrix holds {type(state).__name__}, expected a dict")
        shape = _sparse_shape(state.get("_shape", state.get("shape")))
        data = _numeric(state.get("data"), "sparse data")
        if self.format == "coo":
            coords = state.get("coords", (state.get("row"), state.get("col")))
            rows, cols = (_indices(c, n, len(data)) for c, n in zip(coords, shape, strict=True))
        else:
            major, minor = shape if self.format == "csr" else shape[::-1]
            indptr = _numeric(state.get("indptr"), "sparse indptr").astype(np.int64)
            if indptr.shape != (major + 1,) or indptr[0] != 0 or indptr[-1] != len(data) or (np.diff(indptr) < 0).any():
                raise SmplFileError(f"{self.format} sparse matrix: inconsistent indptr")
            outer = np.repeat(np.arange(major), np.diff(indptr))
            inner = _indices(state.get("indices"), minor, len(data))
            rows, cols = (outer, inner) if self.format == "csr" else (inner, outer)
        dense = np.zeros(shape, dtype=data.dtype)
        np.add.at(dense, (rows, cols), data)  # duplicates add up, as in scipy
        return dense


def _sparse_shape(value) -> tuple[int, int]:
    shape = tuple(int(n) for n in np.asarray(value, dtype=np.int64).reshape(-1)) if value is not None else ()
    if len(shape) != 2 or min(shape) < 0 or shape[0] * shape[1] > _MAX_SPARSE_CELLS:
        raise SmplFileError(f"sparse matrix with unusable shape {_one_line(value, 50)}")
    return shape


def _numeric(value, what: str) -> np.ndarray:
    array = np.asarray(value)
    if array.dtype.kind not in "biuf" or array.ndim != 1:
        raise SmplFileError(f"{what} must be a 1-D numeric array, got {array.dtype} {array.shape}")
    return array


def _indices(value, size: int, count: int) -> np.ndarray:
    index = _numeric(value, "sparse indices").astype(np.int64)
    if len(index) != count or (count and (index.min() < 0 or index.max() >= size)):
        raise SmplFileError("sparse matrix: indices out of range or not one per value")
    return index


def _sparse_class(fmt: str) -> type:
    return type(f"_{fmt.capitalize()}StandIn", (_SparseStandIn,), {"format": fmt})


_SPARSE_CLASSES = {fmt: _sparse_class(fmt) for fmt in set(_SPARSE_FORMATS.values())}


class _Sealed:
    """A callable the pickle may call but not modify: BUILD on a plain function would set its
    attributes (__defaults__...) for the rest of the process."""

    __slots__ = ("_func",)

    def __init__(self, func) -> None:
        self._func = func

    def __call__(self, *args):
        return self._func(*args)

    def __setstate__(self, state) -> None:
        raise SmplFileError("an SMPL file tried to modify a loader function")


def _latin1_encode(text, encoding="latin1"):
    """What Python 3 writes for bytes at protocol < 3: `_codecs.encode(text, 'latin1')`; other codecs
    are refused (a codec is looked up, and so imported, by name)."""
    if not isinstance(text, str) or encoding not in ("latin1", "latin-1"):
        raise SmplFileError(f"refusing _codecs.encode with codec {_one_line(repr(encoding), 40)}")
    return text.encode("latin1")


def _resolve(module: str, name: str):
    """The object a pickle asks for, if the allowlist has it; None otherwise."""
    if module == "chumpy" or module.startswith("chumpy."):
        return _ChumpyStandIn  # every chumpy class: our stand-in, which runs nothing
    if (module, name) in _SPARSE_NAMES:
        return _SPARSE_CLASSES[_SPARSE_NAMES[(module, name)]]
    if module in ("__builtin__", "builtins") and name in _BUILTIN_NAMES:
        return {"object": object, "set": set}[name]
    if module in ("copy_reg", "copyreg") and name == "_reconstructor":
        return _Sealed(copyreg._reconstructor)
    if (module, name) == ("_codecs", "encode"):
        return _Sealed(_latin1_encode)
    if (module, name) in _NUMPY_NAMES:
        found = getattr(_numpy_module(module), name)
        return found if isinstance(found, type) else _Sealed(found)
    return None


def _numpy_module(module: str):
    """numpy 2 moved numpy.core to numpy._core (the old name warns); files use either spelling."""
    if module == "numpy":
        return np
    new_name = module.replace("numpy.core.", "numpy._core.", 1)
    try:
        return importlib.import_module(new_name)
    except ImportError:  # numpy 1.x
        return importlib.import_module(new_name.replace("numpy._core.", "numpy.core.", 1))


class _SmplUnpickler(pickle.Unpickler):
    def __init__(self, handle, path: Path) -> None:
        super().__init__(handle, encoding="latin1")
        self.path = path

    def find_class(self, module: str, name: str):
        found = _resolve(module, name)
        if found is None:
            raise SmplFileError(f"refusing to load {_one_line(f'{module}.{name}')} from {self.path}: "
                                "SMPL files hold only arrays")
        return found


def load_arrays(path: str | Path, skipped: list[str] | None = None) -> dict[str, np.ndarray]:
    """Read a .pkl (official, chumpy or not), .npz or .npy file into a dict of dense numeric arrays.

    A .pkl may hold only what SMPL files hold (see `_resolve`); anything else, e.g. a function to call,
    is refused with SmplFileError before it runs. Entries that are not numeric arrays (SMPL's
    `bs_style` string, `pose_training_info` dict...) are left out; their keys are appended to `skipped`.
    """
    path = Path(path)
    if not path.is_file():
        raise SmplFileError(f"file not found: {path}")
    raw = _read_raw(path)
    if not isinstance(raw, dict):
        raise SmplFileError(f"{path}: expected a mapping of arrays, got {type(raw).__name__}")
    arrays = {}
    for key, value in raw.items():
        if not isinstance(key, str):
            raise SmplFileError(f"{path}: keys must be strings, got {type(key).__name__}")
        try:
            array = _to_dense(value)
        except SmplFileError as exc:
            raise SmplFileError(f"{path}: {_one_line(repr(key))}: {exc}") from exc
        except Exception as exc:  # noqa: BLE001 - a malformed entry is a file problem
            raise SmplFileError(f"{path}: {_one_line(repr(key))}: cannot read ({_one_line(exc, 200)})") from exc
        if array is None:
            if skipped is not None:
                skipped.append(key)
        else:
            arrays[key] = array
    return arrays


def _read_raw(path: Path):
    try:
        if path.suffix == ".npz":
            with np.load(path, allow_pickle=False) as data:
                return {k: data[k] for k in data.files}
        if path.suffix in (".pkl", ".pickle"):
            with open(path, "rb") as handle:
                return _SmplUnpickler(handle, path).load()
        if path.suffix == ".npy":
            return {"array": np.load(path, allow_pickle=False)}
    except SmplFileError as exc:
        if str(path) in str(exc):
            raise
        raise SmplFileError(f"{path}: {exc}") from exc  # raised by a stand-in, which does not know the file
    except Exception as exc:  # noqa: BLE001 - any parse failure is reported as a file problem
        raise SmplFileError(f"{path}: cannot read ({_one_line(exc, 200)})") from exc
    raise SmplFileError(f"{path}: expected a .pkl, .npz or .npy file")


def _to_dense(value) -> np.ndarray | None:
    """A numeric ndarray, or None for anything else (strings, dicts, object arrays)."""
    if isinstance(value, _SparseStandIn):
        value = value.toarray()
    elif isinstance(value, _ChumpyStandIn):
        value = np.asarray(value)
    if not isinstance(value, (np.ndarray, np.generic, int, float)) or isinstance(value, bool):
        return None
    array = np.asarray(value)
    return array if array.dtype.kind in "biuf" else None


# -- pure functions of linear blend skinning (smplx's lbs, restated) ------------------------------
def blend_shapes(coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """(B, K) coefficients, (V, 3, K) directions -> (B, V, 3) offsets."""
    return torch.einsum("bk,vdk->bvd", coeffs, dirs)


def vertices_to_joints(regressor: torch.Tensor, vertices: torch.Tensor) -> torch.Tensor:
    """(J, V) regressor, (B, V, 3) vertices -> (B, J, 3)."""
    return torch.einsum("jv,bvd->bjd", regressor, vertices)


def rigid_chain(rotmats: torch.Tensor, joints: torch.Tensor, parents: list[int]):
    """Posed joint positions and skinning transforms, (B, J, 3) and (B, J, 4, 4)."""
    B, J = joints.shape[:2]
    rel = joints.clone()
    rel[:, 1:] -= joints[:, parents[1:]]
    local = torch.zeros(B, J, 4, 4, dtype=joints.dtype, device=joints.device)
    local[..., :3, :3] = rotmats
    local[..., :3, 3] = rel
    local[..., 3, 3] = 1.0
    chain = [local[:, 0]]
    for j in range(1, J):
        chain.append(chain[parents[j]] @ local[:, j])
    world = torch.stack(chain, dim=1)
    posed_joints = world[..., :3, 3]
    # skinning transform: world @ [I | -rest joint]
    skin = world.clone()
    skin[..., :3, 3] = world[..., :3, 3] - (world[..., :3, :3] @ joints[..., None])[..., 0]
    return posed_joints, skin


def skin_vertices(vertices: torch.Tensor, weights: torch.Tensor, transforms: torch.Tensor) -> torch.Tensor:
    """(B, V, 3) rest vertices, (V, J) weights, (B, J, 4, 4) -> (B, V, 3)."""
    T = torch.einsum("vj,bjxy->bvxy", weights, transforms)
    return (T[..., :3, :3] @ vertices[..., None])[..., 0] + T[..., :3, 3]


class GaussianMixturePrior(torch.nn.Module):
    """SMPLify's pose prior: −log of the best weighted Gaussian component (the 'max' mixture)."""

    def __init__(self, means: np.ndarray, covars: np.ndarray, weights: np.ndarray) -> None:
        super().__init__()
        dtype = torch.get_default_dtype()
        precisions = np.linalg.inv(covars)
        dim = means.shape[1]
        log_norm = -0.5 * (dim * np.log(2 * np.pi) + np.linalg.slogdet(covars)[1])
        self.register_buffer("means", torch.as_tensor(means, dtype=dtype))
        self.register_buffer("precisions", torch.as_tensor(precisions, dtype=dtype))
        self.register_buffer("log_weights", torch.as_tensor(np.log(weights) + log_norm, dtype=dtype))

    @classmethod
    def from_file(cls, path: str | Path) -> GaussianMixturePrior:
        data = load_arrays(path)
        missing = {"means", "covars", "weights"} - set(data)
        if missing:
            raise SmplFileError(f"{path}: GMM prior lacks {sorted(missing)}")
        return cls(data["means"], data["covars"], data["weights"])

    def forward(self, body_pose_69: torch.Tensor) -> torch.Tensor:
        diff = body_pose_69[:, None, :] - self.means  # (B, K, D)
        mahal = torch.einsum("bkd,kde,bke->bk", diff, self.precisions, diff)
        return -(self.log_weights - 0.5 * mahal).max(dim=1).values


class SmplBody(BodyModel):
    name = "smpl"

    def __init__(self, arrays: dict[str, np.ndarray], num_betas: int, coco_regressor: np.ndarray | None,
                 gmm: GaussianMixturePrior | None, source: str = "") -> None:
        super().__init__()
        missing = [k for k in REQUIRED_KEYS if k not in arrays]
        if missing:
            raise SmplFileError(f"{source}: SMPL file lacks {missing}")
        dtype = torch.get_default_dtype()
        v_template = np.asarray(arrays["v_template"], float)
        V = v_template.shape[0]
        shapedirs = np.asarray(arrays["shapedirs"], float)
        if shapedirs.ndim != 3 or shapedirs.shape[:2] != (V, 3):
            raise SmplFileError(f"{source}: shapedirs has shape {shapedirs.shape}, expected ({V}, 3, K)")
        num_betas = min(num_betas, shapedirs.shape[2])
        posedirs = np.asarray(arrays["posedirs"], float).reshape(V * 3, -1).T  # (207, V*3)
        J_regressor = np.asarray(arrays["J_regressor"], float)
        kintree = np.asarray(arrays["kintree_table"]).astype(np.int64)
        if J_regressor.shape != (NUM_SMPL_JOINTS, V) or kintree.shape != (2, NUM_SMPL_JOINTS):
            raise SmplFileError(f"{source}: expected a 24-joint SMPL model, got J_regressor {J_regressor.shape}")
        if posedirs.shape[0] != (NUM_SMPL_JOINTS - 1) * 9:
            raise SmplFileError(f"{source}: posedirs has {posedirs.shape[0]} pose features, expected 207")
        self.shape_names = tuple(f"beta{i}" for i in range(num_betas))
        self.register_buffer("v_template", torch.as_tensor(v_template, dtype=dtype))
        self.register_buffer("shapedirs", torch.as_tensor(shapedirs[:, :, :num_betas], dtype=dtype))
        self.register_buffer("posedirs", torch.as_tensor(posedirs, dtype=dtype))
        self.register_buffer("J_regressor", torch.as_tensor(J_regressor, dtype=dtype))
        self.register_buffer("lbs_weights", torch.as_tensor(arrays["weights"], dtype=dtype))
        self.parents = [-1] + [int(p) for p in kintree[0, 1:]]
        self.faces = torch.as_tensor(np.asarray(arrays["f"]).astype(np.int64))
        self.body_index = [SMPL_JOINT_INDEX[j] for j in BODY_JOINTS]
        self.coco_from_regressor = coco_regressor is not None
        if coco_regressor is None and V <= max(FALLBACK_FACE_VERTICES.values()):
            raise SmplFileError(f"{source}: {V} vertices is not SMPL's topology; give a COCO regressor file")
        if coco_regressor is not None:
            if coco_regressor.shape != (NUM_KEYPOINTS, V):
                raise SmplFileError(f"COCO regressor has shape {coco_regressor.shape}, expected (17, {V})")
            self.register_buffer("coco_regressor", torch.as_tensor(coco_regressor, dtype=dtype))
        self.gmm = gmm
        dominant = self.lbs_weights.argmax(dim=1)
        vertex_part = torch.as_tensor([PART_INDEX[SMPL_JOINT_PART[j]] for j in range(NUM_SMPL_JOINTS)])[dominant]
        self.part_of_face = vertex_part[self.faces].mode(dim=1).values
        rest_joints = vertices_to_joints(self.J_regressor, self.v_template[None])[0]
        self._init_anatomy(rest_joints[self.body_index].double().cpu().numpy())

    @classmethod
    def from_config(cls, config) -> SmplBody:
        if not config.smpl_model_path:
            raise SmplFileError("body model 'smpl' needs fitting.body.smpl_model_path (your own SMPL file)")
        arrays = load_arrays(config.smpl_model_path)
        regressor = None
        if config.smpl_coco_regressor_path:
            data = load_arrays(config.smpl_coco_regressor_path)
            regressor = next(iter(data.values())) if len(data) == 1 else data.get("coco")
            if regressor is None:
                raise SmplFileError(f"{config.smpl_coco_regressor_path}: expected one array or key 'coco'")
        gmm = GaussianMixturePrior.from_file(config.smpl_gmm_path) if config.smpl_gmm_path else None
        return cls(arrays, config.smpl_num_betas, regressor, gmm, source=str(config.smpl_model_path))

    def mean_shape(self) -> torch.Tensor:
        return torch.zeros(len(self.shape_names), dtype=self.v_template.dtype, device=self.v_template.device)

    def shape_prior(self, shape: torch.Tensor) -> torch.Tensor:
        """βᵀ Σ⁻¹ β with SMPL's whitened betas (Σ = I)."""
        return (shape**2).sum(-1)

    def rotation_center(self, shape: torch.Tensor, transl: torch.Tensor) -> torch.Tensor:
        shaped = self.v_template + blend_shapes(shape, self.shapedirs)
        return self.J_regressor[0] @ shaped + transl

    def full_pose(self, pose: torch.Tensor, root_orient: torch.Tensor) -> torch.Tensor:
        """(B, 24, 3) SMPL pose with feet and hands at rest."""
        B = pose.shape[0]
        full = torch.zeros(B, NUM_SMPL_JOINTS, 3, dtype=pose.dtype, device=pose.device)
        full[:, 0] = root_orient
        full[:, self.body_index] = pose
        return full

    def pose_prior(self, pose: torch.Tensor) -> torch.Tensor:
        if self.gmm is None:
            return self.joint_range_prior(pose)
        full = self.full_pose(pose, torch.zeros_like(pose[:, 0]))
        return self.gmm(full[:, 1:].reshape(pose.shape[0], -1))

    def forward(
        self,
        shape: torch.Tensor,
        pose: torch.Tensor,
        root_orient: torch.Tensor,
        transl: torch.Tensor,
        vertex_index: torch.Tensor | None = None,
    ) -> BodyOutput:
        B = max(shape.shape[0], pose.shape[0])
        shaped = self.v_template + blend_shapes(shape.expand(B, -1), self.shapedirs)
        rest_joints = vertices_to_joints(self.J_regressor, shaped)
        rotmats = roma.rotvec_to_rotmat(self.full_pose(pose.expand(B, -1, -1), root_orient.expand(B, -1)))
        eye = torch.eye(3, dtype=rotmats.dtype, device=rotmats.device)
        pose_feature = (rotmats[:, 1:] - eye).reshape(B, -1)
        posed_rest = shaped + (pose_feature @ self.posedirs).reshape(B, -1, 3)
        joints, skin = rigid_chain(rotmats, rest_joints, self.parents)
        verts = skin_vertices(posed_rest, self.lbs_weights, skin) + transl[:, None]
        joints = joints + transl[:, None]
        if self.coco_from_regressor:
            keypoints = vertices_to_joints(self.coco_regressor, verts)
        else:
            keypoints = torch.zeros(B, NUM_KEYPOINTS, 3, dtype=verts.dtype, device=verts.device)
            for name, vid in FALLBACK_FACE_VERTICES.items():
                keypoints[:, KP[name]] = verts[:, vid]
            for name, jid in FALLBACK_BODY_JOINTS.items():
                keypoints[:, KP[name]] = joints[:, jid]
        if vertex_index is not None:
            verts = verts[:, vertex_index]
        return BodyOutput(verts, joints[:, self.body_index], keypoints)
