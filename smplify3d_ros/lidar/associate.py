"""Steps 2, 5 and 6 of person point extraction: skeleton frusta, cluster selection, conflicts.

Everything is measured in metres at the point's own depth: a point's image distance to a skeleton (in
normalized image coordinates, i.e. pixels divided by the focal length) times its depth z is how far,
in metres, it passes beside that skeleton. One `mask_radius_m` thus serves every distance, and a wall
far behind a person needs to project much closer to the skeleton than the person's own points do.

Selection (step 5). For each person k and cluster j we count the cluster's points inside k's padded
bbox (`in_box`), in the bbox's surroundings (`in_context`, `context_pad` further out; clustered, never
assigned), inside k's body mask (`in_mask`: within `mask_radius_m` of a skeleton segment) and inside
k's mask only (`exclusive`: no other skeleton's mask covers them). Each mask point belongs to the
body part (`keypoints.BODY_PARTS`) of its nearest segment. The score of "cluster j is person k" is
  (covered parts - refuted parts - hidden_weight x hidden parts) x isolation,
  - covered parts: parts on which j has mask points, counting 1 with an exclusive point and
    `shared_weight` with only points that another skeleton also covers. Counting parts, not points,
    makes the score independent of range: a box in front of the legs is closer, hence denser, than
    the person behind it, but it covers only the legs; the person covers torso, arms and head. A part
    counts fully when its keypoints score at least `coverage_full_score`, in proportion below: a
    detector reports the joints an occluder hides, with low confidence, and there the occluder is what
    fills the mask.
  - refuted parts: a body hides what is behind it, so the skeleton's core (within `core_radius_m`)
    shows the body itself or an occluder in front of it, never the background. A part refutes j when
    its core holds more points of clusters farther than j (by `depth_tolerance_m`) than of j: the
    occluding box is refuted by the torso and head behind it, and so is a person standing in front
    of k by k's own visible parts. "More" means `refute_ratio` times as many: a child's neck or thigh
    is narrower than the core, and keypoint noise moves the core off a thin part, so that a few points
    of the wall seen beside it must not outvote the body's own. Parts wider than the core refute
    (`refuting_parts`) at that ratio; the thinner ones (shins, forearms), beside which the core shows
    some background anyway, at `thin_refute_ratio` with at least `thin_refute_min_votes` points: the
    shin and forearm of a person behind an object that covers their torso and head show the person's
    own points behind it.
  - hidden parts: under hypothesis j, a torso or head (`hidden_parts`) whose core holds `refute_ratio`
    times more points of clusters nearer than j than of j is hidden by them; yet its keypoints were
    seen. Each weighs `hidden_weight` against j: a patch of wall seen past the shoulder of a person
    merged with the post they lean on is not refuted (the person is in front of it), but it would
    hide their whole body.
  - isolation: how much j stands out from a surface seen through the bbox, the larger of
      purity: in_mask / in_box is 1 for a body (it fills its mask, not the bbox around it), and for
        a wall the fraction of the bbox that the mask covers at the wall's depth (`mask_fraction`,
        from a grid of `mask_area_samples`^2 pixels), or less where a body shadows the wall;
      boundedness: in_box / (in_box + in_context) is 1 for an object inside the bbox, and for a
        wall the bbox's share of bbox + surroundings;
    each rescaled so that the wall's value is 0 and 1 stays 1 (purity by no less than
    `purity_min_room`: where the mask covers nearly all of the bbox, as a far person's skeleton does at
    a near object's depth, purity says nothing, and rescaled by the little left it would read as fully
    isolated); a pair needs `min_isolation`, or
    `core_min_isolation` when the cluster has `core_isolation_points` in the core (a person merged with
    the post they lean on stands out only partly, but fills the core). Boundedness rescues a person merged
    with a prop (a seat, a carried box) whose points leave the mask; purity, a person next to a
    large object. Isolation keeps a wall from standing in for a person whom the LiDAR does not see
    (dark clothes, out of range).
  - a surface through the box: far away a ring or two cross a person, and purity no longer tells the
    patch of wall behind them (which the mask covers almost as well) from the body. A body ends at its
    sides; a wall goes on past both, or (the person at its end) far past one. j is a surface when, in
    the bbox's rows, the bands `surface_side_width` x the bbox width to its left and to its right each
    hold at least `surface_ratio` times the bbox's points at j's depth (within `depth_tolerance_m`), or
    one of them `surface_one_side_ratio` times, and at least `surface_min_points`. Points on another
    person's mask do not count: in a crowd the neighbours on both sides stand at one's own depth.
A pair qualifies with a positive score, the isolation it needs (above), no surface through the box, a
plausible skeleton at the cluster's depth (the largest keypoint distance, scaled by the cluster's median depth, at most
`max_person_extent_m`: rejects background far behind) and a cluster depth within the person's depth
range when the caller gives one: for a person whose depth is expected (a track's prediction), within that
expectation's tolerance (a tracked person half hidden behind another keeps their own few points rather
than the wall seen past their shoulder); for anyone, no nearer than their size in the image allows (an
object in front of a person mostly hidden behind it, whose points make a body far too small for the
keypoints). A cluster that
hides the body is nobody's main cluster: one with `occluder_min_points` mask points, none of them in the
core of a segment the detector saw with confidence, while other points lie there, no nearer (an object in front
fills the mask over the joints the detector guessed; where it saw the body, the LiDAR sees the body's own
few points). Pairs are taken greedily by score (a cluster several people qualify for, by score times
(extent / the largest claimant's extent) ** `contest_extent_power`: the one behind looks smaller; equal
scores by more points in the core of the confident segments, `core_tie_break`, then by more mask points);
each person gets one main cluster, and a cluster that is
already someone's main is shared only when enough of the second person's mask points on it are exclusive
(`share_min_exclusive`): two people touching in 3D form one cluster, yet each has their own region of it.
Then a person whose main cluster has no point in that core takes instead the eligible cluster nobody holds
with the most points there, at least `unclaimed_core_points`: a cluster with none there is seen past the body.
People left without a main cluster get a second look (`second_look`) once the others are placed: a placed person's body
hides nothing (what their cluster covers of a torso behind them is them, not a reason against the
person behind), and a placed person holds only the points within `body_depth_window_m` of their own
depth, so points metres behind them count as exclusively the hidden person's; and a part refutes or is
hidden only with at least `second_look_min_votes` points (a VLP-16 ring through a gap puts one wall
point in the core of a part the LiDAR missed). A person half behind another, whose own points all fell
in the front person's mask too, otherwise scored below zero on every cluster and was fitted from the
image alone. Further clusters that
are nobody's main and qualify but for the score join: those within `depth_tolerance_m` of the main
cluster's depth (an arm or the legs split off by a gap or an occluder), then, transitively, those within
`body_depth_window_m` in depth that come within `secondary_link_m` of a joined one (knees or arms in
front of the torso, split off at the body's own depth steps).

Conflicts (step 6). A point goes to the person whose skeleton it projects closest to, among those that
selected its cluster, whose mask holds it and whose depth window (`body_depth_window_m` around the
main cluster's median depth) contains it; so each point has at most one owner, and an occluder's points
inside a farther person's mask stay with the occluder or with nobody.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from smplify3d_ros.keypoints import BODY_PARTS, COCO17_SKELETON, KP, PART_INDEX
from smplify3d_ros.lidar.config import ExtractionConfig
from smplify3d_ros.types import CameraModel

# Segments whose neighbourhood is the body: the drawing skeleton, torso diagonals (the belly) and neck
# lines (nose to shoulders), so that the mask covers the torso and joins the head to it.
BODY_SEGMENTS: tuple[tuple[int, int], ...] = COCO17_SKELETON + (
    (KP["left_shoulder"], KP["right_hip"]),
    (KP["right_shoulder"], KP["left_hip"]),
    (KP["nose"], KP["left_shoulder"]),
    (KP["nose"], KP["right_shoulder"]),
)


def _part_of(a: int, b: int) -> int:
    """The body part a segment belongs to: the part holding both ends, else the part of its start."""
    both = [PART_INDEX[p] for p, ks in BODY_PARTS.items() if a in ks and b in ks]
    return both[0] if both else next(PART_INDEX[p] for p, ks in BODY_PARTS.items() if a in ks)


SEGMENT_PARTS = np.array([_part_of(a, b) for a, b in BODY_SEGMENTS], dtype=np.int64)
KEYPOINT_PARTS = np.array([_part_of(i, i) for i in range(len(KP))], dtype=np.int64)  # lone keypoints


@dataclass
class Skeleton:
    """One person's confident keypoints as line segments, in normalized image coordinates."""

    starts: np.ndarray  # (S, 2) float64 segment starts (zero-length segments for lone keypoints)
    ends: np.ndarray  # (S, 2) float64 segment ends
    parts: np.ndarray  # (S,) int64 index in `keypoints.PART_NAMES` of each segment's body part
    scores: np.ndarray  # (S,) float64 confidence of each segment: the lower of its keypoints' scores
    bbox: np.ndarray  # (4,) float64 padded keypoint bbox x_min, y_min, x_max, y_max, px, undistorted
    context: np.ndarray  # (4,) float64 the bbox grown by `context_pad`: its surroundings, same layout
    extent: float  # largest distance between two confident keypoints, normalized image units


