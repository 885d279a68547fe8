"""A library of everyday pose families, authored as anatomical joint angles.

Angles are degrees [flexion, twist, abduction] per body joint (`body.joints.BODY_JOINTS`), measured
from the anatomical neutral (standing upright, limbs straight and hanging, palms in):
- flexion: hips and shoulders swing the limb forward, knees and elbows bend, ankles dorsiflex (toes up),
  spine, neck and head bend forward, collars shrug;
- abduction: away from the midline for sided joints; spine, neck and head bend to the body's left;
- twist: external rotation for sided joints (both sides alike); spine, neck and head turn left.

A pose is built joint by joint as R = R_flex · R_abd · R_twist · N, each about the joint's anatomical
axes (from the body model's rest geometry, `BodyModel.anatomy`) carried to neutral by N, the rotation
taking the rest bone to neutral. Composing the three rotations in a fixed order (rather than adding
them into one axis-angle vector) keeps large combined rotations meaningful: an arm abducted 90 deg and
rotated externally 90 deg points its forearm up when the elbow bends, as in a wave.

Families also set a whole-body forward lean (about the body's left axis): bending over and crouching
tilt the pelvis, and the hips flex by as much to keep the legs down. A family's random variation is
Gaussian per joint angle, then clipped to the model's joint ranges.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from smplify3d_ros.body.joints import BODY_JOINTS, HINGE_JOINTS, JOINT_INDEX, joint_spec

FAMILIES: tuple[str, ...] = (
    "standing",
    "walking",
    "running",
    "waving",
    "pointing",
    "reaching_up",
    "bending_over",
    "crouching",
    "sitting",
    "carrying",
    "kneeling",
    "hands_on_hips",
    "arms_crossed",
    "stepping_up",
    "leaning",
    "turning",
)
PHASED_FAMILIES = ("walking", "running")  # families with a gait-cycle phase in [0, 1)

PROP_SEAT = "seat"  # the person needs a seat under the pelvis
PROP_CARRIED_BOX = "carried_box"  # the person holds a box between the hands
PROP_STEP = "step"  # the person's raised foot stands on a step
PROP_POST = "post"  # the person leans back against a post

_SIDES = ("left", "right")
_DEFAULT_SIGMA = 3.0  # deg, variation of every angle a family does not set a spread for


@dataclass
class PoseSpec:
    """Anatomical angles of one pose, before conversion to a body model's axis-angle pose."""

    family: str
    angles_deg: np.ndarray  # (J, 3) [flexion, twist, abduction] from neutral, degrees
    sigma_deg: np.ndarray  # (J, 3) random variation of each angle, degrees
    lean_deg: float = 0.0  # whole-body forward lean, degrees
    lean_sigma_deg: float = 0.0
    phase: float | None = None
    props: tuple[str, ...] = field(default_factory=tuple)
    side: str | None = None  # the side a one-sided family uses (the raised foot of stepping_up)
    # joints whose flexion absorbs the random part of the lean (legs stay under the body)
    lean_followers: tuple[str, ...] = ("left_hip", "right_hip")

    def set(
        self,
        joint: str,
        flex: float = 0.0,
        twist: float = 0.0,
        abd: float = 0.0,
        sigma: tuple[float, float, float] | float | None = None,
    ) -> None:
        i = JOINT_INDEX[joint]
        self.angles_deg[i] = (flex, twist, abd)
        if sigma is not None:
            self.sigma_deg[i] = sigma

    def both(
        self,
        kind: str,
        flex: float = 0.0,
        twist: float = 0.0,
        abd: float = 0.0,
        sigma: tuple[float, float, float] | float | None = None,
    ) -> None:
        for side in _SIDES:
            self.set(f"{side}_{kind}", flex, twist, abd, sigma)


@dataclass
class Pose:
    """A sampled pose: the model's axis-angle rows plus what the scene must know about it."""

    family: str
    pose: np.ndarray  # (J, 3) float64 axis-angle, model convention (body.base)
    angles_deg: np.ndarray  # (J, 3) the sampled anatomical angles (after clipping)
    lean_deg: float
    phase: float | None
    props: tuple[str, ...]
    side: str | None = None


