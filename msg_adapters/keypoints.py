"""The keypoint input encoding (a PointCloud2) <-> COCO-17 keypoint arrays, for several detector formats.

Encoding (docs/encodings.md, "Keypoints"): an unorganized PointCloud2 with one point per (person, joint), fields
`u`, `v` (float32, pixels), `score` (float32, [0, 1]), `person` (int32 track id, -1 when the detector
has none), `joint` (uint16, the joint's index in the detector's keypoint format). An empty cloud means
"no person in this image". Readers also accept any integer type for `person` / `joint` and any float
type for `u` / `v` / `score`; a missing `score` field reads as 1, a missing `person` field as -1.

People without an id (person = -1) cannot be told apart by the encoding itself. The reader groups their
points by consecutive runs: the points of one person must be contiguous, and a joint index that repeats
within a run starts the next person (so two anonymous people published back to back separate correctly
as long as each lists a joint at most once). Points with an id >= 0 are grouped by id, in order of
first appearance, wherever they appear.

Each format is one table, `KeypointFormat.joints`, listing its joints in index order with the COCO-17
name each maps to (None for joints COCO-17 lacks, e.g. OpenPose's neck or the feet).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from msg_adapters.factory import MessageFactory, stamp_to_ns
from msg_adapters.pointcloud2 import POINTFIELD_DTYPES, PointCloudError, make_pointcloud2, read_fields
from smplify3d_ros.keypoints import COCO17_NAMES, KP, NUM_KEYPOINTS


class KeypointError(ValueError):
    """A keypoint message or format this module cannot interpret; the message says what is wrong."""


@dataclass(frozen=True)
class KeypointFormat:
    """A detector's keypoint format: its joints by index, each with the COCO-17 joint it maps to."""

    name: str
    joints: tuple[tuple[str, str | None], ...]  # (joint name in this format, COCO-17 name or None)
    source: str = ""  # where the index order is defined
    to_coco: np.ndarray = field(init=False, repr=False, compare=False)  # (n,) COCO index, -1 if none
    from_coco: np.ndarray = field(init=False, repr=False, compare=False)  # (17,) format index, -1 if none

    def __post_init__(self) -> None:
        to_coco = np.full(len(self.joints), -1, dtype=np.int64)
        from_coco = np.full(NUM_KEYPOINTS, -1, dtype=np.int64)
        for i, (name, coco) in enumerate(self.joints):
            if coco is None:
                continue
            if coco not in KP:
                raise KeypointError(
                    f"format {self.name!r}: joint {name!r} maps to unknown COCO name {coco!r}"
                )
            if from_coco[KP[coco]] >= 0:
                raise KeypointError(f"format {self.name!r}: COCO joint {coco!r} is mapped twice")
            to_coco[i], from_coco[KP[coco]] = KP[coco], i
        object.__setattr__(self, "to_coco", to_coco)
        object.__setattr__(self, "from_coco", from_coco)

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.joints)


_COCO17 = KeypointFormat("coco17", tuple((n, n) for n in COCO17_NAMES), "COCO keypoints (17)")

_BODY25 = KeypointFormat(
    "body25",
    (
        ("Nose", "nose"), ("Neck", None), ("RShoulder", "right_shoulder"), ("RElbow", "right_elbow"),
        ("RWrist", "right_wrist"), ("LShoulder", "left_shoulder"), ("LElbow", "left_elbow"),
        ("LWrist", "left_wrist"), ("MidHip", None), ("RHip", "right_hip"), ("RKnee", "right_knee"),
        ("RAnkle", "right_ankle"), ("LHip", "left_hip"), ("LKnee", "left_knee"), ("LAnkle", "left_ankle"),
        ("REye", "right_eye"), ("LEye", "left_eye"), ("REar", "right_ear"), ("LEar", "left_ear"),
        ("LBigToe", None), ("LSmallToe", None), ("LHeel", None), ("RBigToe", None), ("RSmallToe", None),
        ("RHeel", None),
    ),
    "OpenPose BODY_25 (doc/02_output.md, POSE_BODY_25_BODY_PARTS)",
)

_HALPE26 = KeypointFormat(
    "halpe26",
    (
        *((n, n) for n in COCO17_NAMES),  # Halpe-26 starts with COCO-17 in COCO order
        ("Head", None), ("Neck", None), ("Hip", None), ("LBigToe", None), ("RBigToe", None),
        ("LSmallToe", None), ("RSmallToe", None), ("LHeel", None), ("RHeel", None),
    ),
    "AlphaPose Halpe-26 (docs/output.md)",
)

_OPENPOSE18_HEAD = (
    ("Nose", "nose"), ("Neck", None), ("RShoulder", "right_shoulder"), ("RElbow", "right_elbow"),
    ("RWrist", "right_wrist"), ("LShoulder", "left_shoulder"), ("LElbow", "left_elbow"),
    ("LWrist", "left_wrist"), ("RHip", "right_hip"), ("RKnee", "right_knee"), ("RAnkle", "right_ankle"),
    ("LHip", "left_hip"), ("LKnee", "left_knee"), ("LAnkle", "left_ankle"),
)

