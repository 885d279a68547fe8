"""The `~/bodies` JSON document (std_msgs/String): writer and validating parser.

The schema is described in BODIES_SCHEMA.md next to this file. The parser also reads the node's optional
`init_bodies` input and replay's bag documents, so it accepts documents written by hand or by other tools,
and must survive hostile ones: its cost is bounded (size and nesting are checked before `json.loads`),
everything it needs is validated against plausible ranges, and every error is one BodiesError naming the
body and key at fault, quoting at most ~100 characters of the document (`clip`).
"""

from __future__ import annotations

import json
import math
import re
import reprlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from msg_adapters.factory import split_stamp, stamp_to_ns
from smplify3d_ros.keypoints import COCO17_NAMES
from smplify3d_ros.types import BodyFit, BodyParams

SCHEMA = "smplify3d_ros/bodies"
VERSION = 1
_DECIMALS = 6  # micrometres / microradians: far below fit accuracy, keeps documents short

# Parser limits (BODIES_SCHEMA.md). Ground-truth documents with every vertex of several bodies stay < 1 MiB.
MAX_DOCUMENT_BYTES = 8 * 1024 * 1024  # larger documents are refused unread
MAX_DEPTH = 32  # nesting of arrays / objects; the schema needs 4 (ground truth vertices), json recurses per level
MAX_FRAME_ID_CHARS = 256
MAX_MODEL_CHARS = 64
MAX_ABS_TRANSL_M = 1000.0  # far beyond any sensor's range
MAX_ROTATION_RAD = 4 * math.pi  # axis-angle norm: any rotation needs <= pi; an optimizer may wander past it
MAX_ABS_SHAPE = 10.0  # Anny phenotypes lie in [0, 1], SMPL betas (unit variance) within about +-5
CLIP_CHARS = 100  # user text quoted in an error message
_INT32 = (-(2**31), 2**31 - 1)
_NS_PER_S = 1_000_000_000


class BodiesError(ValueError):
    """A bodies document that does not follow the schema; the message names the body and key at fault."""


def _num(x: float) -> float | None:
    """A JSON number (None for NaN / inf, which JSON cannot hold)."""
    x = float(x)
    return round(x, _DECIMALS) if math.isfinite(x) else None


def _vec(a: Any) -> list[float | None]:
    return [_num(x) for x in np.asarray(a, dtype=np.float64).reshape(-1)]


def body_to_dict(person_id: int, params: BodyParams, joint_names: Sequence[str],
                 keypoints3d: np.ndarray) -> dict[str, Any]:
    """The body parameters and 3D keypoints of one body of a document (also ground-truth documents)."""
    pose = np.asarray(params.pose, dtype=np.float64).reshape(-1, 3)
    if len(joint_names) != len(pose):
        raise ValueError(f"person {person_id}: {len(joint_names)} joint names for {len(pose)} pose rows")
    kp3d = np.asarray(keypoints3d, dtype=np.float64).reshape(-1, 3)
    return {
        "id": int(person_id),
        "model": str(params.model),
        "shape": _vec(params.shape),
        "root_orient": _vec(params.root_orient),
        "transl": _vec(params.transl),
        "pose": {str(name): _vec(row) for name, row in zip(joint_names, pose, strict=True)},
        "joints3d": {name: _vec(p) for name, p in zip(COCO17_NAMES, kp3d, strict=True)},
    }


def fit_to_dict(fit: BodyFit) -> dict[str, Any]:
    """One body of the document."""
    q = fit.quality
    return {
        **body_to_dict(fit.person_id, fit.params, fit.joint_names, fit.keypoints3d),
        "quality": {
            "reprojection_px": _num(q.reprojection_px),
            "chamfer_m": _num(q.chamfer_m),
            "num_points": int(q.num_points),
            "visible_parts": [str(p) for p in q.visible_parts],
            "icp_converged": bool(q.icp_converged),
            "final_loss": _num(q.final_loss),
        },
        "velocity": None if fit.velocity is None else _vec(fit.velocity),
        "flags": sorted(str(f) for f in fit.flags),
    }


