"""The `~/bodies` JSON document (std_msgs/String): writer and validating parser.

The schema is described in BODIES_SCHEMA.md next to this file. The parser also reads the node's optional
`init_bodies` input, so it accepts documents written by hand or by other tools: everything it needs is
validated and every error names the body and key at fault.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from msg_adapters.factory import split_stamp
from smplify3d_ros.keypoints import COCO17_NAMES
from smplify3d_ros.types import BodyFit, BodyParams

SCHEMA = "smplify3d_ros/bodies"
VERSION = 1
_DECIMALS = 6  # micrometres / microradians: far below fit accuracy, keeps documents short


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
        "flags": sorted(str(f) for f in fit.flags),
    }


def fits_to_bodies_json(fits: Sequence[BodyFit], stamp: Any, frame_id: str) -> str:
    """The `~/bodies` document for one frame. `stamp`: float seconds or a stamp message (kept exact)."""
    sec, nanosec = split_stamp(stamp)
    doc = {
        "schema": SCHEMA,
        "version": VERSION,
        "stamp": {"sec": sec, "nanosec": nanosec},
        "frame_id": str(frame_id),
        "bodies": [fit_to_dict(f) for f in fits],
    }
    return json.dumps(doc, allow_nan=False, separators=(",", ":"))


# ------------------------------------------------------------------------------------------------ parse
def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _numbers(value: Any, where: str, size: int | None = None) -> np.ndarray:
    if not isinstance(value, list) or not all(_is_number(x) for x in value):
        raise BodiesError(f"{where} must be a list of finite numbers, got {value!r}")
    if size is not None and len(value) != size:
        raise BodiesError(f"{where} must have {size} numbers, got {len(value)}")
    return np.asarray(value, dtype=np.float64)


def _stamp(value: Any) -> float:
    if _is_number(value):
        return float(value)
    if isinstance(value, dict) and set(value) == {"sec", "nanosec"} and all(
        isinstance(value[k], int) and not isinstance(value[k], bool) for k in value
    ) and 0 <= value["nanosec"] < 1_000_000_000:
        return value["sec"] + value["nanosec"] * 1e-9
    raise BodiesError(f"'stamp' must be {{'sec': int, 'nanosec': int in [0, 1e9)}} or seconds, got {value!r}")


def _body(entry: Any, i: int, joint_names: Sequence[str]) -> tuple[int, BodyParams]:
    where = f"bodies[{i}]"
    if not isinstance(entry, dict):
        raise BodiesError(f"{where} must be an object, got {type(entry).__name__}")
    pid = entry.get("id")
    if not isinstance(pid, int) or isinstance(pid, bool):
        raise BodiesError(f"{where}: 'id' must be an integer, got {pid!r}")
    where = f"bodies[{i}] (id {pid})"
    for key in ("model", "shape", "pose", "root_orient", "transl"):
        if key not in entry:
            raise BodiesError(f"{where}: missing {key!r}")
    model = entry["model"]
    if not isinstance(model, str) or not model:
        raise BodiesError(f"{where}: 'model' must be a non-empty string, got {model!r}")
    shape = _numbers(entry["shape"], f"{where}: 'shape'")
    root_orient = _numbers(entry["root_orient"], f"{where}: 'root_orient'", 3)
    transl = _numbers(entry["transl"], f"{where}: 'transl'", 3)
    pose_in = entry["pose"]
    if not isinstance(pose_in, dict):
        raise BodiesError(
            f"{where}: 'pose' must map joint names to [ax, ay, az], got {type(pose_in).__name__}"
        )
    index = {name: j for j, name in enumerate(joint_names)}
    unknown = sorted(set(pose_in) - set(index))
    if unknown:
        raise BodiesError(f"{where}: unknown joint(s) in 'pose': {', '.join(unknown)}; known: "
                         f"{', '.join(joint_names)}")
    pose = np.zeros((len(joint_names), 3))
    for name, value in pose_in.items():
        pose[index[name]] = _numbers(value, f"{where}: pose[{name!r}]", 3)
    return pid, BodyParams(model=model, shape=shape, pose=pose, root_orient=root_orient, transl=transl)


def bodies_json_to_params(
    text: str | bytes, joint_names: Sequence[str]
) -> tuple[float, str, dict[int, BodyParams]]:
    """Parse a `~/bodies` document -> (stamp s, frame_id, {person id: BodyParams}).

    `joint_names` orders the pose rows (the body model's `joint_names`); joints the document leaves out
    get a zero rotation, joints it names that are not in `joint_names` are an error. Quality, joints3d and
    flags are not needed for BodyParams and are not checked. Raises BodiesError (a ValueError) naming
    what is wrong.
    """
    try:
        doc = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise BodiesError(f"bodies document is not valid JSON: {e}") from e
    if not isinstance(doc, dict):
        raise BodiesError(f"bodies document must be a JSON object, got {type(doc).__name__}")
    if doc.get("schema") != SCHEMA:
        raise BodiesError(f"bodies document: 'schema' must be {SCHEMA!r}, got {doc.get('schema')!r}")
    version = doc.get("version")
    if not isinstance(version, int) or isinstance(version, bool) or not 1 <= version <= VERSION:
        raise BodiesError(
            f"bodies document: unsupported 'version' {version!r} (this reader knows 1 to {VERSION})"
        )
    if "stamp" not in doc:
        raise BodiesError("bodies document: missing 'stamp'")
    stamp = _stamp(doc["stamp"])
    frame_id = doc.get("frame_id")
    if not isinstance(frame_id, str):
        raise BodiesError(f"bodies document: 'frame_id' must be a string, got {frame_id!r}")
    entries = doc.get("bodies")
    if not isinstance(entries, list):
        raise BodiesError(f"bodies document: 'bodies' must be a list, got {type(entries).__name__}")
    bodies: dict[int, BodyParams] = {}
    for i, entry in enumerate(entries):
        pid, params = _body(entry, i, joint_names)
        if pid in bodies:
            raise BodiesError(f"bodies[{i}]: person id {pid} appears twice")
        bodies[pid] = params
    return stamp, frame_id, bodies