# -- gait tables (percent of the cycle from heel strike, degrees), after normative gait data ----------
_WALK_T = np.array([0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100], dtype=float)
_WALK_HIP = np.array([30, 27, 18, 8, -2, -10, -4, 14, 27, 32, 30], dtype=float)
_WALK_KNEE = np.array([4, 16, 14, 7, 5, 10, 36, 60, 48, 18, 4], dtype=float)
_WALK_ANKLE = np.array([0, -4, 4, 8, 10, 4, -16, -6, 0, 2, 0], dtype=float)
_RUN_T = np.array([0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100], dtype=float)
_RUN_HIP = np.array([35, 25, 10, -5, -15, -10, 15, 45, 58, 48, 35], dtype=float)
_RUN_KNEE = np.array([22, 40, 35, 22, 25, 55, 90, 105, 80, 40, 22], dtype=float)
_RUN_ANKLE = np.array([5, 15, 10, -5, -22, -15, -5, 5, 5, 5, 5], dtype=float)


def _cycle(table_t: np.ndarray, table: np.ndarray, phase: float) -> float:
    return float(np.interp((phase % 1.0) * 100.0, table_t, table))


def _new(family: str, **kwargs) -> PoseSpec:
    J = len(BODY_JOINTS)
    return PoseSpec(family, np.zeros((J, 3)), np.full((J, 3), _DEFAULT_SIGMA), **kwargs)


def _relaxed_arms(spec: PoseSpec, sides: tuple[str, ...] = _SIDES) -> None:
    for side in sides:
        spec.set(f"{side}_shoulder", 2, 0, 8, sigma=(8, 10, 4))
        spec.set(f"{side}_elbow", 12, 0, 0, sigma=(8, 10, 2))
        spec.set(f"{side}_wrist", 0, 0, 0, sigma=5)


def _standing_legs(spec: PoseSpec) -> None:
    spec.both("hip", 0, 6, 4, sigma=(4, 6, 2))
    spec.both("knee", 3, 0, 0, sigma=(3, 2, 1))
    spec.both("ankle", 0, 0, 0, sigma=(2, 3, 2))


def _head_free(spec: PoseSpec) -> None:
    spec.set("neck", 0, 0, 0, sigma=(6, 10, 4))
    spec.set("head", 0, 0, 0, sigma=(6, 10, 4))


