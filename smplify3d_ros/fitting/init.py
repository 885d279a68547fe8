"""Initial body estimate (thesis Step 0): an external estimate when one is given, else the built-in one.

The built-in initializer works, like CLIFF, in the full frame rather than in a crop, so that the body's
position and heading are those of the real camera:
1. Pelvis depth from the person's LiDAR points: the median depth of those on the torso (the chest or
   back; all of them when the torso has too few), pushed back by the body's half depth along the ray.
   Without points, from ground contact when the ground plane is known and an ankle is seen: the ray
   through the lower ankle meets the plane (raised by the ankle's height) where the person stands, a
   depth as good as the ground plane at any range; and from the pixel height of the torso and of the
   bounding box and the focal length, for an assumed body size: the nearest of these (`estimate_depth`).
   Points far nearer than all of these put the person are an occluder's (`points_too_near`), unless the
   keypoints show a crouch, which makes every one of these cues read about twice as far. The
   pelvis is then back-projected through the hip midpoint, or placed a torso below the shoulders when
   the hips are not seen (`pelvis_position`).
2. Upright root orientation (up: the ground plane's normal when known, else camera up = −y) turned by
   each heading hypothesis of `fitting.heading` (2D left/right order and foreshortening, the LiDAR's
   torso direction, never the face alone).
3. Limbs: a short fit of pose, orientation and position to the keypoints, the points and the depth of
   the points that hit each limb (`fitting.limbs`), with the anatomical priors only, from every
   hypothesis, standing and, for the first headings, with flexed legs where a thigh is seen, or the
   knees and the points can tell (`flexed_legs_tried`), and, for people with points, bent over at the
   hips (`pitched_root_orient`): by a fixed pitch, and by the pitch and heading whose trunk projects onto
   the image's hips-to-shoulders line (`image_trunk_start`); the full objective picks the hypothesis
   (`fitter.Fitter._refine_builtin`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from smplify3d_ros.camera import pinhole_pixels
from smplify3d_ros.fitting.config import InitConfig
from smplify3d_ros.fitting.heading import TORSO, estimate_heading, torso_points
from smplify3d_ros.keypoints import BODY_PARTS, KP
from smplify3d_ros.types import PersonObservation

CAMERA_UP = np.array([0.0, -1.0, 0.0])
HEAD = list(BODY_PARTS["head"])
ANKLES = [KP["left_ankle"], KP["right_ankle"]]


def _confident(kp: np.ndarray, names: tuple[str, ...], conf: float) -> bool:
    return all(kp[KP[n], 2] >= conf for n in names)


def _mid(kp: np.ndarray, a: str, b: str) -> np.ndarray:
    return 0.5 * (kp[KP[a], :2] + kp[KP[b], :2])


def _ray(K: np.ndarray, uv: np.ndarray) -> np.ndarray:
    return np.array([(uv[0] - K[0, 2]) / K[0, 0], (uv[1] - K[1, 2]) / K[1, 1], 1.0])


def ground_depth(obs: PersonObservation, K: np.ndarray, cfg: InitConfig) -> float | None:
    """Depth (camera z) where the ray through the lower confident ankle meets the ground plane raised by
    the ankle's height; None without a plane, an ankle, or a hit in front of the camera."""
    if obs.ground is None:
        return None
    normal, offset = np.asarray(obs.ground[:3], np.float64), float(obs.ground[3])
    # a guessed ankle is no use: at 10 m a low camera sees the ground so obliquely that a pixel is 0.5 m
    ankles = [KP[n] for n in ("left_ankle", "right_ankle") if obs.keypoints[KP[n], 2] >= cfg.limb_keypoint_conf]
    if not ankles:
        return None
    lower = max(ankles, key=lambda k: obs.keypoints[k, 1])  # the foot on the ground is the lower one
    ray = _ray(K, obs.keypoints[lower, :2])
    along = float(normal @ ray)
    if along >= -1e-6:  # the ray does not go down to the plane
        return None
    t = (cfg.ankle_height - offset) / along  # height(t·ray) = n·(t·ray) + d = ankle height
    return float(t) if t > 0 else None