def fits_to_bodies_json(fits: Sequence[BodyFit], stamp: Any, frame_id: str) -> str:
    """The `~/bodies` document for one frame. `stamp`: a stamp message or int nanoseconds (both kept
    exact, e.g. the stamp `bodies_json_to_params` returns), or float seconds."""
    sec, nanosec = _split_stamp_or_ns(stamp)
    doc = {
        "schema": SCHEMA,
        "version": VERSION,
        "stamp": {"sec": sec, "nanosec": nanosec},
        "frame_id": str(frame_id),
        "bodies": [fit_to_dict(f) for f in fits],
    }
    return json.dumps(doc, allow_nan=False, separators=(",", ":"))


def _split_stamp_or_ns(stamp: Any) -> tuple[int, int]:
    if isinstance(stamp, (int, np.integer)) and not isinstance(stamp, (bool, np.bool_)):
        sec, nanosec = divmod(int(stamp), _NS_PER_S)
        if not _INT32[0] <= sec <= _INT32[1]:
            raise ValueError(f"stamp {sec} s does not fit builtin_interfaces/Time (int32 seconds)")
        return sec, nanosec
    return split_stamp(stamp)


# ------------------------------------------------------------------------------------------------ parse
_ONE_LINE = str.maketrans({"\n": "\\n", "\r": "\\r"})
_REPR = reprlib.Repr()  # bounded repr: a 10 MB list or string costs nothing to describe
_REPR.maxstring, _REPR.maxother, _REPR.maxlong, _REPR.maxlist, _REPR.maxdict = 60, 40, 30, 6, 4
_STRING_LITERAL = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


def clip(text: object, n: int = CLIP_CHARS) -> str:
    """`text` cut to `n` characters (saying how long it was) on one line: user text quoted in a log line."""
    text = str(text)
    if len(text) > n:
        text = f"{text[:n]}... ({len(text)} characters)"
    return text.translate(_ONE_LINE)


def _show(value: Any) -> str:
    return clip(_REPR.repr(value))


def load_document(text: str | bytes) -> Any:
    """json.loads with its cost bounded: size and nesting are checked first (json recurses per level)."""
    if isinstance(text, (bytes, bytearray, memoryview)):
        data = bytes(text)
        _check_size(len(data))
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError as e:
            raise BodiesError(f"bodies document is not valid UTF-8: {clip(e)}") from e
    elif isinstance(text, str):
        _check_size(len(text))  # characters <= UTF-8 bytes: refuses the hopeless ones before encoding
        data = text.encode("utf-8", "surrogatepass")
        _check_size(len(data))
    else:
        raise BodiesError(f"bodies document must be str or bytes, got {type(text).__name__}")
    depth = _nesting_depth(data)
    if depth > MAX_DEPTH:
        raise BodiesError(f"bodies document nests {depth} levels deep, more than {MAX_DEPTH}")
    try:
        return json.loads(text)
    except (ValueError, RecursionError, MemoryError) as e:  # ValueError: JSONDecodeError, huge integers
        raise BodiesError(f"bodies document is not valid JSON: {clip(e)}") from e


def _check_size(size: int) -> None:
    if size > MAX_DOCUMENT_BYTES:
        raise BodiesError(f"bodies document has {size} bytes, more than {MAX_DOCUMENT_BYTES}")


def _nesting_depth(data: bytes) -> int:
    """Deepest bracket nesting outside string literals (an upper bound for invalid JSON)."""
    codes = np.frombuffer(_STRING_LITERAL.sub(b'""', data), np.uint8)
    if not len(codes):
        return 0
    opens = (codes == ord("[")) | (codes == ord("{"))
    step = opens.astype(np.int32) - ((codes == ord("]")) | (codes == ord("}")))
    return int(np.cumsum(step, dtype=np.int32).max())


