"""Which track an anonymous detection continues: a gated assignment on position and box overlap.

Cost of (track, detection): the horizontal distance (camera x-z plane) between where the track's LiDAR
points are predicted (the last points its person had, moved by the track's velocity) and where the
detection's are, plus `iou_weight` x (1 - overlap of their keypoint boxes); a pair farther apart than
the gate (`gate_m` + `gate_speed_mps` x the age of the track's points) cannot match. Without points on
either side, the boxes alone decide, and they must overlap. A track whose person had no points in its
last frame still has a depth: a person behind someone in the image must not hand their track to the
one in front, whose box overlaps theirs. The assignment minimising
the total cost is found with the Hungarian method (scipy's `linear_sum_assignment`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from scipy.optimize import linear_sum_assignment

from smplify3d_ros.tracking.config import TrackingConfig
from smplify3d_ros.types import PersonObservation

if TYPE_CHECKING:  # the tracker imports this module
    from smplify3d_ros.tracking.tracker import Track

_NO_MATCH = 1e9


def box_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Intersection over union of two (x_min, y_min, x_max, y_max) boxes."""
    w = min(a[2], b[2]) - max(a[0], b[0])
    h = min(a[3], b[3]) - max(a[1], b[1])
    if w <= 0 or h <= 0:
        return 0.0
    inter = w * h
    union = (a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter
    return float(inter / union) if union > 0 else 0.0


def _cost(track: Track, obs: PersonObservation, stamp_ns: int, config: TrackingConfig) -> float:
    overlap = box_iou(track.bbox, np.asarray(obs.bbox, np.float64))
    surface = np.median(obs.points, axis=0) if len(obs.points) else None
    predicted = track.predicted_surface(stamp_ns)
    if surface is None or predicted is None:
        return config.iou_weight * (1.0 - overlap) if overlap > 0 else _NO_MATCH
    distance = float(np.hypot(*(predicted - surface)[[0, 2]]))
    if not np.isfinite(distance) or distance > config.gate_m + config.gate_speed_mps * track.surface_age_s(stamp_ns):
        return _NO_MATCH
    return distance + config.iou_weight * (1.0 - overlap)


def associate(tracks: list[Track], people: list[PersonObservation], stamp_ns: int,
              config: TrackingConfig) -> dict[int, Track]:
    """Detection index -> the track it continues (detections left out start new tracks)."""
    if not tracks or not people:
        return {}
    cost = np.array([[_cost(t, p, stamp_ns, config) for p in people] for t in tracks])
    rows, cols = linear_sum_assignment(cost)
    return {int(c): tracks[r] for r, c in zip(rows, cols, strict=True) if cost[r, c] < _NO_MATCH}