def size_depths(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, whole_body: bool) -> list[float]:
    """Depths (m, camera z) that the person's size in the image gives for the assumed body: ground contact
    (`ground_depth`), the torso's pixel height for `torso_height`, and the keypoint box's height for
    `body_height`. Each is an upper bound, give or take the person's own size: foreshortening (a torso
    bent over), a raised foot and a hidden part only shrink a length in the image, and so move its depth
    away. `whole_body` (the bounds of `nearest_depth`): instead of the box, the span from the highest
    head keypoint to the lowest ankle for `head_ankle_fraction` x `body_height`, and only when both are
    seen (else a hidden body part makes it a guess, not a bound). The box also holds arms raised above
    the head: a person reaching up 5.4 m out had a box 25 % taller than their head-to-ankle span, which
    let an object 2.55 m in front of them pass for them (Ouster-64 tuning seed 39; docs/benchmarks.md,
    "Depth without the LiDAR, and points that are not the person's"). Nor is ground contact through a
    lone ankle a bound on its own: it may be the foot in the air, which reads twice as far or more from a
    low camera (a walker 2.2 m out read 4.5 m and lost their 223 points as an occluder's); beside another
    cue the nearest of them still is (docs/benchmarks.md, "A lone ankle")."""
    ground = ground_depth(obs, K, cfg)
    depths = [] if ground is None else [ground]
    kp = obs.keypoints
    f = 0.5 * (K[0, 0] + K[1, 1])
    if _confident(kp, TORSO, cfg.keypoint_conf):
        torso_px = np.linalg.norm(_mid(kp, "left_shoulder", "right_shoulder") - _mid(kp, "left_hip", "right_hip"))
        if torso_px > 1.0:
            depths.append(float(f * cfg.torso_height / torso_px))
    if not whole_body:
        depths.append(float(f * cfg.body_height / max(float(obs.bbox[3] - obs.bbox[1]), 1.0)))
        return depths
    seen = kp[:, 2] >= cfg.keypoint_conf
    head, ankles = [i for i in HEAD if seen[i]], [i for i in ANKLES if seen[i]]
    if head and ankles:
        span = float(kp[ankles, 1].max() - kp[head, 1].min())
        depths.append(float(f * cfg.head_ankle_fraction * cfg.body_height / max(span, 1.0)))
    lone_ankle = not _confident(kp, ("left_ankle", "right_ankle"), cfg.limb_keypoint_conf)
    if ground is not None and len(depths) == 1 and lone_ankle:
        return []  # ground contact through the one ankle seen, alone: it may be the foot in the air
    return depths


def thigh_seen(obs: PersonObservation, cfg: InitConfig) -> bool:
    """Whether the keypoints show a thigh (a hip and its knee at `limb_keypoint_conf`): only then can the
    objective tell a flexed-leg start from a standing one; with the legs hidden, nothing but the priors
    decides between them (docs/benchmarks.md, "Flexed-leg starts")."""
    kp = obs.keypoints
    return any(min(kp[KP[f"{side}_hip"], 2], kp[KP[f"{side}_knee"], 2]) >= cfg.limb_keypoint_conf
               for side in ("left", "right"))


def flexed_legs_tried(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, use_points: bool,
                      depth: float) -> bool:
    """Whether the flexed-leg starts join the standing ones: where the keypoints show a thigh
    (`thigh_seen`), or, without one, where they show both knees (at `limb_keypoint_conf`), the person has
    LiDAR points (`use_points`) and stands at least `flexed_leg_min_px` tall in the image at the
    initializer's `depth` (f·`body_height`/depth). A crouching or kneeling person's hips are often scored
    low (the thighs hide them) while the knees are seen, and the points then tell the two starts apart. A
    hidden knee leaves the leg to the priors (two walkers with a knee hidden, on tuning seeds at 2-8 m,
    went 26 and 43 mm further off with the flexed starts tried), and a small, far person's points and
    keypoints cannot tell (a side-on walker 12 m out on bags/far kept a flexed start turned the wrong
    way); docs/benchmarks.md, "Flexed-leg starts"."""
    if thigh_seen(obs, cfg):
        return True
    knees_seen = all(obs.keypoints[KP[f"{side}_knee"], 2] >= cfg.limb_keypoint_conf for side in ("left", "right"))
    if not (knees_seen and use_points) or cfg.flexed_leg_min_px <= 0 or not depth > 0:
        return False
    return 0.5 * float(K[0, 0] + K[1, 1]) * cfg.body_height / depth >= cfg.flexed_leg_min_px