def _is_number(x: Any) -> bool:
    """An int or a finite float (json gives ints of any size: math.isfinite would overflow on them)."""
    if isinstance(x, bool):
        return False
    return isinstance(x, int) or (isinstance(x, float) and math.isfinite(x))


def _numbers(value: Any, where: str, size: int | None, bound: float, unit: str) -> np.ndarray:
    """A list of finite numbers, each within +-bound (checked before conversion: ints can be huge)."""
    if not isinstance(value, list) or not all(_is_number(x) for x in value):
        raise BodiesError(f"{where} must be a list of finite numbers, got {_show(value)}")
    if size is not None and len(value) != size:
        raise BodiesError(f"{where} must have {size} numbers, got {len(value)}")
    worst = max(value, key=abs, default=0)
    if abs(worst) > bound:
        raise BodiesError(f"{where} values must be within +-{bound:g}{unit}, got {_show(worst)}")
    return np.asarray(value, dtype=np.float64)


def _rotation(value: Any, where: str) -> np.ndarray:
    vec = _numbers(value, where, 3, MAX_ROTATION_RAD, " rad")
    norm = float(np.linalg.norm(vec))
    if norm > MAX_ROTATION_RAD:
        raise BodiesError(f"{where} has an axis-angle norm of {norm:.3g} rad, more than 4 pi")
    return vec


def _stamp_ns(value: Any) -> int:
    """{sec, nanosec} (exact) or seconds (float: whole and fraction apart, as the writer's stamp_to_ns)."""
    if _is_number(value) and _INT32[0] <= value < _INT32[1] + 1:
        return stamp_to_ns(float(value))  # a JSON number is seconds (stamp_to_ns reads ints as ns)
    if isinstance(value, dict) and set(value) == {"sec", "nanosec"} and all(
        isinstance(value[k], int) and not isinstance(value[k], bool) for k in value
    ) and 0 <= value["nanosec"] < _NS_PER_S and _INT32[0] <= value["sec"] <= _INT32[1]:
        return value["sec"] * _NS_PER_S + value["nanosec"]
    raise BodiesError("'stamp' must be {'sec': int32, 'nanosec': int in [0, 1e9)} or int32-range seconds, "
                      f"got {_show(value)}")


def _body_id(entry: dict, i: int) -> int:
    pid = entry.get("id")
    if not isinstance(pid, int) or isinstance(pid, bool):
        raise BodiesError(f"bodies[{i}]: 'id' must be an integer, got {_show(pid)}")
    if not _INT32[0] <= pid <= _INT32[1]:
        raise BodiesError(f"bodies[{i}]: 'id' {_show(pid)} is outside the int32 range")
    return pid


def _pose(pose_in: Any, where: str, joint_names: Sequence[str]) -> np.ndarray:
    if not isinstance(pose_in, dict):
        raise BodiesError(
            f"{where}: 'pose' must map joint names to [ax, ay, az], got {type(pose_in).__name__}"
        )
    index = {name: j for j, name in enumerate(joint_names)}
    unknown = sorted(set(pose_in) - set(index))
    if unknown:
        more = f" and {len(unknown) - 3} more" if len(unknown) > 3 else ""
        raise BodiesError(f"{where}: unknown joint(s) in 'pose': {', '.join(clip(n, 30) for n in unknown[:3])}"
                          f"{more}; known: {', '.join(joint_names)}")
    pose = np.zeros((len(joint_names), 3))
    for name, value in pose_in.items():
        pose[index[name]] = _rotation(value, f"{where}: pose[{name!r}]")
    return pose


