"""Columns: a post, pole or pillar standing on the ground among one person's points.

A person leaning on a post, seen from behind or from the side, has the post between them and the sensor:
its points join the person's cluster, and the fit then puts the body's back where the post's front is.
`extract.without_posts` finds such a post by its points above the person's box, which a LiDAR a few
metres away does not see (a VLP-16's top ring passes 1.2-1.4 m above the floor 3-4 m out). This test
needs none: a post is a vertical cylinder, and a scan cuts it into the same arc in every ring, from the
floor up to the top ring that reaches it. A body has nothing like it: a leg stops at the hip, where the
torso, wider and elsewhere, takes over, and no part of it keeps one circle from the floor up.

The test, in the ground plane (horizontal coordinates, heights above the floor): a RANSAC circle
(`column_trials` circles through three points, radius within [`column_min_radius_m`,
`column_max_radius_m`], its centre farther from the sensor than its points, which face it; of those
that pass the tests on heights below, the `column_checked` with the most points, each fitted again to
them) whose points within `column_tolerance_m` of it
  - start within `column_max_foot_m` of the floor, rise at least `column_min_height_m`, and reach within
    `column_top_gap_m` of the person's highest point;
  - hold, in at least `column_min_bands` height bands of `column_band_m` and in `column_band_pass` of the
    bands with any point within their bearings, `column_band_share` of the points there (nothing but the
    column is seen within a post's bearings: what is behind it is hidden), with no gap wider than
    `column_max_gap_m` across the line of sight (a post's front is whole; a circle through a post and a
    leg behind it has one);
  - number `column_band_points` per such band, and span, in the median band, `column_min_width` x the
    radius across the line of sight (a post shows its whole front).
Measured with a script over the frame path (people with 10 points or more, the column test alone): on
tuning seeds 0-199 at 2-8 m (401 people) it found one column, the post of a person leaning on it; none
at 1.5-15 m (seeds 200-299, 176 people), on Ouster-64 scenes (seeds 0-79, 2-12 m, 166 people) or in the
outdoor crowd (seeds 0-19, 112 people). On seeds 8000-8079 and 9000-9079 at 2-8 m (316 people) it found
the posts of six people leaning on them and nothing else; none of their points was the body's
(docs/benchmarks.md, "A post seen from near").
"""

from __future__ import annotations

import numpy as np

from smplify3d_ros.lidar.config import ExtractionConfig

_SEED = 0  # the circles tried are drawn from a fixed generator: the same scan gives the same result


def column_mask(horizontal: np.ndarray, height: np.ndarray, config: ExtractionConfig) -> np.ndarray:
    """(M,) bool: a person's points that belong to a column standing among them (all false: none).
    horizontal: (M, 2) their ground-plane coordinates, the sensor at the origin; height: (M,) above the
    floor, m. Each circle, from the one with the most points on it down, is fitted again to those points
    before it is tested; the column's points are those within its radius plus `column_tolerance_m` of
    its axis."""
    found = np.zeros(len(horizontal), dtype=bool)
    if config.column_max_radius_m <= 0.0 or len(horizontal) < 3 * max(config.column_min_bands, 1):
        return found
    xy = np.asarray(horizontal, np.float64)
    height = np.asarray(height, np.float64)
    centres, radii = _circles(xy, config)
    if len(radii) == 0:
        return found
    off = np.abs(np.linalg.norm(xy[None] - centres[:, None], axis=2) - radii[:, None])  # (T, M)
    on = off < config.column_tolerance_m
    counts = on.sum(axis=1)
    low = np.where(on, height, np.inf).min(axis=1)
    high = np.where(on, height, -np.inf).max(axis=1)
    tall = ((counts >= config.column_min_bands * config.column_band_points) & (low <= config.column_max_foot_m)
            & (high - low >= config.column_min_height_m) & (high >= height.max() - config.column_top_gap_m))
    bearing = np.arctan2(xy[:, 0], xy[:, 1])
    band = np.floor(height / config.column_band_m).astype(np.int64)
    band -= band.min()
    for t in np.flatnonzero(tall)[np.argsort(-counts[tall], kind="stable")][: config.column_checked]:
        centre, radius = _refined(xy[on[t]])
        distance = np.linalg.norm(xy - centre, axis=1)
        if (config.column_min_radius_m <= radius <= config.column_max_radius_m
                and _standing_column(bearing, height, band, np.abs(distance - radius) < config.column_tolerance_m,
                                     float(np.linalg.norm(centre)), radius, config)):
            return distance < radius + config.column_tolerance_m
    return found