def predicted_depth(obs: PersonObservation) -> float | None:
    """The depth at which a tracked person's track expects their pelvis (None: untracked)."""
    if obs.predicted_pelvis is not None and np.isfinite(obs.predicted_pelvis[2]) and obs.predicted_pelvis[2] > 0:
        return float(obs.predicted_pelvis[2])
    return None


def few_points_depth(obs: PersonObservation, K: np.ndarray, cfg: InitConfig) -> float | None:
    """The pelvis depth that a person's points give when they are too few to be trusted on their own
    (under `fitting.min_points_depth`) but the image agrees with them: it lies no farther than
    `few_points_max_ratio` x the nearest `size_depths`, each an upper bound for a partly hidden person
    (whose box and torso shrink in the image) up to its own noise: a torso 25 px tall 10 m out reads 4 %
    off per pixel, and a person hidden behind another 10.1 m out, with two points of their own there,
    read 9.8 m on their nearest cue. Points beyond it contradict the image: another person's, or the
    background seen past the body. (Points far nearer, an occluder's, are dropped before:
    `points_too_near`.) None otherwise."""
    if len(obs.points) == 0 or cfg.few_points_max_ratio <= 0.0:
        return None
    depth = float(np.median(obs.points[:, 2])) + cfg.lidar_surface_offset
    return depth if depth <= cfg.few_points_max_ratio * min(size_depths(obs, K, cfg, whole_body=False)) else None


def estimate_depth(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, use_points: bool) -> float:
    """Depth (m, camera z) of the pelvis (module docstring). With points, they decide: even a handful
    (`fitting.min_points_depth`) measured the depth within centimetres for 9 of 11 barely seen people
    in our scenes, where ground contact was off by up to 1.8 m (from a camera 0.4 m above the floor the
    ground is seen so obliquely that a pixel of ankle error is 5 % of the depth) and the torso's pixel
    height by up to 8 m (a partly hidden torso). Without points, the nearest of `size_depths`: each cue
    fails by putting the person too far (a bent torso, a raised ankle, a hidden leg), so the nearest is
    the one that failed least. Measured on the robot scenes of tuning seeds 0-79 (166 people): ground
    contact first (as before) was more than 30 % off for 35 people, the nearest cue for 6, and never
    more than 50 % off. A hidden part or a crouch can still put that cue twice as far as the person; the
    scan's bound (`scan_depth_bound`) caps it."""
    if use_points and len(obs.points):
        chest = torso_points(obs.keypoints, K, obs.points, cfg)
        points = chest if len(chest) >= cfg.lidar_heading_min_points else obs.points
        return float(np.median(points[:, 2])) + cfg.lidar_surface_offset
    predicted = predicted_depth(obs)
    if predicted is not None:
        return predicted  # a tracked person: where their track, points and all, expects them
    few = few_points_depth(obs, K, cfg)
    if few is not None:
        return few
    depth = min(size_depths(obs, K, cfg, whole_body=False))
    bound = _accepted_bound(obs, K, cfg)
    return depth if bound is None else min(depth, bound)


def scan_depth_bound(obs: PersonObservation, K: np.ndarray, cfg: InitConfig) -> float | None:
    """The scan's `depth_bound` on a person whose start takes its depth from the size cues (no track
    prediction, no few points the image agrees with: `estimate_depth`'s last case), None otherwise or
    where `_accepted_bound` refuses it."""
    if predicted_depth(obs) is not None or few_points_depth(obs, K, cfg) is not None:
        return None
    return _accepted_bound(obs, K, cfg)


def _accepted_bound(obs: PersonObservation, K: np.ndarray, cfg: InitConfig) -> float | None:
    """`obs.depth_bound`, None where there is none or where it lies nearer than `nearest_depth`: then
    the keypoints were guessed on an occluder in front, whose returns they are (as points that near are
    an occluder's, `points_too_near`)."""
    bound = obs.depth_bound
    if bound is None or not np.isfinite(bound) or bound < nearest_depth(obs, K, cfg):
        return None
    return float(bound)


def depth_from_few_points(obs: PersonObservation, K: np.ndarray, cfg: InitConfig) -> bool:
    """Whether `estimate_depth`, for a person with fewer than `fitting.min_points_depth` points, took the
    depth from those points (`few_points_depth`) rather than from a track's prediction or the size cues."""
    return predicted_depth(obs) is None and few_points_depth(obs, K, cfg) is not None