_OPENPOSE18 = KeypointFormat(
    "openpose18",
    (*_OPENPOSE18_HEAD, ("REye", "right_eye"), ("LEye", "left_eye"), ("REar", "right_ear"),
     ("LEar", "left_ear")),
    "OpenPose COCO-18 (POSE_COCO_BODY_PARTS): 14 REye, 15 LEye, 16 REar, 17 LEar",
)

# REP-155 (ROS4HRI) hri_msgs/Skeleton2D says it follows OpenPose's COCO model, but its constants put the
# left eye/ear first: 14 LEFT_EYE, 15 RIGHT_EYE, 16 LEFT_EAR, 17 RIGHT_EAR. Both orders are kept.
_REP155 = KeypointFormat(
    "rep155",
    (
        ("NOSE", "nose"), ("NECK", None), ("RIGHT_SHOULDER", "right_shoulder"),
        ("RIGHT_ELBOW", "right_elbow"), ("RIGHT_WRIST", "right_wrist"), ("LEFT_SHOULDER", "left_shoulder"),
        ("LEFT_ELBOW", "left_elbow"), ("LEFT_WRIST", "left_wrist"), ("RIGHT_HIP", "right_hip"),
        ("RIGHT_KNEE", "right_knee"), ("RIGHT_ANKLE", "right_ankle"), ("LEFT_HIP", "left_hip"),
        ("LEFT_KNEE", "left_knee"), ("LEFT_ANKLE", "left_ankle"), ("LEFT_EYE", "left_eye"),
        ("RIGHT_EYE", "right_eye"), ("LEFT_EAR", "left_ear"), ("RIGHT_EAR", "right_ear"),
    ),
    "REP-155 / hri_msgs Skeleton2D constants",
)

KEYPOINT_FORMATS: dict[str, KeypointFormat] = {
    f.name: f for f in (_COCO17, _BODY25, _HALPE26, _OPENPOSE18, _REP155)
}


def get_keypoint_format(name: str | KeypointFormat) -> KeypointFormat:
    """The format named `name` (or `name` itself if it already is one); KeypointError if unknown."""
    if isinstance(name, KeypointFormat):
        return name
    fmt = KEYPOINT_FORMATS.get(str(name).lower())
    if fmt is None:
        raise KeypointError(f"unknown keypoint format {name!r}; known: {', '.join(KEYPOINT_FORMATS)}")
    return fmt


@dataclass
class KeypointSet:
    """The people of one keypoint message, in COCO-17 order."""

    keypoints: np.ndarray  # (P, 17, 3) float64: u, v (px), score in [0, 1]; missing joints are (0, 0, 0)
    person_ids: np.ndarray  # (P,) int64 detector track ids, -1 where the detector gave none
    frame_id: str = ""
    stamp_ns: int = 0  # the header's stamp, integer ns
    dropped_joints: int = 0  # points with a joint index outside the format: ignored
    duplicate_joints: int = 0  # repeated (person, joint) points: the highest score was kept
    nan_points: int = 0  # points with non-finite u or v: kept as missing (score 0)
    bad_scores: int = 0  # points with a NaN or infinite score (finite u, v): kept as missing (score 0)

    def __len__(self) -> int:
        return len(self.person_ids)


def _empty(frame_id: str, stamp: int) -> KeypointSet:
    return KeypointSet(np.zeros((0, NUM_KEYPOINTS, 3)), np.zeros(0, np.int64), frame_id, stamp)


def _field_kind(msg: Any, name: str) -> str | None:
    for f in msg.fields:
        if f.name == name:
            dtype = POINTFIELD_DTYPES.get(int(f.datatype))
            return None if dtype is None else dtype.kind
    return None


