"""Fits scored against a bag's ground truth as the replay streams: MPJPE (COCO-17 keypoints) and PVE
(vertices) per person id, in mm, without any alignment (the fits must be where the people are).

Results and ground-truth frames are matched by stamp (within the synchronizer's slop) in whichever order
they arrive; either waits at most `window_ns` of the other's stamps for its partner, and errors are kept
as running sums, so memory stays bounded whatever the bag's length.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from smplify3d_ros.body.base import BodyModel
from smplify3d_ros.eval import metrics
from smplify3d_ros.eval.truth import TruthBody, TruthFrame
from smplify3d_ros.types import BodyFit


@dataclass
class _Fitted:
    stamp_ns: int
    frame_id: str
    fits: dict[int, BodyFit]


class TruthScorer:
    """See the module docstring; `add_result` and `add_truth` in any order, then `finish`."""

    def __init__(self, model: BodyModel, slop_ns: int, window_ns: int = 2_000_000_000) -> None:
        self.model = model
        self.slop_ns = slop_ns
        self.window_ns = max(window_ns, 2 * slop_ns)
        self._results: deque[_Fitted] = deque()
        self._truths: deque[TruthFrame] = deque()
        self._joint_sum, self._joint_n = 0.0, 0  # MPJPE per scored person, mm
        self._vertex_sum, self._vertex_n = 0.0, 0  # PVE per scored person, mm
        self.frames = 0  # ground-truth frames scored
        self.people = 0  # ground-truth people with a fit
        self.missed = 0  # ground-truth people without a fit in a scored frame

    def add_result(self, stamp_ns: int, frame_id: str, fits: list[BodyFit]) -> None:
        self._results.append(_Fitted(stamp_ns, frame_id, {f.person_id: f for f in fits}))
        self._match()
        self._expire(self._truths, stamp_ns)

    def add_truth(self, truth: TruthFrame) -> None:
        self._truths.append(truth)
        self._match()
        self._expire(self._results, truth.stamp_ns)

    @property
    def waiting(self) -> int:
        """Results still waiting for their ground truth."""
        return len(self._results)

    def finish(self) -> None:
        self._match()
        self._results.clear()
        self._truths.clear()

    def _expire(self, pending: deque, newest_ns: int) -> None:
        while pending and pending[0].stamp_ns < newest_ns - self.window_ns:
            pending.popleft()

    def _match(self) -> None:
        for result in list(self._results):
            near = [t for t in self._truths if abs(t.stamp_ns - result.stamp_ns) <= self.slop_ns]
            if not near:
                continue
            truth = min(near, key=lambda t: abs(t.stamp_ns - result.stamp_ns))
            self._results.remove(result)
            self._truths.remove(truth)
            if not truth.frame_id or truth.frame_id == result.frame_id:  # else: fits in another frame
                self._score(result, truth)

    def _score(self, result: _Fitted, truth: TruthFrame) -> None:
        self.frames += 1
        for body in truth.bodies:
            fit = result.fits.get(body.person_id)
            if fit is None:
                self.missed += 1
                continue
            self.people += 1
            keypoints, vertices = self._geometry(body, truth.joint_names)
            if keypoints is not None:
                self._joint_sum += metrics.mpjpe(fit.keypoints3d, keypoints)
                self._joint_n += 1
            if vertices is not None and body.params.model == fit.model and len(vertices) == len(fit.vertices):
                self._vertex_sum += metrics.pve(fit.vertices, vertices)
                self._vertex_n += 1

    def _geometry(self, body: TruthBody, joint_names: list[str]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The body's keypoints and vertices: the document's, else the body model's when it is the fits'."""
        keypoints, vertices = body.keypoints3d, body.vertices
        if (keypoints is None or vertices is None) and body.params.model == self.model.name:
            params = body.params.copy()
            rows = {name: i for i, name in enumerate(joint_names)}
            params.pose = np.array([body.params.pose[rows[n]] if n in rows else np.zeros(3)
                                    for n in self.model.joint_names])
            posed = self.model.posed([params])[0]
            keypoints = posed.keypoints3d if keypoints is None else keypoints
            vertices = posed.vertices if vertices is None else vertices
        return keypoints, vertices

    @property
    def mpjpe_mm(self) -> float | None:
        return self._joint_sum / self._joint_n if self._joint_n else None

    @property
    def pve_mm(self) -> float | None:
        return self._vertex_sum / self._vertex_n if self._vertex_n else None