def nearest_depth(obs: PersonObservation, K: np.ndarray, cfg: InitConfig) -> float:
    """The depth (m) nearer than which the person's points cannot lie: `points_min_depth_ratio` x the
    nearest whole-body `size_depths`, since no foreshortening shrinks every length of a body that much,
    when at least `points_min_depth_cues` of them are known (NaN: no bound): one alone can be off more
    than twofold (ground contact through an ankle guessed behind an occluder, or lifted off the ground;
    the torso of a person bent over). No bound either for a person whose keypoints show a crouch
    (`crouched`, by `crouch_thigh_ratio`): all their cues read about twice as far at once. The
    extraction passes over clusters nearer than this, the fitter drops points nearer (`points_too_near`)."""
    if cfg.points_min_depth_ratio <= 0.0 or (
            cfg.crouch_thigh_ratio > 0 and crouched(obs.keypoints, cfg.keypoint_conf, cfg.crouch_thigh_ratio)):
        return float("nan")  # off, or a crouching body, every size cue of which reads about twice as far
    depths = size_depths(obs, K, cfg, whole_body=True)
    if len(depths) < cfg.points_min_depth_cues:
        return float("nan")
    return cfg.points_min_depth_ratio * min(depths)


def crouched(kp: np.ndarray, conf: float, ratio: float) -> bool:
    """Whether a leg the keypoints show (hip, knee and ankle at `conf`) has a thigh shorter in the image
    than `ratio` x its shin, down the image: a thigh turned towards the camera, a crouching person's."""
    for side in ("left", "right"):
        hip, knee, ankle = (kp[KP[f"{side}_{j}"]] for j in ("hip", "knee", "ankle"))
        if min(hip[2], knee[2], ankle[2]) >= conf and ankle[1] - knee[1] > 1.0:
            if knee[1] - hip[1] < ratio * (ankle[1] - knee[1]):
                return True
    return False


def points_too_near(obs: PersonObservation, K: np.ndarray, cfg: InitConfig) -> bool:
    """Whether the person's points lie nearer than `nearest_depth`: they belong to an occluder in front
    (a box at 2 m taken for a person at 8 m whose keypoints show above it)."""
    return len(obs.points) > 0 and bool(float(np.median(obs.points[:, 2])) < nearest_depth(obs, K, cfg))


def pelvis_position(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, depth: float,
                    up: np.ndarray | None = None) -> np.ndarray:
    """Where the upright start's hip midpoint goes (camera frame, m) at `depth`: on the ray through the
    hips when both are confident; else `torso_height` below the confident shoulders at that depth, along
    the world's `up` (default: camera up), across the image at their midpoint (one shoulder alone: the
    box's centre); else on the ray through the box's centre. (A point 60 % of the way from the shoulders
    to the bottom of the box, the rule before, put a person whose legs something hides as high as their
    elbows: the keypoint box ends where the confident keypoints do.)"""
    kp = obs.keypoints
    if _confident(kp, ("left_hip", "right_hip"), cfg.keypoint_conf):
        return _ray(K, _mid(kp, "left_hip", "right_hip")) * depth
    centre = np.array([0.5 * (obs.bbox[0] + obs.bbox[2]), 0.5 * (obs.bbox[1] + obs.bbox[3])])
    shoulders = [KP[n] for n in ("left_shoulder", "right_shoulder") if kp[KP[n], 2] >= cfg.keypoint_conf]
    if not shoulders:
        return _ray(K, centre) * depth
    uv = kp[shoulders, :2].mean(axis=0) if len(shoulders) == 2 else np.array([centre[0], kp[shoulders[0], 1]])
    up = CAMERA_UP if up is None else np.asarray(up, np.float64) / np.linalg.norm(up)
    return _ray(K, uv) * depth - cfg.torso_height * up


def upright_root_orient(yaw: float, up: np.ndarray | None = None) -> np.ndarray:
    """Axis-angle of the canonical body (x left, y up, z forward) standing upright in the camera frame,
    turned by `yaw` about the vertical (0: facing the camera along −z). `up`: the world's up in the
    camera frame (default: a level camera, −y)."""
    forward = np.array([np.sin(yaw), 0.0, -np.cos(yaw)])
    R = _frame(CAMERA_UP, forward)
    if up is not None:  # tilt the level frame so that its up is `up`
        up = np.asarray(up, np.float64) / np.linalg.norm(up)
        tilt, _ = Rotation.align_vectors(up[None], CAMERA_UP[None])
        R = tilt.as_matrix() @ R
    return Rotation.from_matrix(R).as_rotvec()