def to_normalized(uv: np.ndarray, camera: CameraModel) -> np.ndarray:
    """(N, 2) undistorted pixels -> normalized image coordinates ((u - cx) / fx, (v - cy) / fy)."""
    K = camera.K
    return (np.asarray(uv, dtype=np.float64) - K[:2, 2]) / np.array([K[0, 0], K[1, 1]])


def person_skeleton(keypoints: np.ndarray, camera: CameraModel, config: ExtractionConfig) -> Skeleton | None:
    """The skeleton of one (17, 3) keypoint set (undistorted px + score), None if too few are confident."""
    finite = np.all(np.isfinite(keypoints), axis=1)
    confident = finite & (np.where(finite, keypoints[:, 2], 0.0) >= config.keypoint_min_score)
    if confident.sum() < config.min_keypoints:
        return None
    uv = keypoints[confident, :2].astype(np.float64)
    lo, hi = uv.min(axis=0), uv.max(axis=0)
    size = max(float(np.max(hi - lo)), 1.0)
    limits = np.array([camera.width - 1.0, camera.height - 1.0])

    def grown(pad: float) -> np.ndarray:
        return np.concatenate([np.clip(lo - pad, 0.0, limits), np.clip(hi + pad, 0.0, limits)])

    bbox = grown(config.bbox_pad * size)
    context = grown((config.bbox_pad + config.context_pad) * size)
    xy = to_normalized(keypoints[:, :2], camera)
    pairs = np.array(BODY_SEGMENTS)
    linked = confident[pairs[:, 0]] & confident[pairs[:, 1]]
    lone = np.flatnonzero(confident)  # every confident keypoint is also a zero-length segment
    starts = np.concatenate([xy[pairs[linked, 0]], xy[lone]])
    ends = np.concatenate([xy[pairs[linked, 1]], xy[lone]])
    parts = np.concatenate([SEGMENT_PARTS[linked], KEYPOINT_PARTS[lone]])
    score = keypoints[:, 2]
    scores = np.concatenate([np.minimum(score[pairs[linked, 0]], score[pairs[linked, 1]]), score[lone]])
    conf_xy = xy[confident]
    extent = float(np.max(np.linalg.norm(conf_xy[:, None] - conf_xy[None], axis=2)))
    return Skeleton(starts, ends, parts, scores, bbox, context, extent)