def _body(entry: Any, i: int, joint_names: Sequence[str], shape_size: int | None) -> tuple[int, BodyParams]:
    if not isinstance(entry, dict):
        raise BodiesError(f"bodies[{i}] must be an object, got {type(entry).__name__}")
    pid = _body_id(entry, i)
    where = f"bodies[{i}] (id {pid})"
    for key in ("model", "shape", "pose", "root_orient", "transl"):
        if key not in entry:
            raise BodiesError(f"{where}: missing {key!r}")
    model = entry["model"]
    if not isinstance(model, str) or not model or len(model) > MAX_MODEL_CHARS:
        raise BodiesError(f"{where}: 'model' must be a non-empty string of at most {MAX_MODEL_CHARS} "
                          f"characters, got {_show(model)}")
    shape = _numbers(entry["shape"], f"{where}: 'shape'", None, MAX_ABS_SHAPE, "")
    if shape_size is not None and len(shape) != shape_size:
        raise BodiesError(f"{where}: 'shape' has {len(shape)} values, the body model has {shape_size}")
    root_orient = _rotation(entry["root_orient"], f"{where}: 'root_orient'")
    transl = _numbers(entry["transl"], f"{where}: 'transl'", 3, MAX_ABS_TRANSL_M, " m")
    pose = _pose(entry["pose"], where, joint_names)
    return pid, BodyParams(model=model, shape=shape, pose=pose, root_orient=root_orient, transl=transl)


def _header(doc: Any) -> tuple[int, str]:
    """Schema, version, stamp (ns) and frame id of a parsed document."""
    if not isinstance(doc, dict):
        raise BodiesError(f"bodies document must be a JSON object, got {type(doc).__name__}")
    if doc.get("schema") != SCHEMA:
        raise BodiesError(f"bodies document: 'schema' must be {SCHEMA!r}, got {_show(doc.get('schema'))}")
    version = doc.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= VERSION:
        raise BodiesError(
            f"bodies document: unsupported 'version' {_show(version)} (this reader knows 1 to {VERSION})"
        )
    if "stamp" not in doc:
        raise BodiesError("bodies document: missing 'stamp'")
    stamp_ns = _stamp_ns(doc["stamp"])
    frame_id = doc.get("frame_id")
    if not isinstance(frame_id, str):
        raise BodiesError(f"bodies document: 'frame_id' must be a string, got {_show(frame_id)}")
    if len(frame_id) > MAX_FRAME_ID_CHARS:
        raise BodiesError(f"bodies document: 'frame_id' has {len(frame_id)} characters, more than "
                          f"{MAX_FRAME_ID_CHARS}: {_show(frame_id)}")
    return stamp_ns, frame_id


def bodies_json_to_params(
    text: str | bytes, joint_names: Sequence[str], *, shape_size: int | None = None
) -> tuple[int, str, dict[int, BodyParams]]:
    """Parse a `~/bodies` document -> (stamp ns, frame_id, {person id: BodyParams}).

    `text`: str, or UTF-8 bytes. `joint_names` orders the pose rows (the body model's `joint_names`);
    joints the document leaves out get a zero rotation, joints it names that are not in `joint_names` are
    an error. `shape_size`, when given, is the number of shape values the body model has: any other
    length is an error. The stamp is integer nanoseconds: exact for `{sec, nanosec}`, the nearest
    nanosecond for float seconds. Limits and ranges: BODIES_SCHEMA.md. Quality, joints3d and flags are
    not needed for BodyParams and are not checked. Raises BodiesError (a ValueError) naming what is wrong.
    """
    return document_to_params(load_document(text), joint_names, shape_size=shape_size)


def document_to_params(
    doc: Any, joint_names: Sequence[str], *, shape_size: int | None = None
) -> tuple[int, str, dict[int, BodyParams]]:
    """`bodies_json_to_params` of a document already read with `load_document` (readers of documents
    with more keys, e.g. ground truth with vertices, parse once)."""
    stamp_ns, frame_id = _header(doc)
    entries = doc.get("bodies")
    if not isinstance(entries, list):
        raise BodiesError(f"bodies document: 'bodies' must be a list, got {type(entries).__name__}")
    bodies: dict[int, BodyParams] = {}
    for i, entry in enumerate(entries):
        pid, params = _body(entry, i, joint_names, shape_size)
        if pid in bodies:
            raise BodiesError(f"bodies[{i}]: person id {pid} appears twice")
        bodies[pid] = params
    return stamp_ns, frame_id, bodies
