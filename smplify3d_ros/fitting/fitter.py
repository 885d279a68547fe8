"""The method on one frame's people: initial estimate -> visibility -> ICP -> stages -> BodyFit.

`Fitter.fit(people, K)` runs the thesis's steps in order, batched over the people of a frame; each step
is a method over one `Batch`, the state the steps share. From the built-in initializer (no upstream HMR,
the robot's usual case) each person starts as several heading hypotheses (`fitting.heading`), refined
together and reduced to the one the objective prefers before the ICP. The stages run Adam or
Levenberg-Marquardt (`fitting.solver`) on the same objective, as the profile says. The people come as
`PersonObservation`s in the camera frame (keypoints undistorted, LiDAR points cut out):
`frame_fitter.FrameFitter` makes them from a whole `Frame`.
"""

from __future__ import annotations

import dataclasses
import functools
import logging
import math
from dataclasses import dataclass

import numpy as np
import torch

from smplify3d_ros.body import BodyModel, load_body_model
from smplify3d_ros.body.base import PARAM_FIELDS
from smplify3d_ros.fitting import free_space
from smplify3d_ros.fitting import init as initializer
from smplify3d_ros.fitting.config import FittingConfig
from smplify3d_ros.fitting.icp import align_mesh_to_points
from smplify3d_ros.fitting.limbs import limb_depth_targets
from smplify3d_ros.fitting.losses import nearest_sq_distances, project, reprojection_loss
from smplify3d_ros.fitting.options import FitOptions
from smplify3d_ros.fitting.problem import FitProblem, FitState
from smplify3d_ros.fitting.stages import StageSpec, optimize, run_stage
from smplify3d_ros.fitting.visibility import occluded_parts, visible_vertices
from smplify3d_ros.geometry import move_body, transform
from smplify3d_ros.keypoints import PART_NAMES, swapped_order
from smplify3d_ros.types import (
    FLAG_DIVERGED,
    FLAG_EXTERNAL_INIT,
    FLAG_FEW_KEYPOINTS,
    FLAG_ICP_NOT_CONVERGED,
    FLAG_IMAGE_ONLY,
    FLAG_LIDAR_MISMATCH,
    FLAG_POINTS_TOO_NEAR,
    FLAG_SWAPPED_KEYPOINTS,
    BodyFit,
    BodyParams,
    FitQuality,
    PersonObservation,
)

log = logging.getLogger(__name__)


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        log.warning("device 'cuda' requested but unavailable; using the CPU")
        return torch.device("cpu")
    return torch.device(name)


@dataclass
class Batch:
    """What the steps of one `Fitter.fit` call share; row i of every array is person i."""

    people: list[PersonObservation]
    K: torch.Tensor  # (3, 3) intrinsics of the undistorted image
    lidar_origin: np.ndarray  # (3,) the LiDAR's position in the camera frame (back-face culling)
    options: FitOptions
    keypoints: torch.Tensor  # (B, 17, 2) px
    confidence: torch.Tensor  # (B, 17)
    use_lidar: np.ndarray  # (B,) bool: enough points for L_3D
    occluded_image: list[np.ndarray]  # per person, (parts,) bool: parts the image term treats as occluded
    occluded_lidar: list[np.ndarray]  # per person, (parts,) bool: parts left out of L_3D
    occluded_joints: np.ndarray  # (B, J) bool: joints driving image-occluded parts (L_θocc)
    flags: list[set[str]]
    builtin: np.ndarray  # (B,) bool: started from the built-in initializer
    state: FitState | None = None
    hypotheses: list[list[BodyParams]] = dataclasses.field(default_factory=list)  # built-in starts per person
    # per person and start, the keypoint order it reads the detection in (None: as detected; else a
    # left/right swap, `init.swap_hypotheses`); in a trial batch of hypotheses (`_compete`), one per row
    readings: list = dataclasses.field(default_factory=list)
    keypoint_depth: np.ndarray | None = None  # (B, 17) limb-depth targets, camera z (NaN: none)
    problem: FitProblem | None = None  # the stages' observations (also what the fit quality is measured on)
    icp_ok: np.ndarray | None = None  # (B,) bool
    vertices: np.ndarray | None = None  # (B, V, 3) the bodies of `state` when known (after ICP), else None
    final_loss: torch.Tensor | None = None  # (B,)

    @property
    def size(self) -> int:
        return len(self.people)

    def take(self, rows: np.ndarray) -> Batch:
        """The people of `rows` (repeats allowed), without a state: a batch of hypotheses."""
        index = torch.as_tensor(rows, device=self.keypoints.device)
        return Batch(
            people=[self.people[i] for i in rows], K=self.K, lidar_origin=self.lidar_origin,
            options=self.options, keypoints=self.keypoints[index],
            confidence=self.confidence[index], use_lidar=self.use_lidar[rows],
            occluded_image=[self.occluded_image[i] for i in rows],
            occluded_lidar=[self.occluded_lidar[i] for i in rows], occluded_joints=self.occluded_joints[rows],
            flags=[set() for _ in rows], builtin=self.builtin[rows],
            keypoint_depth=None if self.keypoint_depth is None else self.keypoint_depth[rows],
        )


def _pad_rows(rows: list[np.ndarray], width: int, fill) -> tuple[np.ndarray, np.ndarray]:
    n = max([len(r) for r in rows] + [0])
    shape = (len(rows), n) + ((width,) if width else ())
    out = np.full(shape, fill, dtype=np.float64 if width else np.int64)
    mask = np.zeros((len(rows), n), dtype=bool)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
        mask[i, : len(r)] = True
    return out, mask


def _subsample(n: int, limit: int, seed: int) -> np.ndarray:
    """`limit` of `n` indices (all when `limit` is 0 or at least `n`), sorted: drawn by a generator of
    `seed`, `n` and `limit` alone, so that a person's subsets, and their fit, do not depend on who else
    is fitted in the same batch (other people, other hypotheses) nor in what order."""
    if limit <= 0 or n <= limit:
        return np.arange(n)
    return np.sort(np.random.default_rng((seed, n, limit)).choice(n, size=limit, replace=False))