def pitched_root_orient(root_orient: np.ndarray, pitch: float) -> np.ndarray:
    """`root_orient` (axis-angle) with the body pitched forward by `pitch` (rad) about its own left axis
    (canonical x): the upper body leans towards where the person faces, the pelvis with it."""
    return (Rotation.from_rotvec(root_orient) * Rotation.from_rotvec([pitch, 0.0, 0.0])).as_rotvec()


@dataclass
class TrunkStart:
    """A bent start read from the image (`image_trunk_start`)."""

    root_orient: np.ndarray  # (3,) axis-angle, the upright heading's pitched forward by `pitch_deg`
    pelvis: np.ndarray  # (3,) camera frame, m
    pitch_deg: float  # forward pitch of the pelvis, deg; the start pose flexes the hips as much


def image_trunk_start(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, roots: list[np.ndarray],
                      pelvis: np.ndarray) -> TrunkStart | None:
    """The bent start whose trunk (hips to shoulders, `torso_height` long) projects closest to the
    image's: over each heading hypothesis (`roots`, upright) and each pitch from 0 to
    `image_trunk_max_pitch_deg` in `image_trunk_pitch_step_deg` steps, the one whose trunk vector (px)
    lies nearest the keypoints' hips-to-shoulders one. A trunk horizontal in the image is a person side-on
    bent over, leaning the way they face, which picks the heading.

    A trunk short in the image (under `image_trunk_short_ratio` x an upright one's length there) is bent
    towards the camera or away from it, which the image alone cannot tell. Where the points around the
    shoulders' pixel lie at least `image_trunk_min_rise_m` nearer or deeper than those around the hips'
    (`_points_rise`), only trunks bent that way are read, and none shallower than that difference. It
    is a lower bound, not a measure: the hips of a trunk bent towards the camera hide behind it, and
    their pixel's points lie on the trunk. A smaller difference says nothing (a person side-on, bent over
    7.9 m out, read 5 cm); over a trunk the image sees at length, it reads the arms and the background as
    much as the trunk (a person side-on, bent over 5.8 m out, read 0.2 m deeper at the shoulders, whose
    were 0.1 m nearer).

    The pelvis depth (`pelvis`, the upright starts') came from the torso's points (the bent starts are
    for people with points), which lie around the middle of the trunk, not over the pelvis: the start's
    pelvis moves along its ray by as much as the pitched trunk's middle moved in depth from the upright
    one's. None where both hips or both shoulders are not confident (`keypoint_conf`), where an upright
    trunk would stand less than `image_trunk_min_px` tall (a pixel of keypoint noise turns it by several
    degrees: a person bent over 13.7 m out, 12 px, was read side-on and fitted 123 mm off, 69 mm
    without), where the reading is pitched less than `image_trunk_min_pitch_deg` (upright people whose
    trunks look short, a child's or a turned one's, read 20-45 deg on tuning seeds 0-79, people bending
    over 59-95 deg), or with `image_trunk_max_pitch_deg` 0.

    Measured on the people bending over of seeds first run on 2026-12-07 (VLP-16, 2-8 m): a person bent
    towards the camera 2.6 m out was fitted 293 mm off (MPJPE) from the fixed 55 deg start, 29 mm from
    this one; two side-on, 204 -> 43 and 184 -> 64 mm (docs/benchmarks.md, "A bent start read from the
    image")."""
    kp = obs.keypoints
    if cfg.image_trunk_max_pitch_deg <= 0.0 or not (
            _confident(kp, ("left_hip", "right_hip"), cfg.keypoint_conf)
            and _confident(kp, ("left_shoulder", "right_shoulder"), cfg.keypoint_conf)):
        return None
    pelvis = np.asarray(pelvis, np.float64)
    if not roots or not (np.isfinite(pelvis).all() and pelvis[2] > 0.0):
        return None
    hips, shoulders = _mid(kp, "left_hip", "right_hip"), _mid(kp, "left_shoulder", "right_shoulder")
    observed = shoulders - hips
    upright_px = K[0, 0] * cfg.torso_height / max(float(pelvis[2]), 1e-3)
    if upright_px < cfg.image_trunk_min_px:
        return None
    rise = None
    if np.linalg.norm(observed) < cfg.image_trunk_short_ratio * upright_px:
        rise = _points_rise(obs, K, hips, shoulders, cfg)
        if rise is not None and abs(rise) < cfg.image_trunk_min_rise_m:
            rise = None
    # every (heading hypothesis, pitch): the trunk's direction in the camera frame, cos(pitch) x the
    # upright body's up + sin(pitch) x its forward
    frames = np.stack([Rotation.from_rotvec(root).as_matrix() for root in roots])  # (H, 3, 3)
    upward, forward = frames[:, :, 1], frames[:, :, 2]
    pitches = np.radians(np.arange(0.0, cfg.image_trunk_max_pitch_deg + 1e-9, cfg.image_trunk_pitch_step_deg))
    trunk = cfg.torso_height * (np.cos(pitches)[None, :, None] * upward[:, None, :]
                                + np.sin(pitches)[None, :, None] * forward[:, None, :])  # (H, P, 3)
    depth = pelvis[2] - 0.5 * (trunk[..., 2] - cfg.torso_height * upward[:, None, 2])  # its middle held
    at = pelvis * (np.maximum(depth, 1e-3) / pelvis[2])[..., None]
    top = at + trunk
    ok = (depth > 0.0) & (top[..., 2] > 0.0)
    if rise is not None:
        ok &= trunk[..., 2] * rise >= 0.0  # bent the way the points say, towards the camera or away
    shown = (pinhole_pixels(top, K) - pinhole_pixels(at, K)).reshape(*ok.shape, 2)  # the trunk's vector, px
    cost = np.hypot(shown[..., 0] - observed[0], shown[..., 1] - observed[1])
    if rise is not None:  # and no shallower than they say, in pixels at the pelvis
        cost = np.hypot(cost, K[0, 0] * np.maximum(0.0, abs(rise) - np.abs(trunk[..., 2])) / at[..., 2])
    cost = np.where(ok, cost, np.inf)
    y, p = np.unravel_index(int(np.argmin(cost)), cost.shape)
    if not np.isfinite(cost[y, p]) or np.degrees(pitches[p]) < cfg.image_trunk_min_pitch_deg:
        return None
    return TrunkStart(pitched_root_orient(roots[y], float(pitches[p])), at[y, p], float(np.degrees(pitches[p])))