def _refined(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """The least-squares circle through points (algebraic fit): the column's axis and radius from all its
    points, not the three that found it."""
    A = np.column_stack([2.0 * xy, np.ones(len(xy))])
    (cx, cy, k), *_ = np.linalg.lstsq(A, (xy * xy).sum(axis=1), rcond=None)
    return np.array([cx, cy]), float(np.sqrt(max(k + cx * cx + cy * cy, 0.0)))


def _circles(xy: np.ndarray, config: ExtractionConfig) -> tuple[np.ndarray, np.ndarray]:
    """(T, 2) centres and (T,) radii of the circles through `column_trials` random triples of points,
    those with a radius in range and the centre behind the points (farther from the sensor)."""
    rng = np.random.default_rng(_SEED)
    a, b, c = (xy[i] for i in rng.integers(0, len(xy), size=(3, config.column_trials)))
    A = 2.0 * np.stack([b - a, c - a], axis=1)  # (T, 2, 2): rows b - a and c - a
    rhs = np.stack([(b * b).sum(1) - (a * a).sum(1), (c * c).sum(1) - (a * a).sum(1)], axis=1)
    det = A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0]
    ok = np.abs(det) > 1e-9
    A, rhs, a, b, c, det = A[ok], rhs[ok], a[ok], b[ok], c[ok], det[ok]
    centres = np.stack([(A[:, 1, 1] * rhs[:, 0] - A[:, 0, 1] * rhs[:, 1]) / det,
                        (A[:, 0, 0] * rhs[:, 1] - A[:, 1, 0] * rhs[:, 0]) / det], axis=1)
    radii = np.linalg.norm(a - centres, axis=1)
    near = (np.linalg.norm(a, axis=1) + np.linalg.norm(b, axis=1) + np.linalg.norm(c, axis=1)) / 3.0
    keep = ((radii >= config.column_min_radius_m) & (radii <= config.column_max_radius_m)
            & (np.linalg.norm(centres, axis=1) > near))
    return centres[keep], radii[keep]


def _standing_column(bearing: np.ndarray, height: np.ndarray, band: np.ndarray, on: np.ndarray, reach: float,
                     radius: float, config: ExtractionConfig) -> bool:
    """Whether the points `on` one circle stand as a column (the module docstring's tests). bearing: (M,)
    each point's, rad; band: (M,) its height band, from 0; reach: the circle's centre's distance from the
    sensor, m (a bearing times it is a distance across the line of sight)."""
    if not on.any():  # the refitted circle can leave the three-point one's points
        return False
    low, high = float(height[on].min()), float(height[on].max())
    if (low > config.column_max_foot_m or high - low < config.column_min_height_m
            or high < float(height.max()) - config.column_top_gap_m):
        return False
    first, last = np.percentile(bearing[on], [5.0, 95.0])
    within = (bearing >= first) & (bearing <= last)
    n = int(band.max()) + 1
    points = np.bincount(band[within], minlength=n)
    share = np.bincount(band[within], weights=on[within], minlength=n)
    # each band's points on the circle in order across the line of sight: their widest gap and their span
    seen = within & on
    order = np.lexsort((bearing[seen], band[seen]))
    k, across = band[seen][order], bearing[seen][order] * reach
    same = k[1:] == k[:-1]
    gap = np.zeros(n)
    np.maximum.at(gap, k[1:][same], np.diff(across)[same])
    span = np.zeros(n)
    np.add.at(span, k[1:][same], np.diff(across)[same])
    present = points > 0
    good = present & (share > 0) & (share >= config.column_band_share * points) & (gap <= config.column_max_gap_m)
    return (int(good.sum()) >= config.column_min_bands
            and good.sum() >= config.column_band_pass * present.sum()
            and on.sum() >= config.column_band_points * present.sum()
            and float(np.median(span[good])) >= config.column_min_width * radius)