class Fitter:
    """Holds the body model and the configuration; `fit` runs the method on one frame's people."""

    def __init__(self, config: FittingConfig, model: BodyModel | None = None) -> None:
        self.config = config
        if config.num_threads > 0:
            # per-iteration tensors are small: intra-op threads only add synchronization, and on a busy robot
            # CPU (drivers, planners) oversubscribed OpenMP threads made fits 10x slower in our measurements
            torch.set_num_threads(config.num_threads)
        self.device = resolve_device(config.device)
        self.model = model if model is not None else load_body_model(config.body.model, config.body, str(self.device))
        self.dtype = self.model.dtype
        self.faces_np = self.model.faces.cpu().numpy()
        self._start_pose = self._builtin_start_pose()
        self._flexed_start_pose = self._builtin_start_pose(self.config.init.start_hip_flexion_deg,
                                                           self.config.init.start_knee_flexion_deg)
        self._pitched_poses: dict[float, np.ndarray] = {}  # `_pitched_start_pose`'s
        self._keypoints_only = torch.zeros(1, dtype=torch.long, device=self.device)
        # the keypoint orders every person's starts are tried in: as detected (None), then each of
        # `init.swap_hypotheses`' swaps (a person's own `hypothesis`, a track's warm start, in the one it
        # projects closest to: `_reading_of`)
        self._readings: list[list[int] | None] = [None] + [swapped_order([group])
                                                          for group in config.init.swap_hypotheses]
        self.part_of_face_np = self.model.part_of_face.cpu().numpy()
        self._around = free_space.vertex_faces(self.faces_np, int(self.faces_np.max()) + 1)

    def _pitched_start_pose(self, pitch_deg: float) -> np.ndarray:
        """The pose of a start bent over at the hips, for a pelvis pitched forward by `pitch_deg`
        (`initializer.pitched_root_orient`): the hips flexed as much, so that the legs stay upright; the
        fixed bent start's (`init.start_trunk_pitch_deg`) and the one read from the image. Cached."""
        key = round(float(pitch_deg), 3)
        if key not in self._pitched_poses:
            self._pitched_poses[key] = self._builtin_start_pose(key)
        return self._pitched_poses[key]

    def _builtin_start_pose(self, hip_deg: float = 0.0, knee_deg: float = 0.0) -> np.ndarray:
        """(J, 3) pose the built-in initializer starts every person from: the anatomical neutral
        (standing, arms hanging, legs straight), not the model's rest pose (Anny's is an A-pose), with the
        elbows flexed by `init.start_elbow_flexion_deg`, and the hips and knees by `hip_deg` and
        `knee_deg`. A straight elbow is a singular start: there, no small turn of the upper arm moves the
        wrist, and the solver leaves a forearm the image shows across the body or held forward pointing at
        the camera (docs/benchmarks.md, "A bent elbow"). A straight hip is one for the thigh of a person
        facing the camera or turned away: a small flexion moves the knee along the ray, which the image
        does not see, so a sitting or crouching person's thighs stay hanging (the flexed-leg start)."""
        names = list(self.model.joint_names)
        angles = torch.zeros(1, len(names), 3, dtype=self.dtype)
        flexion = {"elbow": self.config.init.start_elbow_flexion_deg, "hip": hip_deg, "knee": knee_deg}
        for joint, degrees in flexion.items():
            for name in (f"left_{joint}", f"right_{joint}"):
                if name in names:
                    angles[0, names.index(name), 0] = math.radians(degrees)
        return self.model.anatomical_to_pose(angles, from_neutral=True)[0].cpu().double().numpy()

    def fit(
        self,
        people: list[PersonObservation],
        K: np.ndarray,
        lidar_origin: np.ndarray | None = None,
        options: FitOptions | None = None,
    ) -> list[BodyFit]:
        """Fit every person of one frame (camera frame; `K` of the undistorted image)."""
        if not people:
            return []
        batch = self._start(people, K, lidar_origin, options or FitOptions())
        self._initialize(batch)
        batch, owner = self._refine_builtin(batch)
        self._align_to_points(batch)
        self._optimize(batch)
        return _pick_hypotheses(self._results(batch), owner, len(people), self.config.init.final_hypothesis_margin)

    # -- the steps ---------------------------------------------------------------------------------------
    def _start(self, people: list[PersonObservation], K: np.ndarray, lidar_origin: np.ndarray | None,
               options: FitOptions) -> Batch:
        """Which terms each person gets: LiDAR or image only, and the visibility of its parts."""
        cfg = self.config
        torch.manual_seed(cfg.seed)
        occlusion = [self._occlusion(p.keypoints[:, 2], options) for p in people]
        people = list(people)
        flags: list[set[str]] = [set() for _ in people]
        K = np.asarray(K, np.float64)
        for i, p in enumerate(people):
            if initializer.points_too_near(p, K, cfg.init):
                people[i] = dataclasses.replace(p, points=p.points[:0])  # an occluder's: fitted from the image
                flags[i].add(FLAG_POINTS_TOO_NEAR)
        # points, but every part scored under `visibility.keypoint_conf_lidar`: L_3D has no vertex to match
        # them to, and a body fitted as if it had would hold its depth by nothing but the image (a crowd
        # seen from behind, scored low, stood metres off); they still measure the depth, as a few points do
        no_lidar_part = np.array([options.use_visibility and bool(o[1].all()) for o in occlusion])
        use_lidar = np.array([len(p.points) >= cfg.min_points for p in people]) & ~no_lidar_part
        for i, p in enumerate(people):
            if not use_lidar[i]:
                flags[i].add(FLAG_IMAGE_ONLY)
            if (p.keypoints[:, 2] >= cfg.init.keypoint_conf).sum() < cfg.min_keypoints:
                flags[i].add(FLAG_FEW_KEYPOINTS)
        return Batch(
            people=people,
            K=torch.as_tensor(K, dtype=self.dtype, device=self.device),
            lidar_origin=np.zeros(3) if lidar_origin is None else np.asarray(lidar_origin, np.float64),
            options=options,
            keypoints=self._tensor([p.keypoints[:, :2] for p in people]),
            confidence=self._tensor([p.keypoints[:, 2] for p in people]),
            use_lidar=use_lidar,
            occluded_image=[o[0] for o in occlusion],
            occluded_lidar=[o[1] for o in occlusion],
            occluded_joints=np.stack([o[2] for o in occlusion]),
            flags=flags,
            builtin=np.zeros(len(people), dtype=bool),
        )

    def _occlusion(self, confidence: np.ndarray, options: FitOptions) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What a person's keypoint confidences (17,) leave occluded: the parts the image term and the
        parts L_3D treat as occluded, and the joints the occlusion prior holds (none without it)."""
        vis = self.config.visibility
        image = occluded_parts(confidence, vis.keypoint_conf_image)
        joints = np.zeros(len(self.model.joint_names), dtype=bool)
        if options.use_occlusion_prior:
            for part in np.flatnonzero(image):
                joints[self.model.part_joint_index[part]] = True
        return image, occluded_parts(confidence, vis.keypoint_conf_lidar), joints

    def _read_in_order(self, batch: Batch, row: int, order: list[int]) -> None:
        """Row `row` of `batch` reads its detection in `order` (a left/right swap of some keypoints): its
        keypoints, confidences, limb-depth targets and the occlusion they imply, in place."""
        index = torch.as_tensor(order, device=self.device)
        batch.keypoints[row] = batch.keypoints[row, index]
        batch.confidence[row] = batch.confidence[row, index]
        if batch.keypoint_depth is not None:
            batch.keypoint_depth[row] = batch.keypoint_depth[row, order]
        image, lidar, joints = self._occlusion(batch.confidence[row].cpu().double().numpy(), batch.options)
        batch.occluded_image[row], batch.occluded_lidar[row], batch.occluded_joints[row] = image, lidar, joints
        batch.flags[row].add(FLAG_SWAPPED_KEYPOINTS)

    def _initialize(self, batch: Batch) -> None:
        """Step 1: an external estimate of this model when a person has one, else the built-in one's
        hypotheses (the first stands in until `_refine_builtin` picks one): each heading hypothesis
        standing, then the first `init.flexed_leg_hypotheses` of them again with flexed legs where the
        image shows a thigh, or the knees and the points can tell (`initializer.flexed_legs_tried`), the
        first `init.bent_trunk_hypotheses` bent over at the hips by `init.start_trunk_pitch_deg` for a
        person with LiDAR points, and one more bent as far as the image's trunk reads
        (`initializer.image_trunk_start`), for each of `init.swap_hypotheses`' left/right keypoint groups the best
        guess of the detection read with that group swapped (a detector's swap; a swapped shoulder or hip
        pair turns the heading read from it), then the person's own `hypothesis` (a track's warm start),
        if any, in the reading it projects closest to (`_reading_of`)."""
        cfg = self.config
        mean_shape = self.model.mean_shape().cpu().double().numpy()
        K = batch.K.cpu().double().numpy()
        params: list[BodyParams] = []
        batch.hypotheses = [[] for _ in batch.people]
        batch.readings = [[] for _ in batch.people]
        batch.keypoint_depth = np.full((batch.size, 17), np.nan)
        for i, p in enumerate(batch.people):
            if p.init is not None and p.init.model == self.model.name:
                params.append(p.init.copy())
                batch.flags[i].add(FLAG_EXTERNAL_INIT)
                continue
            if p.init is not None:
                log.warning("person %d: initial estimate is for %r, not %r; using the built-in init",
                            p.person_id, p.init.model, self.model.name)
            hypotheses = initializer.builtin_hypotheses(p, K, cfg.init, bool(batch.use_lidar[i]),
                                                        len(p.points) >= cfg.min_points_depth)
            starts = [(self._start_pose, root, pelvis) for root, pelvis in hypotheses]
            if hypotheses and initializer.flexed_legs_tried(p, K, cfg.init, bool(batch.use_lidar[i]),
                                                            float(hypotheses[0][1][2])):
                starts += [(self._flexed_start_pose, root, pelvis)
                           for root, pelvis in hypotheses[: cfg.init.flexed_leg_hypotheses]]
            if batch.use_lidar[i]:  # from the image alone, a trunk bent towards the camera is a short one
                pitch = math.radians(cfg.init.start_trunk_pitch_deg)
                bent = self._pitched_start_pose(cfg.init.start_trunk_pitch_deg)
                starts += [(bent, initializer.pitched_root_orient(root, pitch), pelvis)
                           for root, pelvis in hypotheses[: cfg.init.bent_trunk_hypotheses]]
                read = initializer.image_trunk_start(p, K, cfg.init, [root for root, _ in hypotheses],
                                                     hypotheses[0][1]) if hypotheses else None
                if read is not None:
                    starts.append((self._pitched_start_pose(read.pitch_deg), read.root_orient, read.pelvis))
            for pose, root, pelvis in starts:
                batch.hypotheses[i].append(BodyParams(self.model.name, mean_shape.copy(), pose.copy(),
                                                      root.copy(), pelvis.copy()))
            batch.readings[i] = [None] * len(starts)
            if starts:
                for order in self._readings[1:]:  # the best guess from the swapped detection
                    swapped = dataclasses.replace(p, keypoints=p.keypoints[order])
                    root, pelvis = initializer.builtin_hypotheses(swapped, K, cfg.init, bool(batch.use_lidar[i]),
                                                                  len(p.points) >= cfg.min_points_depth)[0]
                    batch.hypotheses[i].append(BodyParams(self.model.name, mean_shape.copy(), self._start_pose.copy(),
                                                          root, pelvis))
                    batch.readings[i].append(order)
            if p.hypothesis is not None and p.hypothesis.model == self.model.name:
                batch.hypotheses[i].append(p.hypothesis.copy())
                batch.readings[i].append(self._reading_of(p.hypothesis, p.keypoints, K))
            params.append(batch.hypotheses[i][0])
            batch.builtin[i] = True
            if batch.use_lidar[i]:
                depth = float(batch.hypotheses[i][0].transl[2])
                batch.keypoint_depth[i] = limb_depth_targets(p.keypoints, K, p.points, depth, cfg.init)
        batch.state = self._placed_state(params, batch.builtin)

    def _reading_of(self, params: BodyParams, keypoints: np.ndarray, K: np.ndarray) -> list[int] | None:
        """The reading of a detection (17, 3) that a fitted body (a track's warm start) projects closest
        to: one of `init.swap_hypotheses`' swaps where its L_J (`reprojection_loss`) is below
        `init.swap_hypothesis_margin` of the as-detected reading's, else as detected (None). The fit it
        came from may have read a detector's swap; trying it in every reading would cost a row each."""
        if len(self._readings) == 1:
            return None
        out = self._forward(self._placed_state([params], np.ones(1, dtype=bool)), self._keypoints_only)
        projected = project(out.keypoints, self._tensor([K]))
        reads = [keypoints if order is None else keypoints[order] for order in self._readings]
        costs = reprojection_loss(projected.expand(len(reads), -1, -1), self._tensor([r[:, :2] for r in reads]),
                                  self._tensor([r[:, 2] for r in reads]), self.config.optimizer.weights.sigma_px)
        costs = costs.cpu().double().numpy()
        best = 1 + int(np.argmin(costs[1:]))
        return self._readings[best] if costs[best] < self.config.init.swap_hypothesis_margin * costs[0] else None

    def _placed_state(self, params: list[BodyParams], builtin: np.ndarray) -> FitState:
        """The state of these parameters, built-in estimates moved so that their hip midpoint is where
        their `transl` says (the model's rotation centre may not be its pelvis: SMPL)."""
        state = FitState.from_params(self.model, params)
        if builtin.any():
            out = self._forward(state, self._keypoints_only)  # keypoints only: one vertex, not the mesh
            pelvis_now = 0.5 * (out.keypoints[:, 11] + out.keypoints[:, 12])
            rows = torch.as_tensor(np.flatnonzero(builtin), device=self.device)
            with torch.no_grad():
                state.transl[rows] += state.transl[rows] - pelvis_now[rows]
        return state

    def _refine_builtin(self, batch: Batch) -> tuple[Batch, np.ndarray]:
        """The built-in estimate: every heading hypothesis of every person refined together for
        `hypothesis_iterations` (pose, orientation and position against the keypoints, the points and the
        limb depths, anatomical priors only: there is no estimate to hold), then each person's
        `final_hypotheses` lowest losses (those within `final_hypothesis_ratio` of the lowest) refined on
        for the rest of `refine_iterations`. People with an external estimate keep theirs. Returns the
        batch the later steps fit, one row per person and kept hypothesis (the leader first), and each
        row's person: another hypothesis's fit replaces the leader's when its final loss is below
        `final_hypothesis_margin` of the leader's (`_pick_hypotheses`). A heading the first iterations
        cannot tell from its mirror is told by the whole fit."""
        init = self.config.init
        owner = np.arange(batch.size)
        if not batch.builtin.any() or init.refine_iterations <= 0:
            return batch, owner
        trial, kept = self._compete(batch)
        rows = [np.array([i]) if i not in kept else kept[i] for i in range(batch.size)]
        owner = np.concatenate([np.full(len(r), i) for i, r in enumerate(rows)])
        if len(owner) > batch.size:  # several hypotheses go on: a batch of them
            out = batch.take(owner)
            out.flags = [set(batch.flags[i]) for i in owner]
            out.state = batch.state.take(torch.as_tensor(owner, device=self.device))
        else:
            out = batch
        builtin_rows = np.flatnonzero(np.isin(owner, list(kept)))  # their hypotheses, in `kept`'s order
        source = torch.as_tensor(np.concatenate([kept[i] for i in range(batch.size) if i in kept]))
        with torch.no_grad():
            for name in PARAM_FIELDS:
                getattr(out.state, name)[torch.as_tensor(builtin_rows)] = getattr(trial.state, name)[source]
        for row, trial_row in zip(builtin_rows, source.tolist()):
            if trial.readings[trial_row] is not None:
                self._read_in_order(out, int(row), trial.readings[trial_row])
        rest = init.refine_iterations - min(init.hypothesis_iterations, init.refine_iterations)
        if rest > 0:
            self._refine_rows(out, np.flatnonzero(out.builtin), rest)
        return out, owner

    def _compete(self, batch: Batch) -> tuple[Batch, dict[int, np.ndarray]]:
        """Every hypothesis of every built-in person refined together for `init.hypothesis_iterations`
        (0: compared as they start), reviewed after `init.hypothesis_review_iterations` of them
        (`_review`): the trial batch and, per built-in person, its rows that go on, lowest loss first (at
        most `init.final_hypotheses`, within `init.final_hypothesis_ratio` of the lowest), a swapped
        reading's loss counted over `init.swap_hypothesis_margin`."""
        init = self.config.init
        rows = np.array([i for i in range(batch.size) for _ in batch.hypotheses[i]], dtype=np.int64)
        trial = batch.take(rows)
        trial.readings = [order for i in range(batch.size) for order in batch.readings[i]]
        for r, order in enumerate(trial.readings):
            if order is not None:
                self._read_in_order(trial, r, order)
        trial.state = self._placed_state([h for i in range(batch.size) for h in batch.hypotheses[i]],
                                         np.ones(len(rows), dtype=bool))
        swapped = np.array([order is not None for order in trial.readings])
        margin = np.where(swapped, init.swap_hypothesis_margin, 1.0)  # a swapped reading must do clearly better
        iterations = min(init.hypothesis_iterations, init.refine_iterations)
        first = min(init.hypothesis_review_iterations, iterations) if init.hypothesis_review_iterations else iterations
        loss = self._refine(trial, first).cpu().double().numpy() / margin
        if iterations > first:
            loss = self._review(trial, rows, loss, iterations - first) / margin
        kept = {}
        for i in np.flatnonzero(batch.builtin):
            mine = np.flatnonzero(rows == i)
            mine = mine[np.argsort(loss[mine], kind="stable")]
            near = np.isfinite(loss[mine]) & (loss[mine] <= init.final_hypothesis_ratio * loss[mine[0]])
            kept[int(i)] = mine[: max(1, min(init.final_hypotheses, int(near.sum())))]
        return trial, kept

    def _review(self, trial: Batch, rows: np.ndarray, loss: np.ndarray, iterations: int) -> np.ndarray:
        """The rest of the competing `iterations` for the hypotheses whose `loss` (over the swap margin) is
        within `init.hypothesis_drop_ratio` of their person's best, from a problem posed anew: which
        vertices face the LiDAR is read off each body as it now stands, not as it started (a heading
        hypothesis turns by tens of degrees in its first iterations, and the side it showed the LiDAR
        then is not the one it shows now). The others are dropped (their loss inf): on tuning seeds 0-39,
        no hypothesis that led after all of them had been over 1.8 times its person's best at the review.
        Returns (R,) the raw final losses, inf where dropped or diverged; `trial.state` in place."""
        best = np.full(rows.max() + 1, np.inf)
        np.minimum.at(best, rows, loss)
        keep = np.flatnonzero(np.isfinite(loss) & (loss <= self.config.init.hypothesis_drop_ratio * best[rows]))
        out = np.full(len(rows), np.inf)
        if len(keep):  # the readings' keypoints and occlusion as the trial has them (swapped)
            out[keep] = self._refine_rows(trial, keep, iterations).cpu().double().numpy()
        return out

    def _refine_rows(self, batch: Batch, rows: np.ndarray, iterations: int) -> torch.Tensor:
        """`_refine` of `batch`'s `rows` only, their state updated in place; (len(rows),) final losses."""
        index = torch.as_tensor(rows, device=self.device)
        sub = batch.take(rows)
        sub.state = batch.state.take(index)
        loss = self._refine(sub, iterations)
        batch.state.copy_rows_from_subset(sub.state, index)
        return loss

    def given_hypothesis_wins(self, people: list[PersonObservation], K: np.ndarray,
                              lidar_origin: np.ndarray | None = None,
                              options: FitOptions | None = None) -> list[bool]:
        """Per person: whether their own `hypothesis` (a tracked person's warm start) has the lowest loss
        among their hypotheses after the built-in heading hypotheses' joint refinement, the comparison by
        which `fit` picks its start; False for people without one. Costs the initializer and that
        refinement, a third of a cold fit."""
        if not people:
            return []
        batch = self._start(people, K, lidar_origin, options or FitOptions())
        self._initialize(batch)
        if not batch.builtin.any() or self.config.init.refine_iterations <= 0:
            return [False] * len(people)
        trial, kept = self._compete(batch)
        offsets = np.cumsum([0] + [len(h) for h in batch.hypotheses])
        return [i in kept and p.hypothesis is not None and p.hypothesis.model == self.model.name
                and kept[i][0] == offsets[i + 1] - 1  # a person's own start: the last row
                for i, p in enumerate(batch.people)]

    def _refine(self, trial: Batch, iterations: int) -> torch.Tensor:
        """`iterations` of the built-in init's refinement of `trial`'s state, in place; (B,) final losses
        (inf where diverged)."""
        init = self.config.init
        problem = self._problem(trial, init.refine_max_vertices)  # coarse: the start is decimetres off
        params = ("pose", "root_orient", "transl") if init.refine_chamfer > 0 else ("pose", "root_orient")
        spec = StageSpec("init", params, iterations, None, self.config.optimizer.weights.sigma_px,
                         init.refine_chamfer, priors=True, hold=False, keypoint_depth_weight=init.refine_keypoint_depth,
                         keypoint_depth_sigma=init.limb_depth_sigma)
        diverged = torch.zeros(trial.size, dtype=torch.bool, device=self.device)
        _, loss = run_stage(self.model, trial.state, problem, spec, _refine_profile(self.config),
                            self.config.divergence_factor, diverged)
        return torch.where(diverged | ~torch.isfinite(loss), torch.full_like(loss, float("inf")), loss)

    def _align_to_points(self, batch: Batch) -> None:
        """Step 2: ICP of the LiDAR-visible vertices to each person's points (Sec. 3.3)."""
        cfg = self.config
        batch.icp_ok = np.ones(batch.size, dtype=bool)
        if not (batch.options.use_icp and cfg.icp.enabled):
            return
        known = [p.init_vertices for p in batch.people]
        if not batch.builtin.any() and all(v is not None for v in known):
            verts = np.stack(known).astype(np.float32)  # the initial estimates' meshes came with them
        else:
            verts = self._forward(batch.state).vertices.cpu().numpy()
        masks = self._visible_masks(batch, verts)
        translation_only = dataclasses.replace(cfg.icp, estimate_rotation=False)
        for i, p in enumerate(batch.people):
            visible = verts[i][masks[i]]
            if not batch.use_lidar[i]:
                # too few points for L_3D, but enough to fix the depth along the ray, which the image
                # cannot (an image HMR's depth errors reach metres). The built-in initializer took its
                # depth from them already, and a translation fitted to a dozen points of unknown parts
                # moves the body up or sideways as much as it corrects the depth (tuning seeds 0-39:
                # 10-45 cm): it keeps the initializer's.
                if len(p.points) >= cfg.min_points_depth and not batch.builtin[i]:
                    result = align_mesh_to_points(visible, p.points, translation_only)
                    if result.converged:
                        self._move(batch.state, i, result.T, verts)
                continue
            result = align_mesh_to_points(visible, p.points, cfg.icp)
            batch.icp_ok[i] = result.converged
            if result.converged:
                self._move(batch.state, i, result.T, verts)
            else:
                batch.flags[i].add(FLAG_ICP_NOT_CONVERGED)
                if np.linalg.norm(result.translation) <= cfg.icp.max_translation:
                    self._move(batch.state, i, transform(t=result.translation), verts)
        batch.vertices = verts  # moved with their bodies: the stages' problem needs no new forward pass

    def _optimize(self, batch: Batch) -> None:
        """Step 3: the stages of the profile's scheme (Eq. 2, or Eq. 11-14)."""
        problem = batch.problem = self._problem(batch)
        if not batch.options.use_chamfer:
            problem.use_lidar = torch.zeros_like(problem.use_lidar)
        batch.final_loss = torch.full((batch.size,), float("nan"))
        if not batch.options.optimize:
            return
        report = optimize(self.model, batch.state, problem, self.config.optimizer, self.config.divergence_factor)
        batch.final_loss = report.final_loss.cpu()
        for i in np.flatnonzero(report.diverged.cpu().numpy()):
            batch.flags[i].add(FLAG_DIVERGED)

    def _results(self, batch: Batch) -> list[BodyFit]:
        """Fits with their quality: reprojection error and chamfer distance of the final bodies."""
        state, problem = batch.state, batch.problem
        out = self._forward(state)
        with torch.no_grad():
            err = (project(out.keypoints, batch.K) - batch.keypoints).norm(dim=-1)
            weights = batch.confidence * (batch.confidence >= self.config.init.keypoint_conf)
            reprojection = (err * weights).sum(-1) / weights.sum(-1).clamp(min=1e-9)
            visible = torch.gather(out.vertices, 1, problem.vertex_ids[..., None].expand(-1, -1, 3))
            d_vp = nearest_sq_distances(visible, problem.points, problem.point_mask).sqrt()
            d_pv = nearest_sq_distances(problem.points, visible, problem.vertex_mask).sqrt()
            args = state.body_args(self.model)
            centers = self.model.rotation_center(args[0], state.transl)
        as_np = {name: t.cpu().double().numpy() for name, t in zip(PARAM_FIELDS, args)}
        fits = []
        for i, p in enumerate(batch.people):
            n_v, n_p = int(problem.vertex_mask[i].sum()), int(problem.point_mask[i].sum())
            chamfer = 0.5 * float(d_vp[i, :n_v].mean() + d_pv[i, :n_p].mean()) if n_v and n_p else float("nan")
            to_mesh = float(d_pv[i, :n_p].mean()) if n_v and n_p else float("nan")
            if batch.use_lidar[i] and to_mesh > self.config.lidar_mismatch_m:
                batch.flags[i].add(FLAG_LIDAR_MISMATCH)
            fits.append(BodyFit(
                person_id=p.person_id,
                params=BodyParams(self.model.name, *(as_np[n][i] for n in PARAM_FIELDS)),
                joint_names=list(self.model.joint_names),
                vertices=out.vertices[i].cpu().numpy().astype(np.float32),
                keypoints3d=out.keypoints[i].cpu().numpy().astype(np.float32),
                joints=out.joints[i].cpu().numpy().astype(np.float32),
                rotation_center=centers[i].cpu().double().numpy(),
                quality=FitQuality(
                    reprojection_px=float(reprojection[i]),
                    chamfer_m=chamfer,
                    num_points=n_p,
                    visible_parts=[name for name, occ in zip(PART_NAMES, batch.occluded_image[i]) if not occ],
                    icp_converged=bool(batch.icp_ok[i]),
                    final_loss=float(batch.final_loss[i]),
                    points_to_mesh_m=to_mesh,
                ),
                flags=batch.flags[i],
            ))
        return fits

    # -- helpers -----------------------------------------------------------------------------------------
    def _tensor(self, rows: list[np.ndarray]) -> torch.Tensor:
        return torch.as_tensor(np.stack(rows), dtype=self.dtype, device=self.device)

    def _forward(self, state: FitState, vertex_index: torch.Tensor | None = None):
        with torch.no_grad():
            return self.model(*state.body_args(self.model), vertex_index=vertex_index)

    def _move(self, state: FitState, i: int, T: np.ndarray, vertices: np.ndarray | None = None) -> None:
        """Move person i's body by the rigid transform T (camera frame), and its row of `vertices` with it."""
        if vertices is not None:
            vertices[i] = (vertices[i] @ T[:3, :3].T + T[:3, 3]).astype(vertices.dtype)
        with torch.no_grad():
            shape = self.model.shape_from_free(state.shape[i : i + 1])
            center = self.model.rotation_center(shape, state.transl[i : i + 1])[0]
            root, transl, _ = move_body(state.root_orient[i].cpu().double().numpy(),
                                        state.transl[i].cpu().double().numpy(), center.cpu().double().numpy(), T)
            state.root_orient[i] = torch.as_tensor(root, dtype=self.dtype, device=self.device)
            state.transl[i] = torch.as_tensor(transl, dtype=self.dtype, device=self.device)

    def surface_distances(self, person: PersonObservation, vertices: np.ndarray,
                          lidar_origin: np.ndarray | None = None) -> tuple[float, float]:
        """(chamfer, points to mesh), m, of any body's `vertices` (V, 3) against `person`'s points, by the
        rule of a fit's `FitQuality.chamfer_m` and `points_to_mesh_m`: the vertices that Eq. 1 (from the
        LiDAR at `lidar_origin`) and the keypoint rule leave visible, but all of them and all points,
        where a fit's quality uses the subsamples its L_3D used (`chamfer_max_vertices`, `_points`; fewer
        vertices lie farther from a point). For scoring bodies alike: the bench's fits and true bodies
        (what a perfect fit would read). nan without points or visible vertices."""
        vis = self.config.visibility
        origin = np.zeros(3) if lidar_origin is None else np.asarray(lidar_origin, np.float64)
        occluded = occluded_parts(person.keypoints[:, 2], vis.keypoint_conf_lidar)
        vertices = np.asarray(vertices, np.float64)
        visible = vertices[visible_vertices(vertices, self.faces_np, self.part_of_face_np, origin,
                                            vis.culling_threshold, occluded)]
        points = np.asarray(person.points, np.float64)
        if not len(visible) or not len(points):
            return float("nan"), float("nan")
        # the same nearest-neighbour search as the fit's own quality (`_results`)
        v, x = torch.as_tensor(visible)[None], torch.as_tensor(points)[None]
        to_points = nearest_sq_distances(v, x, torch.ones(x.shape[:2], dtype=torch.bool)).sqrt().mean()
        to_mesh = nearest_sq_distances(x, v, torch.ones(v.shape[:2], dtype=torch.bool)).sqrt().mean()
        return 0.5 * float(to_points + to_mesh), float(to_mesh)

    def _visible_masks(self, batch: Batch, verts: np.ndarray) -> list[np.ndarray]:
        """Per person, (V,) bool: the vertices L_3D and ICP use (Eq. 1 and the keypoint rule)."""
        if not batch.options.use_visibility:
            return [np.ones(len(v), dtype=bool) for v in verts]
        threshold = self.config.visibility.culling_threshold
        return [visible_vertices(verts[i], self.faces_np, self.part_of_face_np, batch.lidar_origin, threshold,
                                 batch.occluded_lidar[i]) for i in range(batch.size)]

    def _depth_from_points(self, person: PersonObservation, K: np.ndarray) -> bool:
        """Whether the person's points gave their depth: `min_points_depth` of them, or, for the built-in
        initializer, fewer that the image agrees with (`initializer.depth_from_few_points`)."""
        if len(person.points) >= self.config.min_points_depth:
            return True
        return person.init is None and initializer.depth_from_few_points(person, K, self.config.init)

    def _depth_bound(self, person: PersonObservation, K: np.ndarray) -> float:
        """How deep the scan lets a person fitted without L_3D from the built-in start, their depth not
        measured by points (`_depth_from_points`), be (`initializer.scan_depth_bound`; inf: any)."""
        bound = None if person.init is not None else initializer.scan_depth_bound(person, K, self.config.init)
        return np.inf if bound is None else bound

    def _problem(self, batch: Batch, max_vertices: int | None = None) -> FitProblem:
        """The batched observations of the current bodies: visible vertices (subsampled to `max_vertices`,
        default the profile's `chamfer_max_vertices`), points, priors."""
        opt = self.config.optimizer
        max_vertices = opt.chamfer_max_vertices if max_vertices is None else max_vertices
        verts = batch.vertices if batch.vertices is not None else self._forward(batch.state).vertices.cpu().numpy()
        batch.vertices = None  # the stages move the bodies next
        masks = self._visible_masks(batch, verts)
        K = batch.K.cpu().double().numpy()
        vertex_rows, point_rows = [], []
        for i, p in enumerate(batch.people):
            index = np.flatnonzero(masks[i])
            index = index[_subsample(len(index), max_vertices, self.config.seed)]
            points = p.points[_subsample(len(p.points), opt.chamfer_max_points, self.config.seed)]
            vertex_rows.append(index if batch.use_lidar[i] else index[:0])
            point_rows.append(points if batch.use_lidar[i] else points[:0])
        # the vertices any person's L_3D uses are the only ones posed per step
        subset, positions = np.unique(np.concatenate(vertex_rows + [np.zeros(0, np.int64)]), return_inverse=True)
        vidx, vmask = _pad_rows(np.split(positions, np.cumsum([len(r) for r in vertex_rows])[:-1]), 0, 0)
        pts, pmask = _pad_rows(point_rows, 3, 0.0)
        dev = self.device
        # people without L_3D whose points measured the depth (held there), and the others' scan bounds
        measured = [not batch.use_lidar[i] and self._depth_from_points(p, K) for i, p in enumerate(batch.people)]
        bounds = [np.inf if batch.use_lidar[i] or measured[i] else self._depth_bound(p, K)
                  for i, p in enumerate(batch.people)]
        return FitProblem(
            K=batch.K, keypoints=batch.keypoints, confidence=batch.confidence,
            points=torch.as_tensor(pts, dtype=self.dtype, device=dev),
            point_mask=torch.as_tensor(pmask, device=dev),
            vertex_subset=torch.as_tensor(subset, dtype=torch.int64, device=dev),
            vertex_index=torch.as_tensor(vidx, device=dev),
            vertex_mask=torch.as_tensor(vmask, device=dev),
            occluded_joints=torch.as_tensor(batch.occluded_joints, dtype=self.dtype, device=dev),
            init_pose=batch.state.pose.detach().clone(),
            init_transl=batch.state.transl.detach().clone(),
            use_lidar=torch.as_tensor(batch.use_lidar, device=dev),
            depth_measured=torch.as_tensor(measured, dtype=torch.bool, device=dev),
            depth_bound=torch.as_tensor(bounds, dtype=self.dtype, device=dev),
            pixel_scale=self._pixel_scale(batch),
            neutral_scale=self._neutral_scale(batch),
            lidar_gain=self._lidar_gain(batch),
            up=torch.as_tensor(np.stack([p.ground[:3] if p.ground is not None else (0.0, -1.0, 0.0)
                                         for p in batch.people]), dtype=self.dtype, device=dev),
            keypoint_depth=None if batch.keypoint_depth is None else torch.as_tensor(
                batch.keypoint_depth, dtype=self.dtype, device=dev),
            predicted_transl=self._predicted_transl(batch),
            predicted_keypoints=self._predicted_keypoints(batch),
            lidar_origin=torch.as_tensor(batch.lidar_origin, dtype=self.dtype, device=dev),
            # cast only by a stage whose own weights use L_free (`solver.uses_free_space`): the init's
            # refinement has its own weight (`init.refine_free_space`)
            cast_beams=(functools.partial(self._blocked_beams, batch, vertex_rows, point_rows)
                        if batch.use_lidar.any() else None),
        )

    def _blocked_beams(self, batch: Batch, vertex_rows: list[np.ndarray], point_rows: list[np.ndarray],
                       state: FitState) -> free_space.BlockedBeams | None:
        """The beams (to `point_rows`) that the bodies of `state` block (`free_space.blocked_beams`), each
        tied to the nearest of its person's `vertex_rows` (their L_3D vertices); None without any."""
        origin, margin = batch.lidar_origin, self.config.optimizer.free_space_margin_m
        verts = self._forward(state).vertices.cpu().double().numpy()
        masks = self._visible_masks(batch, verts)
        found = []
        for i in range(batch.size):
            hits, direction, limit = free_space.blocked_beams(verts[i], self.faces_np, self._around, masks[i],
                                                              point_rows[i], origin, margin)
            row, limit = free_space.tie_to_vertices(verts[i][vertex_rows[i]], hits, direction, limit, origin)
            found.append((row, direction, limit))
        if not any(len(f[0]) for f in found):
            return None
        rows, mask = _pad_rows([f[0] for f in found], 0, 0)
        direction, _ = _pad_rows([f[1] for f in found], 3, 0.0)
        limit = _pad_rows([f[2][:, None] for f in found], 1, 0.0)[0][..., 0]
        dev, dt = self.device, self.dtype
        return free_space.BlockedBeams(
            torch.as_tensor(rows, device=dev), torch.as_tensor(direction, dtype=dt, device=dev),
            torch.as_tensor(limit, dtype=dt, device=dev), torch.as_tensor(mask, device=dev))

    def _predicted_transl(self, batch: Batch) -> torch.Tensor | None:
        """(B, 3) the translations the motion hold keeps each person near: the start's, for people whose
        start (`init`, a warm start) was placed at their predicted pelvis; NaN rows for the others; None
        when the profile has no hold or nobody such a start."""
        if self.config.optimizer.weights.motion <= 0:
            return None
        rows = [np.asarray(p.init.transl, np.float64) if p.predicted_pelvis is not None and p.init is not None
                and not batch.builtin[i] else np.full(3, np.nan) for i, p in enumerate(batch.people)]
        if all(np.isnan(r).all() for r in rows):
            return None
        return self._tensor(rows)

    def _predicted_keypoints(self, batch: Batch) -> torch.Tensor | None:
        """(B, 17, 3) the joints the joint motion hold keeps each person near (`predicted_keypoints`), for
        people with a warm start (`init`, placed at their predicted pelvis) that came with them; NaN rows for
        the others; None when the profile has no such hold or nobody such a prediction."""
        if self.config.optimizer.weights.joint_motion <= 0:
            return None
        rows = [np.asarray(p.predicted_keypoints, np.float64) if p.predicted_keypoints is not None
                and p.predicted_pelvis is not None and p.init is not None and not batch.builtin[i]
                else np.full((17, 3), np.nan) for i, p in enumerate(batch.people)]
        if all(np.isnan(r).all() for r in rows):
            return None
        return self._tensor(rows)

    def _lidar_gain(self, batch: Batch) -> torch.Tensor | None:
        """(B,) the factor on each person's λ_3D² in the mesh and image stages: clip(points /
        `chamfer_points_ref`, 1, `chamfer_gain_max`) (None: off). L_3D is a mean over the points, so
        without it a person with 20 points and one with 500 give the LiDAR the same say against the
        image; with it, as many points as a VLP-16 puts on a person 10 m out keep the plain weight,
        where a pull harder than that cost accuracy, and four times as many or more, on whom the
        image's noise costs more than the points' own, get four times the weight (docs/benchmarks.md,
        "The LiDAR's say grows with its points")."""
        opt = self.config.optimizer
        if opt.chamfer_points_ref <= 0:
            return None
        n = np.array([len(p.points) for p in batch.people], dtype=np.float64)
        gain = np.clip(n / opt.chamfer_points_ref, 1.0, opt.chamfer_gain_max)
        return torch.as_tensor(gain, dtype=self.dtype, device=self.device)

    def _neutral_scale(self, batch: Batch) -> torch.Tensor | None:
        """(B,) max(1, `neutral_reference_px` / each person's expected height in the image (f · stature /
        depth)), the factor on their neutral-pose prior weight: the fewer pixels (and, with them, points) a
        person has, the less the data say about their limbs; None when the profile keeps it constant."""
        reference = self.config.optimizer.neutral_reference_px
        return None if reference <= 0 else self._over_expected_height(batch, reference).clamp(min=1.0)

    def _pixel_scale(self, batch: Batch) -> torch.Tensor | None:
        """(B,) reference height / each person's expected height in the image (f · stature / depth), the
        factor on their pixel residuals; None when the profile works in raw pixels."""
        reference = self.config.optimizer.pixel_reference_px
        return None if reference <= 0 else self._over_expected_height(batch, reference)

    def _over_expected_height(self, batch: Batch, reference_px: float) -> torch.Tensor:
        """(B,) `reference_px` / each person's expected height in the image, f · `init.body_height` / depth
        (depth: the body's rotation centre's z)."""
        with torch.no_grad():
            shape = self.model.shape_from_free(batch.state.shape)
            depth = self.model.rotation_center(shape, batch.state.transl)[:, 2].clamp(min=0.3)
        f = 0.5 * (batch.K[0, 0] + batch.K[1, 1])
        return reference_px * depth / (f * self.config.init.body_height)


def _pick_hypotheses(fits: list[BodyFit], owner: np.ndarray, people: int, margin: float = 1.0) -> list[BodyFit]:
    """Per person (`owner`: each fit's person), the fit of their first row (the hypothesis that led after
    the joint refinement) unless another's final loss is below `margin` times its own; diverged or
    non-finite rows count as an infinite loss (a diverged leader gives way to any finite fit)."""
    def loss(r: int) -> float:
        value = fits[r].quality.final_loss
        return value if FLAG_DIVERGED not in fits[r].flags and np.isfinite(value) else np.inf

    picked = []
    for i in range(people):
        rows = np.flatnonzero(owner == i)
        best = min(rows[1:], key=loss, default=rows[0])
        picked.append(fits[best] if loss(best) < margin * loss(rows[0]) else fits[rows[0]])
    return picked


def _refine_profile(cfg: FittingConfig):
    opt = cfg.optimizer
    weights = dataclasses.replace(opt.weights, pose=cfg.init.refine_pose_weight, free_space=cfg.init.refine_free_space)
    # Adam runs every refinement step (its loss creeps down for long); LM stops each person on its own
    tol = opt.early_stop_rel_tol if opt.optimizer == "lm" else 0.0
    return dataclasses.replace(opt, lr=cfg.init.refine_lr, weights=weights, early_stop_rel_tol=tol)