def _points_rise(obs: PersonObservation, K: np.ndarray, hips: np.ndarray, shoulders: np.ndarray,
                 cfg: InitConfig) -> float | None:
    """How much deeper (m, camera z) the person's points around the shoulders' pixel lie than those around
    the hips' (the median of each, within `image_trunk_points_radius` x the box's height of the pixel;
    None with fewer than two around either): a trunk bent towards the camera reads negative."""
    if len(obs.points) == 0:
        return None
    points = np.asarray(obs.points, np.float64)
    uv = pinhole_pixels(points, K)
    radius = cfg.image_trunk_points_radius * float(obs.bbox[3] - obs.bbox[1])
    near_shoulders = np.linalg.norm(uv - shoulders, axis=1) <= radius
    near_hips = np.linalg.norm(uv - hips, axis=1) <= radius
    if near_shoulders.sum() < 2 or near_hips.sum() < 2:
        return None
    return float(np.median(points[near_shoulders, 2]) - np.median(points[near_hips, 2]))


def _frame(up: np.ndarray, forward: np.ndarray) -> np.ndarray:
    left = np.cross(up, forward)
    return np.stack([left, up, forward], axis=1)


def builtin_hypotheses(obs: PersonObservation, K: np.ndarray, cfg: InitConfig, use_points: bool,
                       depth_points: bool) -> list[tuple[np.ndarray, np.ndarray]]:
    """(root_orient (3,), pelvis position (3,)) of each heading hypothesis of the built-in initializer,
    before the limb refinement; the best guess first. `use_points`: the points inform the heading;
    `depth_points`: they give the depth (fewer suffice for that, `fitting.min_points_depth`)."""
    depth = estimate_depth(obs, K, cfg, use_points or depth_points)
    up = None if obs.ground is None else np.asarray(obs.ground[:3], np.float64)
    pelvis = pelvis_position(obs, K, cfg, depth, up)
    heading = estimate_heading(obs.keypoints, K, pelvis, obs.points if use_points else obs.points[:0], cfg)
    return [(upright_root_orient(yaw, up), pelvis) for yaw in heading.hypotheses]