def standing(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    spec = _new("standing", lean_sigma_deg=2.0)
    _standing_legs(spec)
    _relaxed_arms(spec)
    _head_free(spec)
    if rng.random() < 0.5:  # weight on one leg: that hip adducts, the other knee bends
        side, other = _SIDES[int(rng.integers(2))], None
        other = "right" if side == "left" else "left"
        spec.set(f"{side}_hip", 0, 6, -2, sigma=(3, 5, 2))
        spec.set(f"{other}_hip", 4, 10, 8, sigma=(3, 5, 2))
        spec.set(f"{other}_knee", 12, 0, 0, sigma=(4, 2, 1))
    return spec


def _gait(
    family: str,
    phase: float,
    hip: tuple,
    knee: tuple,
    ankle: tuple,
    arm_gain: float,
    elbow_mean: float,
    lean: float,
    twist_gain: float,
) -> PoseSpec:
    spec = _new(family, lean_deg=lean, lean_sigma_deg=2.0, phase=phase)
    left_hip = 0.0
    for side, offset in (("left", 0.0), ("right", 0.5)):
        p = phase + offset
        h = _cycle(hip[0], hip[1], p)
        spec.set(f"{side}_hip", h, 4, 3, sigma=(3, 4, 1.5))
        spec.set(f"{side}_knee", _cycle(knee[0], knee[1], p), 0, 0, sigma=(4, 2, 1))
        spec.set(f"{side}_ankle", _cycle(ankle[0], ankle[1], p), 0, 0, sigma=(3, 3, 2))
        swing = -arm_gain * (h - float(np.mean(hip[1])))  # the arm swings against its own leg
        spec.set(f"{side}_shoulder", swing, 0, 7, sigma=(4, 6, 3))
        spec.set(f"{side}_elbow", elbow_mean + 0.4 * max(swing, 0.0), 0, 0, sigma=(6, 6, 2))
        if side == "left":
            left_hip = h
    # the thorax counter-rotates against the pelvis: turns away from the forward-swinging leg
    spec.set("spine3", 0, -twist_gain * (left_hip - float(np.mean(hip[1]))), 0, sigma=(2, 2, 2))
    _head_free(spec)
    return spec


def walking(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    phase = float(rng.random()) if phase is None else phase
    return _gait(
        "walking",
        phase,
        (_WALK_T, _WALK_HIP),
        (_WALK_T, _WALK_KNEE),
        (_WALK_T, _WALK_ANKLE),
        arm_gain=0.6,
        elbow_mean=18.0,
        lean=3.0,
        twist_gain=0.2,
    )


def running(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    phase = float(rng.random()) if phase is None else phase
    spec = _gait(
        "running",
        phase,
        (_RUN_T, _RUN_HIP),
        (_RUN_T, _RUN_KNEE),
        (_RUN_T, _RUN_ANKLE),
        arm_gain=0.8,
        elbow_mean=80.0,
        lean=8.0,
        twist_gain=0.3,
    )
    return spec


def waving(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    spec = standing(rng)
    spec.family = "waving"
    side = _SIDES[int(rng.integers(2))]
    swing = np.sin(2 * np.pi * (float(rng.random()) if phase is None else phase))
    if rng.random() < 0.6:  # hand up beside the head, forearm vertical, waving from the elbow
        spec.set(f"{side}_shoulder", 0, 75, 85, sigma=(10, 10, 10))
        spec.set(f"{side}_elbow", 95 + 20 * swing, 0, 0, sigma=(8, 5, 2))
    else:  # whole arm raised high, waving from the shoulder
        spec.set(f"{side}_shoulder", 10, 80, 140 + 15 * swing, sigma=(8, 8, 6))
        spec.set(f"{side}_elbow", 15, 0, 0, sigma=(8, 5, 2))
    spec.set(f"{side}_wrist", 0, 0, 0, sigma=8)
    return spec


def pointing(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    spec = standing(rng)
    spec.family = "pointing"
    side = _SIDES[int(rng.integers(2))]
    spec.set(f"{side}_shoulder", 80, 0, 15, sigma=(10, 8, 12))
    spec.set(f"{side}_elbow", 5, 0, 0, sigma=(4, 5, 2))
    spec.set(f"{side}_wrist", 0, 0, 0, sigma=4)
    spec.set("neck", 0, 10 if side == "left" else -10, 0, sigma=(4, 6, 3))
    return spec


def reaching_up(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    spec = _new("reaching_up", lean_deg=-2.0, lean_sigma_deg=2.0)
    _standing_legs(spec)
    spec.both("shoulder", 160, 0, 12, sigma=(8, 8, 5))
    spec.both("elbow", 12, 0, 0, sigma=(8, 5, 2))
    spec.both("collar", 15, 0, 0, sigma=(4, 3, 3))
    spec.set("spine3", -8, 0, 0, sigma=(3, 3, 2))
    spec.set("neck", -15, 0, 0, sigma=(5, 6, 3))
    spec.set("head", -15, 0, 0, sigma=(5, 6, 3))
    return spec


def bending_over(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    lean = 55.0
    spec = _new("bending_over", lean_deg=lean, lean_sigma_deg=10.0)
    spec.both("hip", lean, 5, 6, sigma=(3, 4, 2))
    spec.both("knee", 10, 0, 0, sigma=(5, 2, 1))
    spec.both("ankle", -5, 0, 0, sigma=(3, 3, 2))
    for joint in ("spine1", "spine2", "spine3"):
        spec.set(joint, 12, 0, 0, sigma=(4, 3, 2))
    spec.set("neck", -25, 0, 0, sigma=(6, 8, 3))  # looks ahead rather than at the feet
    spec.set("head", -15, 0, 0, sigma=(5, 8, 3))
    spec.both("shoulder", lean + 30, 0, 8, sigma=(12, 10, 5))  # arms hang down or reach to the floor
    spec.lean_followers = ("left_hip", "right_hip", "left_shoulder", "right_shoulder")
    spec.both("elbow", 12, 0, 0, sigma=(8, 5, 2))
    return spec


def crouching(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    lean = 30.0
    spec = _new("crouching", lean_deg=lean, lean_sigma_deg=6.0)
    spec.both("hip", 112, 12, 14, sigma=(6, 5, 4))
    spec.both("knee", 125, 0, 0, sigma=(8, 2, 1))
    spec.both("ankle", 28, 0, 0, sigma=(2, 3, 2))
    for joint in ("spine1", "spine2", "spine3"):
        spec.set(joint, 8, 0, 0, sigma=(3, 3, 2))
    spec.set("neck", -20, 0, 0, sigma=(5, 8, 3))
    spec.set("head", -10, 0, 0, sigma=(5, 8, 3))
    spec.both("shoulder", 55, 0, 12, sigma=(10, 8, 5))  # forearms resting towards the knees
    spec.both("elbow", 55, 0, 0, sigma=(12, 5, 2))
    return spec


def sitting(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    spec = _new("sitting", lean_deg=-4.0, lean_sigma_deg=4.0, props=(PROP_SEAT,))
    spec.both("hip", 88, 8, 8, sigma=(5, 5, 4))
    spec.both("knee", 88, 0, 0, sigma=(8, 2, 1))
    spec.both("ankle", 0, 0, 0, sigma=(4, 3, 2))
    spec.set("spine2", 5, 0, 0, sigma=(3, 3, 2))
    spec.both("shoulder", 20, 0, 10, sigma=(8, 8, 4))  # hands on the thighs
    spec.both("elbow", 55, 0, 0, sigma=(10, 5, 2))
    _head_free(spec)
    return spec


def carrying(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    spec = standing(rng)
    spec.family = "carrying"
    spec.props = (PROP_CARRIED_BOX,)
    spec.lean_deg = -3.0
    spec.both("shoulder", 22, -8, 12, sigma=(4, 4, 3))
    spec.both("elbow", 80, 0, 0, sigma=(5, 4, 2))
    spec.both("wrist", 0, 0, 0, sigma=3)
    return spec


def kneeling(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    """On both knees (thighs upright, shins on the ground) or on one (the other foot planted ahead)."""
    spec = _new("kneeling", lean_deg=4.0, lean_sigma_deg=4.0)
    _relaxed_arms(spec)
    _head_free(spec)
    spec.both("ankle", -35, 0, 0, sigma=(6, 3, 2))  # toes point back along the ground
    if rng.random() < 0.5:
        spec.both("hip", 8, 6, 6, sigma=(6, 5, 3))
        spec.both("knee", 95, 0, 0, sigma=(6, 2, 1))
    else:
        front = _SIDES[int(rng.integers(2))]
        back = "right" if front == "left" else "left"
        spec.set(f"{front}_hip", 85, 5, 8, sigma=(8, 5, 3))
        spec.set(f"{front}_knee", 90, 0, 0, sigma=(8, 2, 1))
        spec.set(f"{front}_ankle", 5, 0, 0, sigma=(5, 3, 2))
        spec.set(f"{back}_hip", -5, 5, 4, sigma=(5, 5, 2))
        spec.set(f"{back}_knee", 100, 0, 0, sigma=(6, 2, 1))
    return spec


def hands_on_hips(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    """Standing, elbows out to the sides, hands resting on the hips."""
    spec = standing(rng)
    spec.family = "hands_on_hips"
    spec.both("shoulder", -10, -55, 40, sigma=(5, 8, 5))  # turned in, so that the bent forearm points to the hip
    spec.both("elbow", 100, 0, 0, sigma=(8, 5, 2))
    spec.both("wrist", 0, 0, 0, sigma=5)
    return spec


def arms_crossed(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    """Standing with the forearms folded across the chest, one above the other."""
    spec = standing(rng)
    spec.family = "arms_crossed"
    upper = _SIDES[int(rng.integers(2))]
    for side in _SIDES:
        spec.set(f"{side}_shoulder", 30 if side == upper else 20, -80, 12, sigma=(5, 5, 4))
        spec.set(f"{side}_elbow", 120, 0, 0, sigma=(6, 5, 2))
        spec.set(f"{side}_wrist", 0, 0, 0, sigma=4)
    return spec


def stepping_up(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    """One foot raised onto a step (a prop under it), the other leg straight, a slight forward lean."""
    spec = _new("stepping_up", lean_deg=8.0, lean_sigma_deg=3.0, props=(PROP_STEP,))
    side = _SIDES[int(rng.integers(2))]
    other = "right" if side == "left" else "left"
    spec.side = side
    spec.set(f"{side}_hip", 60, 5, 4, sigma=(6, 4, 2))
    spec.set(f"{side}_knee", 70, 0, 0, sigma=(6, 2, 1))
    spec.set(f"{side}_ankle", 10, 0, 0, sigma=(3, 3, 2))
    spec.set(f"{other}_hip", -5, 5, 3, sigma=(3, 4, 2))
    spec.set(f"{other}_knee", 5, 0, 0, sigma=(3, 2, 1))
    spec.set(f"{other}_ankle", 5, 0, 0, sigma=(3, 3, 2))
    spec.set(f"{side}_shoulder", -15, 0, 8, sigma=(6, 6, 3))  # arms swing against the legs
    spec.set(f"{other}_shoulder", 20, 0, 8, sigma=(6, 6, 3))
    spec.both("elbow", 25, 0, 0, sigma=(8, 5, 2))
    _head_free(spec)
    return spec


def leaning(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    """Leaning back against a post (a prop behind the shoulders): the whole body tilts back as one,
    feet ahead of the post, arms relaxed or crossed."""
    spec = _new("leaning", lean_deg=-12.0, lean_sigma_deg=3.0, props=(PROP_POST,), lean_followers=())
    _standing_legs(spec)
    if rng.random() < 0.5:
        _relaxed_arms(spec)
    else:
        for side in _SIDES:
            spec.set(f"{side}_shoulder", 25, -80, 12, sigma=(5, 5, 4))
            spec.set(f"{side}_elbow", 120, 0, 0, sigma=(6, 5, 2))
    spec.set("neck", 12, 0, 0, sigma=(5, 10, 4))  # the head comes forward to look level
    spec.set("head", 0, 0, 0, sigma=(5, 10, 4))
    return spec


def turning(rng: np.random.Generator, phase: float | None = None) -> PoseSpec:
    """Mid-turn: the spine and head twisted towards one side, one foot pivoting on the other."""
    spec = _new("turning", lean_sigma_deg=2.0)
    sign = 1.0 if rng.random() < 0.5 else -1.0  # + turns to the body's left
    pivot = "left" if sign > 0 else "right"
    stepping = "right" if sign > 0 else "left"
    spec.set(f"{pivot}_hip", 0, 25, 4, sigma=(4, 6, 2))  # the pivot leg turns out
    spec.set(f"{pivot}_knee", 8, 0, 0, sigma=(3, 2, 1))
    spec.set(f"{stepping}_hip", 20, -15, 10, sigma=(6, 6, 3))  # the other leg steps round
    spec.set(f"{stepping}_knee", 25, 0, 0, sigma=(6, 2, 1))
    spec.both("ankle", 0, 0, 0, sigma=(3, 3, 2))
    for joint in ("spine1", "spine2", "spine3"):
        spec.set(joint, 0, 12 * sign, 0, sigma=(2, 3, 2))
    spec.set("neck", 0, 30 * sign, 0, sigma=(5, 8, 3))
    spec.set("head", 0, 15 * sign, 0, sigma=(5, 8, 3))
    spec.set(f"{pivot}_shoulder", -15, 0, 10, sigma=(6, 6, 3))
    spec.set(f"{stepping}_shoulder", 25, 0, 10, sigma=(6, 6, 3))
    spec.both("elbow", 25, 0, 0, sigma=(8, 5, 2))
    return spec


FAMILY_BUILDERS: dict[str, Callable[[np.random.Generator, float | None], PoseSpec]] = {
    "standing": standing,
    "walking": walking,
    "running": running,
    "waving": waving,
    "pointing": pointing,
    "reaching_up": reaching_up,
    "bending_over": bending_over,
    "crouching": crouching,
    "sitting": sitting,
    "carrying": carrying,
    "kneeling": kneeling,
    "hands_on_hips": hands_on_hips,
    "arms_crossed": arms_crossed,
    "stepping_up": stepping_up,
    "leaning": leaning,
    "turning": turning,
}


# -- conversion to the body model's pose --------------------------------------------------------------
def _rotmat(axis: np.ndarray, angle: float) -> np.ndarray:
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _rotvec(R: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(R).as_rotvec()


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis)
    if s < 1e-9:
        return np.eye(3)
    return _rotmat(axis / s, float(np.arctan2(s, a @ b)))


def _twist_sign(joint: str) -> float:
    """Model twist (right-handed about the bone) per unit of our twist (external rotation)."""
    return -1.0 if joint.startswith("left_") else 1.0


@dataclass(frozen=True)
class AnatomyAxes:
    """Per joint: neutral-pose anatomical axes and the rotation taking the rest bone to neutral."""

    flexion: np.ndarray  # (J, 3)
    twist: np.ndarray  # (J, 3)
    abduction: np.ndarray  # (J, 3)
    to_neutral: np.ndarray  # (J, 3, 3)
    limits_deg: np.ndarray  # (J, 3, 2) [min, max] of our angles from neutral


def anatomy_axes(model) -> AnatomyAxes:
    """Axes from `model.anatomy` (frames from the rest geometry) and the model's joint ranges."""
    frames = np.asarray(model.anatomy.frames, dtype=np.float64)
    rest = np.asarray(model.anatomy.rest_offset, dtype=np.float64)
    ranges = np.asarray(model.joint_ranges.detach().cpu().numpy(), dtype=np.float64)
    J = len(BODY_JOINTS)
    to_neutral = np.repeat(np.eye(3)[None], J, axis=0)
    limits = np.rad2deg(ranges + rest[..., None])
    for i, name in enumerate(BODY_JOINTS):
        spec = joint_spec(name)
        a, u, _ = frames[i]
        if spec.neutral_direction is not None:
            to_neutral[i] = _rotation_between(u, spec.neutral_direction)
        elif name in HINGE_JOINTS:
            to_neutral[i] = _rotmat(a, -rest[i, 0])
        if _twist_sign(name) < 0:
            limits[i, 1] = -limits[i, 1, ::-1]
    axes = np.einsum("jab,jkb->jka", to_neutral, frames)  # each frame row carried to neutral
    return AnatomyAxes(axes[:, 0], axes[:, 1], axes[:, 2], to_neutral, limits)


_AXES_CACHE: dict[int, AnatomyAxes] = {}


def _axes_of(model) -> AnatomyAxes:
    key = id(model)
    if key not in _AXES_CACHE:
        _AXES_CACHE[key] = anatomy_axes(model)
    return _AXES_CACHE[key]


def angles_to_pose(model, angles_deg: np.ndarray) -> np.ndarray:
    """(J, 3) anatomical angles from neutral (degrees, our convention) -> (J, 3) model axis-angle."""
    axes = _axes_of(model)
    pose = np.zeros((len(BODY_JOINTS), 3))
    for i, name in enumerate(BODY_JOINTS):
        flex, twist, abd = np.deg2rad(angles_deg[i])
        R = (
            _rotmat(axes.flexion[i], flex)
            @ _rotmat(axes.abduction[i], abd)
            @ _rotmat(axes.twist[i], _twist_sign(name) * twist)
            @ axes.to_neutral[i]
        )
        pose[i] = _rotvec(R)
    return pose


def clip_to_limits(model, angles_deg: np.ndarray) -> np.ndarray:
    limits = _axes_of(model).limits_deg
    return np.clip(angles_deg, limits[..., 0], limits[..., 1])


def toward_limits(model, angles_deg: np.ndarray, fraction: float, rng: np.random.Generator) -> np.ndarray:
    """Every angle moved by a uniform random fraction in [-fraction, fraction] of its way to the joint
    limit on that side: variation that grows with each joint's room and never leaves its range."""
    limits = _axes_of(model).limits_deg
    angles = clip_to_limits(model, angles_deg)
    u = rng.uniform(-fraction, fraction, angles.shape)
    room = np.where(u > 0, limits[..., 1] - angles, angles - limits[..., 0])
    return angles + u * room


def sample_pose(
    model,
    family: str,
    rng: np.random.Generator,
    phase: float | None = None,
    variation_scale: float = 1.0,
    limit_variation: float = 0.0,
) -> Pose:
    """One random pose of `family` (a gait phase for walking/running; random when None); with
    `limit_variation`, every angle also moves towards its joint limits (`toward_limits`)."""
    if family not in FAMILY_BUILDERS:
        raise ValueError(f"unknown pose family {family!r}; known: {', '.join(FAMILIES)}")
    spec = FAMILY_BUILDERS[family](rng, phase)
    angles = spec.angles_deg + rng.normal(0.0, 1.0, spec.angles_deg.shape) * spec.sigma_deg * variation_scale
    lean = spec.lean_deg + float(rng.normal(0.0, spec.lean_sigma_deg * variation_scale))
    for joint in spec.lean_followers:
        angles[JOINT_INDEX[joint], 0] += lean - spec.lean_deg
    angles = clip_to_limits(model, angles)
    if limit_variation > 0:  # no draw otherwise: scenes without it stay as they were
        angles = toward_limits(model, angles, limit_variation, rng)
    return Pose(family, angles_to_pose(model, angles), angles, lean, spec.phase, spec.props, spec.side)