def score_scale(scores: np.ndarray, config: ExtractionConfig) -> float:
    """How confident the frame's detector is, against one scoring a plainly seen joint `score_level`: the
    upper quartile of every keypoint score of the frame (`scores`, any shape; NaN ignored) over
    `score_level`, at most 1. `refute_min_score` scales by it, so that a detector scoring seen joints
    about 0.65 is read as one scoring them 0.9 is; a more confident one changes nothing. A property of
    the detector, read from everyone in the frame: a person mostly hidden scores most joints low, and
    read alone would let guessed joints refute. (Per person, and scaling `coverage_full_score` too, were
    measured and not taken.)"""
    scores = np.asarray(scores, np.float64).ravel()
    scores = scores[np.isfinite(scores)]
    if config.score_level <= 0 or len(scores) == 0:
        return 1.0
    return float(min(1.0, np.quantile(scores, 0.75) / config.score_level))


def segment_distance(xy: np.ndarray, skeleton: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """(M,) distance of (M, 2) normalized image points to the nearest skeleton segment, and its index."""
    ax, ay = skeleton.starts[:, 0], skeleton.starts[:, 1]
    abx, aby = skeleton.ends[:, 0] - ax, skeleton.ends[:, 1] - ay
    inv_length2 = 1.0 / np.maximum(abx * abx + aby * aby, 1e-18)
    px = xy[:, :1] - ax  # (M, S)
    py = xy[:, 1:] - ay
    t = np.clip((px * abx + py * aby) * inv_length2, 0.0, 1.0)
    px -= t * abx
    py -= t * aby
    d2 = px * px + py * py
    nearest = np.argmin(d2, axis=1)
    return np.sqrt(d2[np.arange(len(xy)), nearest]), nearest


def _area(bbox: np.ndarray) -> float:
    return float(max(bbox[2] - bbox[0], 0.0) * max(bbox[3] - bbox[1], 0.0))


def in_bbox(uv: np.ndarray, bbox: np.ndarray) -> np.ndarray:
    """(N,) bool: pixel inside bbox x_min, y_min, x_max, y_max (NaN is outside)."""
    with np.errstate(invalid="ignore"):
        return (uv[:, 0] >= bbox[0]) & (uv[:, 0] <= bbox[2]) & (uv[:, 1] >= bbox[1]) & (uv[:, 1] <= bbox[3])


def _grouped_median(groups: np.ndarray, values: np.ndarray, n_groups: int) -> np.ndarray:
    """(n_groups,) median of `values` per group id (lower median; NaN for empty groups)."""
    out = np.full(n_groups, np.nan)
    if len(groups) == 0:
        return out
    order = np.lexsort((values, groups))
    groups, values = groups[order], values[order]
    starts = np.flatnonzero(np.r_[True, groups[1:] != groups[:-1]])
    counts = np.diff(np.r_[starts, len(groups)])
    out[groups[starts]] = values[starts + (counts - 1) // 2]
    return out


def _contradicted_parts(
    z: np.ndarray, clusters: np.ndarray, parts: np.ndarray, hypotheses: np.ndarray,
    hypothesis_depth: np.ndarray, own_core: np.ndarray, config: ExtractionConfig,
    can_hide: np.ndarray | None = None, min_votes: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """(H,) for each hypothesis "cluster j is this person": body parts that refute it, and parts that
    it would have hidden.

    A body hides what is behind it, so the skeleton's core (points within `core_radius_m`) shows the
    body itself or an occluder in front of it, never the background. A part refutes hypothesis j when
    its core holds `refute_ratio` times more points of other clusters farther than j (by
    `depth_tolerance_m`) than of j, if it is one of the `refuting_parts`, those wider than the core
    (torso, head, thighs); the others, beside which the core already shows some of what is behind,
    refute at `thin_refute_ratio` (0: never) with `thin_refute_min_votes`. Only segments
    whose keypoints score at least `refute_min_score` (times the frame's `score_scale`: a less
    confident detector), since a guessed joint puts the core beside the body. One of the
    `hidden_parts` (torso, head) is hidden under hypothesis j when its core holds that many times more
    points of clusters nearer than j: j can still be the person (someone half behind another), but
    those keypoints were seen with confidence, so each weighs `hidden_weight` against j.
    Legs are not counted: a detector reports legs behind a box with confidence (hallucinated).
    z, clusters, parts: depth, cluster and body part of the person's core points; own_core: (H, parts)
    core points of each hypothesis cluster per part; can_hide: optional (n,) bool, the core points that
    count as hiding a part (default: all); min_votes: the fewest points that refute or hide a part.
    """
    if len(hypotheses) == 0 or len(z) == 0:
        return np.zeros(len(hypotheses)), np.zeros(len(hypotheses))
    other = clusters[None, :] != hypotheses[:, None]
    behind = (z[None, :] > hypothesis_depth[:, None] + config.depth_tolerance_m) & other
    before = (z[None, :] < hypothesis_depth[:, None] - config.depth_tolerance_m) & other
    if can_hide is not None:
        before &= can_hide[None, :]
    one_hot = np.eye(own_core.shape[1])[parts]  # (n, parts)

    def outvoted(selection: np.ndarray, part_names: list[str], ratio: float, least: int) -> np.ndarray:
        counted = np.isin(np.arange(own_core.shape[1]), [PART_INDEX[p] for p in part_names])
        votes = selection.astype(np.float64) @ one_hot
        return ((votes > ratio * own_core) & (votes >= least) & counted).sum(axis=1)

    refuted = outvoted(behind, config.refuting_parts, config.refute_ratio, min_votes)
    if config.thin_refute_ratio > 0:
        thin = [p for p in PART_INDEX if p not in config.refuting_parts]
        refuted += outvoted(behind, thin, config.thin_refute_ratio, max(min_votes, config.thin_refute_min_votes))
    return refuted, outvoted(before, config.hidden_parts, config.refute_ratio, min_votes)


def mask_fraction(
    skeleton: Skeleton, depth: np.ndarray, camera: CameraModel, config: ExtractionConfig
) -> np.ndarray:
    """(H,) fraction of the skeleton's bbox that its mask covers for a surface at each depth (m)."""
    n = config.mask_area_samples
    x0, y0, x1, y1 = skeleton.bbox
    u, v = np.meshgrid(np.linspace(x0, x1, n), np.linspace(y0, y1, n))
    grid = segment_distance(to_normalized(np.column_stack([u.ravel(), v.ravel()]), camera), skeleton)[0]
    grid.sort()
    with np.errstate(divide="ignore", invalid="ignore"):
        limit = np.where(depth > 0, config.mask_radius_m / depth, 0.0)
    return np.searchsorted(grid, np.nan_to_num(limit), side="right") / len(grid)


def _isolation(fraction_in: np.ndarray, uniform_fraction: np.ndarray, min_room: float = 1e-6) -> np.ndarray:
    """0 where points fall inside a region as often as on a uniform surface, 1 where all do, if the region
    leaves `min_room` of the surface outside it (less: in proportion, a region covering all tells nothing)."""
    return (fraction_in - uniform_fraction) / np.maximum(1.0 - uniform_fraction, min_room)


def _part_weights(skeletons: list[Skeleton | None], n_parts: int, config: ExtractionConfig) -> np.ndarray:
    """(P, parts) what covering each body part is worth: 1 for a part whose best segment scores at
    least `coverage_full_score`, in proportion below (a detector reports the joints an occluder hides
    with low confidence, and the occluder is what fills the mask there)."""
    weights = np.zeros((len(skeletons), n_parts))
    for k, skeleton in enumerate(skeletons):
        if skeleton is not None:
            np.maximum.at(weights[k], skeleton.parts, np.minimum(skeleton.scores / config.coverage_full_score, 1.0))
    return weights


def _surface_through(g: _Geometry, z: np.ndarray, depth: np.ndarray, config: ExtractionConfig) -> np.ndarray:
    """(P, C) bool: at cluster j's depth, the surface seen in person k's bbox goes on past its sides."""
    surface = np.zeros(depth.shape, dtype=bool)
    for k in range(len(depth)):
        hypotheses = np.flatnonzero(np.isfinite(depth[k]))
        if len(hypotheses) == 0:
            continue
        levels = depth[k, hypotheses, None]
        inside, left, right = (
            (np.abs(z[region][None, :] - levels) <= config.depth_tolerance_m).sum(axis=1)  # (H,) at each depth
            for region in (g.box[k], g.left[k], g.right[k])
        )
        both = np.minimum(left, right) >= np.maximum(config.surface_ratio * inside, config.surface_min_points)
        one = np.maximum(left, right) >= np.maximum(
            config.surface_one_side_ratio * inside, config.surface_min_points
        )
        surface[k, hypotheses] = both | one
    return surface


def _main_clusters(
    counts: dict[str, np.ndarray], coverage: np.ndarray, contradicted: np.ndarray,
    mask_cover: np.ndarray, box_fraction: np.ndarray, depth: np.ndarray, extent: np.ndarray,
    surface: np.ndarray, config: ExtractionConfig, depth_range: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) main cluster per person (-1: none) and (P, C) bool clusters that may be part of a body.

    counts: (P, C) points of each cluster "in_box", "in_context" (around the box), "in_mask",
    "exclusive"; coverage: (P, C) weighted count of body parts covered; contradicted: (P, C) parts
    whose core shows more of something behind the cluster than of the cluster, plus `hidden_weight` x
    those whose core shows more of something in front of it; mask_cover: (P, C)
    fraction of the bbox the mask covers at the cluster's depth; box_fraction: (P,) the bbox's share
    of bbox + context; depth: (P, C) median depth of the mask points; extent: (P,) skeleton size;
    surface: (P, C) a surface at the cluster's depth goes on past the sides of the bbox;
    depth_range: optional (P, 2) nearest and farthest depth of each person's main cluster (NaN: unbounded).
    """
    score, body_like = _qualify(counts, coverage, contradicted, mask_cover, box_fraction, depth, extent,
                                surface, config, depth_range)
    eligible = body_like & ~_barred(counts, config)
    main, owners = _assign(score, eligible, counts, config, extent=extent)
    main, owners = _unclaimed_core(main, owners, score, eligible, counts, config)
    body_like[:, owners > 0] = False  # someone's main cluster is nobody's extra
    return main, body_like


def _qualify(
    counts: dict[str, np.ndarray], coverage: np.ndarray, contradicted: np.ndarray,
    mask_cover: np.ndarray, box_fraction: np.ndarray, depth: np.ndarray, extent: np.ndarray,
    surface: np.ndarray, config: ExtractionConfig, depth_range: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(P, C) score of each (person, cluster) pair and whether the cluster may be part of that body
    (`_main_clusters` has the arguments)."""
    in_box, in_mask = counts["in_box"], counts["in_mask"]
    purity = _isolation(in_mask / np.maximum(in_box, 1), mask_cover, config.purity_min_room)
    bounded = _isolation(in_box / np.maximum(in_box + counts["in_context"], 1), box_fraction[:, None])
    isolation = np.maximum(purity, bounded)
    score = (coverage - contradicted) * isolation
    with np.errstate(invalid="ignore"):
        plausible = extent[:, None] * depth <= config.max_person_extent_m
        if depth_range is not None:  # NaN: no constraint
            plausible &= ~(depth < depth_range[:, :1]) & ~(depth > depth_range[:, 1:])
        body_like = (in_mask > 0) & plausible & (isolation >= _min_isolation(counts, config)) & ~surface
    return score, body_like


def _min_isolation(counts: dict[str, np.ndarray], config: ExtractionConfig) -> np.ndarray:
    """(P, C) the isolation each cluster needs: `min_isolation`, or `core_min_isolation` for a cluster
    with `core_isolation_points` points in the core of the confident segments. A wall seen where the
    LiDAR misses a person does not stand out from the wall around it (isolation about 0) however many
    of its points fall in the core; a person merged with the post they lean against stands out partly
    (the post fills the box beside the body and leaves it at the top: 0.3-0.4, tuning seed 29 at
    2-8 m), and their own points fill the skeleton's core."""
    needed = np.full(counts["core"].shape, config.min_isolation)
    if config.core_isolation_points > 0:
        needed[counts["core"] >= config.core_isolation_points] = min(config.core_min_isolation, config.min_isolation)
    return needed


def _barred(counts: dict[str, np.ndarray], config: ExtractionConfig) -> np.ndarray:
    """(P, C) bool: clusters that may not be the person's main cluster, on the first look and the second:
    an object hiding the body (`_hides_the_body`), or a cluster seen past it (`_outshone`)."""
    return _hides_the_body(counts, config) | _outshone(counts, config)


def _hides_the_body(counts: dict[str, np.ndarray], config: ExtractionConfig) -> np.ndarray:
    """(P, C) bool: the cluster has `occluder_min_points` mask points, none of them in the core of a
    segment the detector saw with confidence, while other points lie there at or behind its depth. Where
    the detector saw the body the LiDAR sees something farther: the cluster covers only the joints it
    guessed, i.e. it hides them. It may not be the person's main cluster (an arm split off the body may
    still join one). Core points nearer than the cluster do not count: an object in front hides the
    core from the body, whose cluster then has no core points of its own (tuning seed 242 at 2-8 m)."""
    if config.occluder_min_points <= 0:
        return np.zeros(counts["in_mask"].shape, dtype=bool)
    return (counts["in_mask"] >= config.occluder_min_points) & (counts["core"] == 0) & (counts["core_behind"] > 0)


def _outshone(counts: dict[str, np.ndarray], config: ExtractionConfig) -> np.ndarray:
    """(P, C) bool: the cluster has no point in person k's core while another cluster has
    `outshone_core_points` there. Points that close to the confident segments are the body (or something
    in front of it); a cluster beside them only, none on them, is seen past the body, and may not be its
    main cluster however much of the mask it fills (a person 1.5 m from the camera leaning on an object,
    their cluster merged with it, lost to an object 2 m behind them; tuning seed 118 with a 70° camera).
    It may still join a body as an extra cluster."""
    if config.outshone_core_points <= 0:
        return np.zeros(counts["core"].shape, dtype=bool)
    core = counts["core"]
    return (core == 0) & (core.max(axis=1, keepdims=True) >= config.outshone_core_points)


def _core_behind(core: np.ndarray, z: np.ndarray, depth: np.ndarray, config: ExtractionConfig) -> np.ndarray:
    """(P, C) points in person k's confident core that lie no nearer than cluster j (within
    `depth_tolerance_m`): the body behind an object in front. Points nearer than j are something in front
    of it, which hides the core from a cluster that is the body."""
    out = np.zeros(depth.shape, dtype=np.int64)
    for k in range(len(depth)):
        depths = np.sort(z[core[k]])
        finite = np.isfinite(depth[k])
        out[k, finite] = len(depths) - np.searchsorted(depths, depth[k, finite] - config.depth_tolerance_m)
    return out


def _assign(
    score: np.ndarray, body_like: np.ndarray, counts: dict[str, np.ndarray], config: ExtractionConfig,
    main: np.ndarray | None = None, owners: np.ndarray | None = None, people: np.ndarray | None = None,
    extent: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(P,) main clusters and (C,) how many people hold each cluster as their main: those of `people`
    (default: everyone) taken greedily by score, best first, on top of `main` (-1: none; default: nobody
    has one) and `owners`; a cluster several people still without one qualify for goes first to the one
    who looks larger (`_in_front`, from `extent` (P,), the skeletons' extents). Of equal keys, the pair
    with more points in the core of the person's confident segments goes first (`core_tie_break`), then
    the one with more mask points: points on the segments the camera sees are the body, those beside
    them may be what is seen past it (a woman 13.3 m out scored alike on her own cluster, 7 core points,
    and on the background 1.7 m behind her, 4, and was fitted there with its one more mask point; seed
    578, docs/benchmarks.md, "Equal scores: the cluster on the confident segments")."""
    main = np.full(len(score), -1) if main is None else main.copy()
    owners = np.zeros(score.shape[1], np.int64) if owners is None else owners.copy()
    in_mask, exclusive, core = counts["in_mask"], counts["exclusive"], counts["core"]
    qualified = body_like & (score > 0)
    if people is not None:
        qualified &= np.isin(np.arange(len(score)), people)[:, None]
    people, clusters = np.nonzero(qualified)
    pending = np.ones(len(people), dtype=bool)
    while True:
        live = np.flatnonzero(pending & (main[people] < 0))
        if len(live) == 0:
            break
        k, j = people[live], clusters[live]
        key = score[k, j] * _in_front(k, j, extent, score.shape[1], config.contest_extent_power)
        tie = core[k, j] if config.core_tie_break else np.zeros(len(live))
        best = live[np.lexsort((-in_mask[k, j], -tie, -key))[0]]
        pending[best] = False
        k, j = people[best], clusters[best]
        if owners[j] > 0 and exclusive[k, j] < config.share_min_exclusive * in_mask[k, j]:
            continue
        main[k] = j
        owners[j] += 1
    return main, owners


def _unclaimed_core(
    main: np.ndarray, owners: np.ndarray, score: np.ndarray, eligible: np.ndarray,
    counts: dict[str, np.ndarray], config: ExtractionConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """`main` and `owners` with each person whose main cluster has no point in the core of their
    confident segments moved to the eligible, positively scored cluster nobody holds with the most
    points there, at least `unclaimed_core_points` (0: off). Points on the segments the camera sees are
    the body; a cluster with none there is seen past it. Unused seed 3005's woman 8.0 m out, 18 % seen
    past two nearer people, scored 1.37 on the background 4 m behind her (no core point) and 1.25 on her
    own cluster (8 core points on her shin) and was fitted 4.3 m off. After the assignment, not before:
    a nearer person's cluster fills the core of whoever stands behind them, and it is theirs (with
    `outshone_core_points`, which bars before the assignment, at 5 instead of its 20, a person behind a
    crowd's bystander lost every point to the bystander's cluster)."""
    if config.unclaimed_core_points <= 0:
        return main, owners
    main, owners, core = main.copy(), owners.copy(), counts["core"]
    for k in np.flatnonzero(main >= 0):
        if core[k, main[k]] > 0:
            continue
        free = eligible[k] & (owners == 0) & (score[k] > 0) & (core[k] >= config.unclaimed_core_points)
        if free.any():
            j = int(np.argmax(np.where(free, core[k], -1)))
            owners[main[k]] -= 1
            main[k] = j
            owners[j] += 1
    return main, owners


def _in_front(people: np.ndarray, clusters: np.ndarray, extent: np.ndarray | None, n_clusters: int,
              power: float) -> np.ndarray:
    """(N,) weight of each (person, cluster) pair still open in the order `_assign` takes them: (the
    person's skeleton extent / the largest extent among the open pairs' people on that cluster) ** `power`,
    1 where only one person claims the cluster (or `power` is 0, or no extent is given). A person already
    placed elsewhere claims nothing: on bags/people_anonymous a walker who had taken their own cluster
    still made a passer-by's best cluster look contested, and the passer-by took 2 points instead of 9
    (weighted once for all pairs, before any was taken: MPJPE 51.9 -> 55.4 mm). Two people
    overlapping in the image claim one cluster with the same points; the one behind is mostly hidden and
    looks smaller, so the nearer cluster is more likely the larger one's. With a detector that scores
    hidden joints as seen, a woman 8.6 m out and a man hidden behind her 11.4 m out scored 2.00 and 2.25
    on her cluster, and both were fitted 2.8 m off (tuning seed 239; docs/benchmarks.md, "The larger of
    two claimants in front")."""
    weight = np.ones(len(people))
    if power <= 0.0 or extent is None or len(people) == 0:
        return weight
    size = np.nan_to_num(np.asarray(extent, np.float64), nan=0.0)[people]
    largest = np.zeros(n_clusters)
    np.maximum.at(largest, clusters, size)
    contested = np.bincount(clusters, minlength=n_clusters)[clusters] > 1
    weight[contested] = (size[contested] / np.maximum(largest[clusters[contested]], 1e-12)) ** power
    return weight


def _grow(
    seeds: list[int], candidates: np.ndarray, coords: np.ndarray, clusters: np.ndarray,
    config: ExtractionConfig,
) -> list[int]:
    """The seed clusters and the candidate clusters linked to them through gaps <= `secondary_link_m`.

    coords, clusters: clustering-space coordinates and cluster labels of the person's bbox points. A
    body splits at its own depth steps (knees or arms in front of the torso) into clusters a few
    decimetres apart; an occluder stands farther away (the linking is transitive, cluster to cluster).
    """
    joined = list(seeds)
    pending = [j for j in candidates.tolist() if j not in joined]
    while pending:
        tree = cKDTree(coords[np.isin(clusters, joined)])
        gap, _ = tree.query(coords, distance_upper_bound=config.secondary_link_m)
        reached = set(clusters[np.isfinite(gap)].tolist())
        added = [j for j in pending if j in reached]
        if not added:
            break
        joined += added
        pending = [j for j in pending if j not in reached]
    return joined


@dataclass
class _Geometry:
    """Where each candidate point lies relative to each person's skeleton, (P, M) arrays."""

    box: np.ndarray  # in the person's padded keypoint bbox
    context: np.ndarray  # around the bbox, not in it
    box_fraction: np.ndarray  # (P,) bbox area / context area
    left: np.ndarray  # in the bbox's rows, in the band `surface_side_width` bbox widths to its left
    right: np.ndarray  # ... and to its right
    dist: np.ndarray  # metres beside the skeleton, at the point's depth (inf outside the bbox)
    part: np.ndarray  # body part of the nearest segment
    sure: np.ndarray  # the nearest segment is confident enough to refute
    extent: np.ndarray  # (P,) the skeleton's extent


def _geometry(uv: np.ndarray, z: np.ndarray, skeletons: list[Skeleton | None], camera: CameraModel,
              config: ExtractionConfig, refute_scale: float) -> _Geometry:
    n_people, n_points = len(skeletons), len(uv)
    sure_score = config.refute_min_score * refute_scale
    xy = to_normalized(uv, camera)
    g = _Geometry(
        box=np.zeros((n_people, n_points), dtype=bool), context=np.zeros((n_people, n_points), dtype=bool),
        box_fraction=np.zeros(n_people), left=np.zeros((n_people, n_points), dtype=bool),
        right=np.zeros((n_people, n_points), dtype=bool), dist=np.full((n_people, n_points), np.inf),
        part=np.zeros((n_people, n_points), dtype=np.int64), sure=np.zeros((n_people, n_points), dtype=bool),
        extent=np.full(n_people, np.nan),
    )
    for k, skeleton in enumerate(skeletons):
        if skeleton is None:
            continue
        box = g.box[k] = in_bbox(uv, skeleton.bbox)
        g.context[k] = in_bbox(uv, skeleton.context) & ~box
        g.box_fraction[k] = _area(skeleton.bbox) / max(_area(skeleton.context), 1e-9)
        x0, y0, x1, y1 = skeleton.bbox
        width = config.surface_side_width * (x1 - x0)
        rows = (uv[:, 1] >= y0) & (uv[:, 1] <= y1)
        g.left[k] = rows & (uv[:, 0] < x0) & (uv[:, 0] >= x0 - width)
        g.right[k] = rows & (uv[:, 0] > x1) & (uv[:, 0] <= x1 + width)
        d, nearest = segment_distance(xy[box], skeleton)
        g.dist[k, box] = d * z[box]
        g.part[k, box] = skeleton.parts[nearest]
        g.sure[k, box] = skeleton.scores[nearest] >= sure_score
        g.extent[k] = skeleton.extent
    return g


def associate(
    points: np.ndarray, uv: np.ndarray, coords: np.ndarray, clusters: np.ndarray,
    skeletons: list[Skeleton | None], camera: CameraModel, config: ExtractionConfig,
    depth_range: np.ndarray | None = None, refute_scale: float = 1.0,
) -> np.ndarray:
    """(M,) int64 person index of each candidate point (-1: nobody).

    points: (M, 3) camera-frame candidates (ground removed); uv: (M, 2) their undistorted pixels;
    coords: (M, 3) their clustering-space coordinates (`cluster.scaled_coordinates`); clusters: (M,)
    cluster labels 0..C-1; skeletons: one per person, None for people without one; depth_range:
    optional (P, 2) nearest and farthest depth (m) of each person's main cluster (NaN: unbounded);
    refute_scale: the frame's `score_scale`, on `refute_min_score`.
    """
    owner = np.full(len(points), -1, dtype=np.int64)
    if len(points) == 0 or len(skeletons) == 0:
        return owner
    z = points[:, 2].astype(np.float64)
    g = _geometry(uv, z, skeletons, camera, config, refute_scale)
    mask = g.dist <= config.mask_radius_m
    on_a_body = mask.any(axis=0)  # beside a box, that is a neighbour's body, not a surface going on
    g.left &= ~on_a_body
    g.right &= ~on_a_body
    main, body_like, depth = _score_clusters(g, mask, z, clusters, skeletons, camera, config, depth_range)
    chosen, reference = _body_clusters(main, body_like, depth, g.box, coords, clusters, config)
    with np.errstate(invalid="ignore"):
        in_window = np.abs(z[None, :] - reference[:, None]) <= config.body_depth_window_m
    eligible = mask & in_window & np.take_along_axis(chosen, np.broadcast_to(clusters, mask.shape), axis=1)
    dist = np.where(eligible, g.dist, np.inf)
    nearest = np.argmin(dist, axis=0)
    has_owner = np.isfinite(dist[nearest, np.arange(len(points))])
    owner[has_owner] = nearest[has_owner]
    return owner


def _score_clusters(
    g: _Geometry, mask: np.ndarray, z: np.ndarray, clusters: np.ndarray, skeletons: list[Skeleton | None],
    camera: CameraModel, config: ExtractionConfig, depth_range: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each person's main cluster (-1: none), which clusters look like a body, and each (person, cluster)
    pair's median depth."""
    n_people, n_clusters, n_parts = len(skeletons), int(clusters.max()) + 1, len(BODY_PARTS)
    group = np.arange(n_people)[:, None] * n_clusters + clusters[None, :]  # (P, M) person-cluster id
    size = n_people * n_clusters

    def count(selection: np.ndarray) -> np.ndarray:
        return np.bincount(group[selection], minlength=size).reshape(n_people, n_clusters)

    def parts_with(selection: np.ndarray) -> np.ndarray:  # (P, C, parts) bool: part has such points
        ids = group[selection] * n_parts + g.part[selection]
        return np.bincount(ids, minlength=size * n_parts).reshape(n_people, n_clusters, n_parts) > 0

    weight = _part_weights(skeletons, n_parts, config)[:, None, :]  # (P, 1, parts)
    parts_any = parts_with(mask)
    depth = _grouped_median(group[mask], np.broadcast_to(z, mask.shape)[mask], size).reshape(
        n_people, n_clusters
    )
    core = mask & (g.dist <= config.core_radius_m) & g.sure
    own_core = np.bincount(group[core] * n_parts + g.part[core], minlength=size * n_parts).reshape(
        n_people, n_clusters, n_parts
    )
    hypotheses = [np.flatnonzero(np.isfinite(depth[k])) for k in range(n_people)]

    def evidence(
        exclusive: np.ndarray, rows: np.ndarray, explained: np.ndarray | None = None, min_votes: int = 1,
    ) -> tuple[np.ndarray, np.ndarray]:
        """(P, C) coverage and contradicted parts of `rows` with these exclusive points; points of
        `explained` clusters hide nothing, and fewer than `min_votes` points neither refute nor hide."""
        parts_excl = parts_with(exclusive)
        coverage = (parts_excl * weight).sum(axis=2) + config.shared_weight * (
            (parts_any & ~parts_excl) * weight
        ).sum(axis=2)
        contradicted = np.zeros((n_people, n_clusters))
        for k in rows:
            if len(hypotheses[k]):
                can_hide = None if explained is None else ~explained[clusters[core[k]]]
                refuted, hidden = _contradicted_parts(
                    z[core[k]], clusters[core[k]], g.part[k, core[k]], hypotheses[k], depth[k, hypotheses[k]],
                    own_core[k, hypotheses[k]], config, can_hide, min_votes,
                )
                contradicted[k, hypotheses[k]] = refuted + config.hidden_weight * hidden
        return coverage, contradicted

    exclusive = mask & (mask.sum(axis=0) == 1)
    coverage, contradicted = evidence(exclusive, np.arange(n_people))
    fraction = np.zeros((n_people, n_clusters))
    for k in range(n_people):
        if len(hypotheses[k]):
            fraction[k, hypotheses[k]] = mask_fraction(skeletons[k], depth[k, hypotheses[k]], camera, config)
    counts = {"in_box": count(g.box), "in_context": count(g.context), "in_mask": count(mask),
              "exclusive": count(exclusive), "core": own_core.sum(axis=2),
              "core_behind": _core_behind(core, z, depth, config)}
    surface = _surface_through(g, z, depth, config)
    if depth_range is not None:
        depth_range = np.asarray(depth_range, np.float64).reshape(n_people, 2)
    main, body_like = _main_clusters(
        counts, coverage, contradicted, fraction, g.box_fraction, depth, g.extent, surface, config, depth_range,
    )
    missing = np.flatnonzero(main < 0)
    if config.second_look and 0 < len(missing) < n_people:
        # A second look for the people left without points, now that the others' bodies are placed:
        # someone placed in front explains what hides them, a placed person holds only the points in
        # their own depth window, so the points behind them are no longer shared with them, and a
        # single point behind or in front of a part (a ring through a gap) neither refutes nor hides.
        placed = np.flatnonzero(main >= 0)
        holds = mask.copy()
        with np.errstate(invalid="ignore"):
            holds[placed] &= np.abs(z[None, :] - depth[placed, main[placed]][:, None]) <= config.body_depth_window_m
        exclusive = mask & (holds.sum(axis=0) == 1)
        explained = np.isin(np.arange(n_clusters), main[placed])
        coverage, contradicted = evidence(exclusive, missing, explained, config.second_look_min_votes)
        counts["exclusive"] = count(exclusive)
        score, second = _qualify(counts, coverage, contradicted, fraction, g.box_fraction, depth, g.extent,
                                 surface, config, depth_range)
        owners = np.bincount(main[placed], minlength=n_clusters)
        main, owners = _assign(score, second & ~_barred(counts, config), counts, config, main, owners, missing,
                               g.extent)
        body_like[missing] = second[missing]
        body_like[:, owners > 0] = False
    return main, body_like, depth


def _body_clusters(
    main: np.ndarray, body_like: np.ndarray, depth: np.ndarray, box: np.ndarray, coords: np.ndarray,
    clusters: np.ndarray, config: ExtractionConfig,
) -> tuple[np.ndarray, np.ndarray]:
    """(P, C) the clusters that make each person's body, and each person's reference depth (NaN: none)."""
    chosen = np.zeros(body_like.shape, dtype=bool)
    reference = np.full(len(main), np.nan)
    for k in np.flatnonzero(main >= 0):
        reference[k] = depth[k, main[k]]
        with np.errstate(invalid="ignore"):
            near = np.abs(depth[k] - reference[k]) <= config.body_depth_window_m
        candidates = np.flatnonzero(body_like[k] & near)
        # Clusters at the main cluster's depth are the body's (an arm split off by a gap); the others
        # must connect to those.
        level = np.abs(depth[k, candidates] - reference[k]) <= config.depth_tolerance_m
        seeds = [int(main[k])] + candidates[level].tolist()
        chosen[k, _grow(seeds, candidates, coords[box[k]], clusters[box[k]], config)] = True
    return chosen, reference
