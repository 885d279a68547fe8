"""Ground truth of a recording: one type, one writer and one parser for `/ground_truth/bodies`.

A ground-truth document is a `~/bodies` document (msg_adapters/BODIES_SCHEMA.md) whose bodies may also
carry `vertices` (the mesh, m) and, from the simulator, `detected` (the keypoint topic has the person at
this stamp), `visible_fraction` (of the silhouette, in the image) and `lidar_points` (returns on the
person in the published scan). docs/bags.md describes the topic.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from msg_adapters.bodies import SCHEMA, VERSION, BodiesError, body_to_dict, document_to_params, load_document
from msg_adapters.factory import split_stamp, stamp_to_ns
from smplify3d_ros.keypoints import COCO17_NAMES
from smplify3d_ros.types import BodyParams

GROUND_TRUTH_TOPIC = "/ground_truth/bodies"
VERTEX_DECIMALS = 3  # vertices in millimetres: keeps a body near 70 kB in a bag


@dataclass
class TruthBody:
    """One person at one stamp (the document's frame)."""

    person_id: int
    params: BodyParams
    keypoints3d: np.ndarray | None = None  # (17, 3) float64 COCO-17, m
    vertices: np.ndarray | None = None  # (V, 3) float64, m
    detected: bool | None = None  # simulator: the keypoint topic has this person at this stamp
    visible_fraction: float | None = None  # simulator: fraction of the silhouette the camera sees
    lidar_points: int | None = None  # simulator: returns on this person in the published scan


@dataclass
class TruthFrame:
    stamp_ns: int  # the image's stamp
    frame_id: str
    bodies: list[TruthBody] = field(default_factory=list)
    joint_names: list[str] = field(default_factory=list)  # the order of the bodies' `params.pose` rows


def truth_document(frame: TruthFrame, joint_names: list[str]) -> str:
    """The `/ground_truth/bodies` JSON of one frame (bodies need `keypoints3d`)."""
    sec, nanosec = split_stamp(frame.stamp_ns)
    bodies = []
    for body in frame.bodies:
        entry = body_to_dict(body.person_id, body.params, joint_names, body.keypoints3d)
        if body.vertices is not None:
            entry["vertices"] = np.round(np.asarray(body.vertices, np.float64), VERTEX_DECIMALS).tolist()
        if body.detected is not None:
            entry["detected"] = bool(body.detected)
        if body.visible_fraction is not None:
            entry["visible_fraction"] = round(float(body.visible_fraction), 4)
        if body.lidar_points is not None:
            entry["lidar_points"] = int(body.lidar_points)
        bodies.append(entry)
    doc = {"schema": SCHEMA, "version": VERSION, "stamp": {"sec": sec, "nanosec": nanosec},
           "frame_id": frame.frame_id, "bodies": bodies}
    return json.dumps(doc, allow_nan=False, separators=(",", ":"))


def parse_truth_document(text: str | bytes) -> TruthFrame:
    """A `/ground_truth/bodies` document -> TruthFrame (geometry as the document has it). Raises
    msg_adapters.BodiesError (a ValueError) for a malformed document."""
    doc = load_document(text)
    if not isinstance(doc, dict):
        raise BodiesError(f"ground-truth document must be a JSON object, got {type(doc).__name__}")
    entries = doc.get("bodies") or []
    first = entries[0] if isinstance(entries, list) and entries and isinstance(entries[0], dict) else {}
    joint_names = list(first["pose"]) if isinstance(first.get("pose"), dict) else []  # the document's model
    stamp, frame_id, params = document_to_params(doc, joint_names)
    bodies = []
    for entry in doc["bodies"]:
        pid = int(entry["id"])
        joints3d = entry.get("joints3d")
        keypoints3d = None
        if isinstance(joints3d, dict) and all(name in joints3d for name in COCO17_NAMES):
            keypoints3d = np.array([joints3d[name] for name in COCO17_NAMES], dtype=np.float64)
        vertices = entry.get("vertices")
        bodies.append(TruthBody(
            person_id=pid, params=params[pid], keypoints3d=keypoints3d,
            vertices=np.asarray(vertices, dtype=np.float64).reshape(-1, 3) if vertices else None,
            detected=bool(entry["detected"]) if "detected" in entry else None,
            visible_fraction=float(entry["visible_fraction"]) if "visible_fraction" in entry else None,
            lidar_points=int(entry["lidar_points"]) if "lidar_points" in entry else None,
        ))
    return TruthFrame(stamp_to_ns(stamp), frame_id, bodies, joint_names)