def read_keypoints(msg: Any, keypoint_format: str | KeypointFormat = "coco17") -> KeypointSet:
    """Keypoint PointCloud2 (see the module docstring) -> KeypointSet in COCO-17 order.

    Joints outside the format are ignored and counted; joints the format has but COCO-17 lacks are
    ignored; non-finite u/v, and non-finite scores (an infinite confidence is no confidence), give score 0
    and are counted; scores are clipped to [0, 1]. Raises KeypointError
    for a missing `u`, `v` or `joint` field, non-integer `joint` / `person` fields or a malformed cloud.
    """
    fmt = get_keypoint_format(keypoint_format)
    frame_id, stamp = str(msg.header.frame_id), stamp_to_ns(msg.header.stamp)
    if int(msg.width) * int(msg.height) == 0:
        return _empty(frame_id, stamp)
    present = {str(f.name) for f in msg.fields}
    names = ["u", "v", "joint"] + [n for n in ("score", "person") if n in present]
    for name in ("joint", "person"):
        if name in present and _field_kind(msg, name) not in ("i", "u"):
            raise KeypointError(f"keypoint field {name!r} must have an integer datatype")
    try:
        cols = read_fields(msg, names)
    except PointCloudError as e:
        raise KeypointError(f"keypoint cloud: {e}") from e
    u = cols["u"].astype(np.float64)
    v = cols["v"].astype(np.float64)
    n = len(u)
    joint = cols["joint"].astype(np.int64)
    person = cols["person"].astype(np.int64) if "person" in cols else np.full(n, -1, np.int64)
    person[person < 0] = -1
    score = cols["score"].astype(np.float64) if "score" in cols else np.ones(n)
    bad = ~(np.isfinite(u) & np.isfinite(v))
    bad_score = ~np.isfinite(score) & ~bad
    score = np.clip(np.where(np.isfinite(score), score, 0.0), 0.0, 1.0)
    u[bad], v[bad], score[bad] = 0.0, 0.0, 0.0

    in_format = (joint >= 0) & (joint < fmt.num_joints)
    group, ids = _group_people(joint, person, in_format)
    coco = np.full(n, -1, np.int64)
    coco[in_format] = fmt.to_coco[joint[in_format]]
    use = np.flatnonzero(coco >= 0)
    key = group[use] * NUM_KEYPOINTS + coco[use]
    order = np.lexsort((score[use], key))  # by (person, joint), then score: the last of a key wins
    key_sorted = key[order]
    last = np.r_[key_sorted[1:] != key_sorted[:-1], True] if len(order) else np.zeros(0, bool)
    chosen = use[order[last]]
    keypoints = np.zeros((len(ids), NUM_KEYPOINTS, 3))
    keypoints[group[chosen], coco[chosen]] = np.stack([u[chosen], v[chosen], score[chosen]], axis=1)
    return KeypointSet(
        keypoints, np.asarray(ids, np.int64), frame_id, stamp,
        dropped_joints=int((~in_format).sum()),
        duplicate_joints=int(len(order) - last.sum()),
        nan_points=int(bad.sum()),
        bad_scores=int(bad_score[in_format].sum()),
    )


def _group_people(joint: np.ndarray, person: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Person slot of each point (-1 for invalid points) and the id of each slot (see module docstring)."""
    group = np.full(len(joint), -1, np.int64)
    ids: list[int] = []
    slot_of_id: dict[int, int] = {}
    run_slot, run_joints = -1, set()
    for i, (j, pid, ok) in enumerate(zip(joint.tolist(), person.tolist(), valid.tolist(), strict=True)):
        if not ok:
            continue
        if pid >= 0:
            run_slot = -1  # an anonymous run ends at any point that carries an id
            if pid not in slot_of_id:
                slot_of_id[pid] = len(ids)
                ids.append(pid)
            group[i] = slot_of_id[pid]
            continue
        if run_slot < 0 or j in run_joints:
            run_slot, run_joints = len(ids), set()
            ids.append(-1)
        run_joints.add(j)
        group[i] = run_slot
    return group, ids


def write_keypoints(
    keypoints: np.ndarray,
    person_ids: np.ndarray,
    stamp: Any,
    frame_id: str,
    factory: MessageFactory | None = None,
    keypoint_format: str | KeypointFormat = "coco17",
) -> Any:
    """(P, 17, 3) COCO-17 keypoints and (P,) ids -> keypoint PointCloud2 in `keypoint_format`.

    Every joint of the format that has a COCO-17 counterpart is written, missing ones with their score
    of 0; joints COCO-17 lacks (e.g. a neck) are not written. Points are grouped per person, so anonymous
    (-1) people read back as separate people. No person gives an empty cloud.
    """
    fmt = get_keypoint_format(keypoint_format)
    kp = np.asarray(keypoints, dtype=np.float64)
    if kp.ndim == 2 and kp.shape == (NUM_KEYPOINTS, 3):
        kp = kp[None]
    ids = np.asarray(person_ids).reshape(-1)
    if kp.ndim != 3 or kp.shape[1:] != (NUM_KEYPOINTS, 3):
        raise KeypointError(f"keypoints must be (P, {NUM_KEYPOINTS}, 3), got {kp.shape}")
    if len(ids) != len(kp):
        raise KeypointError(f"{len(kp)} keypoint sets but {len(ids)} person ids")
    if len(ids) and (ids.dtype.kind not in "iu" or ids.min() < -1 or ids.max() >= 2**31):
        raise KeypointError(f"person ids must be integers in [-1, 2^31), got {ids.tolist()}")
    fmt_joints = np.flatnonzero(fmt.to_coco >= 0)
    coco = fmt.to_coco[fmt_joints]
    per_person = kp[:, coco]  # (P, J, 3)
    n_joints = len(fmt_joints)
    return make_pointcloud2(
        stamp,
        frame_id,
        {
            "u": per_person[..., 0].reshape(-1).astype(np.float32),
            "v": per_person[..., 1].reshape(-1).astype(np.float32),
            "score": per_person[..., 2].reshape(-1).astype(np.float32),
            "person": np.repeat(ids.astype(np.int32), n_joints),
            "joint": np.tile(fmt_joints.astype(np.uint16), len(ids)),
        },
        factory,
    )
