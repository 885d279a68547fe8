"""Frame -> BodyFit[]: the thesis's steps in order, batched over the people of a frame.

    init -> visibility -> ICP -> stages (scale, mesh, image) -> BodyFit

`fit_frame` takes a whole `Frame` (it undistorts the keypoints and extracts each person's LiDAR points)
or a list of `PersonObservation` already in the camera frame.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass

import numpy as np
import roma
import torch

from smplify3d_ros.body import BodyModel, load_body_model
from smplify3d_ros.camera import transform_points, undistort_pixels
from smplify3d_ros.config import Config, load_config
from smplify3d_ros.fitting import init as initializer
from smplify3d_ros.fitting.config import FittingConfig
from smplify3d_ros.fitting.icp import align_mesh_to_points
from smplify3d_ros.fitting.stages import FitProblem, FitState, StageSpec, optimize, run_stage
from smplify3d_ros.fitting.visibility import occluded_parts, visible_vertices
from smplify3d_ros.keypoints import PART_NAMES
from smplify3d_ros.types import (
    FLAG_DIVERGED,
    FLAG_EXTERNAL_INIT,
    FLAG_FEW_KEYPOINTS,
    FLAG_ICP_NOT_CONVERGED,
    FLAG_IMAGE_ONLY,
    BodyFit,
    BodyParams,
    CameraModel,
    FitQuality,
    Frame,
    PersonObservation,
)

log = logging.getLogger(__name__)


@dataclass
class FitOptions:
    """Switches used by the benchmark's baselines and ablations (the defaults are the method)."""

    optimize: bool = True  # run the stages (False: init + ICP only)
    use_icp: bool = True
    use_chamfer: bool = True  # L_3D (ablation: no L_3D)
    use_occlusion_prior: bool = True  # L_θocc (ablation)
    use_visibility: bool = True  # visibility filter (ablation: every vertex used by L_3D)


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        log.warning("device 'cuda' requested but unavailable; using the CPU")
        return torch.device("cpu")
    return torch.device(name)


def _params_tensor(values: list[np.ndarray], device, dtype) -> torch.Tensor:
    return torch.as_tensor(np.stack(values), dtype=dtype, device=device)


def _pad_rows(rows: list[np.ndarray], width: int, fill) -> tuple[np.ndarray, np.ndarray]:
    n = max([len(r) for r in rows] + [0])
    shape = (len(rows), n) + ((width,) if width else ())
    out = np.full(shape, fill, dtype=np.float64 if width else np.int64)
    mask = np.zeros((len(rows), n), dtype=bool)
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
        mask[i, : len(r)] = True
    return out, mask


def _subsample(n: int, limit: int, rng: np.random.Generator) -> np.ndarray:
    if limit <= 0 or n <= limit:
        return np.arange(n)
    return np.sort(rng.choice(n, size=limit, replace=False))


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
        self.dtype = self.model.anat_frames.dtype
        self.faces_np = self.model.faces.cpu().numpy()
        # the built-in initializer starts from the anatomical neutral (standing, arms hanging, limbs
        # straight), not from the model's rest pose (Anny's is an A-pose with bent elbows)
        zeros = torch.zeros(1, len(self.model.joint_names), 3, dtype=self.model.anat_frames.dtype)
        self._neutral_pose = self.model.anatomical_to_pose(zeros, from_neutral=True)[0].cpu().double().numpy()
        self.part_of_face_np = self.model.part_of_face.cpu().numpy()

    # -- helpers -------------------------------------------------------------------------------------
    def _forward(self, state: FitState):
        with torch.no_grad():
            return self.model(state.shape, state.pose, state.root_orient, state.transl)

    def _state(self, params: list[BodyParams]) -> FitState:
        dev, dt = self.device, self.dtype
        return FitState(
            _params_tensor([p.shape for p in params], dev, dt),
            _params_tensor([p.pose for p in params], dev, dt),
            _params_tensor([p.root_orient for p in params], dev, dt),
            _params_tensor([p.transl for p in params], dev, dt),
        )

    def _apply_rigid(self, state: FitState, i: int, T: np.ndarray) -> None:
        """Move person i's body by the rigid transform T (camera frame)."""
        R = torch.as_tensor(T[:3, :3], dtype=self.dtype, device=self.device)
        t = torch.as_tensor(T[:3, 3], dtype=self.dtype, device=self.device)
        with torch.no_grad():
            center = self.model.rotation_center(state.shape[i : i + 1], state.transl[i : i + 1])[0]
            R_root = roma.rotvec_to_rotmat(state.root_orient[i])
            state.root_orient[i] = roma.rotmat_to_rotvec(R @ R_root)
            state.transl[i] = state.transl[i] + (R @ center + t - center)

    # -- the method ------------------------------------------------------------------------------------
    def fit(
        self,
        people: list[PersonObservation],
        K: np.ndarray,
        lidar_origin: np.ndarray | None = None,
        options: FitOptions | None = None,
    ) -> list[BodyFit]:
        if not people:
            return []
        options = options or FitOptions()
        cfg = self.config
        torch.manual_seed(cfg.seed)
        rng = np.random.default_rng(cfg.seed)
        lidar_origin = np.zeros(3) if lidar_origin is None else np.asarray(lidar_origin, float)
        K = np.asarray(K, dtype=np.float64)
        Kt = torch.as_tensor(K, dtype=self.dtype, device=self.device)
        B = len(people)
        J = len(self.model.joint_names)
        flags: list[set[str]] = [set() for _ in people]
        use_lidar = np.array([len(p.points) >= cfg.min_points for p in people])
        for i, p in enumerate(people):
            if not use_lidar[i]:
                flags[i].add(FLAG_IMAGE_ONLY)
            if (p.keypoints[:, 2] >= cfg.init.keypoint_conf).sum() < cfg.min_keypoints:
                flags[i].add(FLAG_FEW_KEYPOINTS)

        # 1. initial estimate
        params: list[BodyParams] = []
        builtin = []
        for i, p in enumerate(people):
            if p.init is not None and p.init.model == self.model.name:
                params.append(p.init.copy())
                flags[i].add(FLAG_EXTERNAL_INIT)
            else:
                if p.init is not None:
                    log.warning("person %d: initial estimate is for %r, not %r; using the built-in init",
                                p.person_id, p.init.model, self.model.name)
                root, pelvis = initializer.builtin_root(p, K, cfg.init, bool(use_lidar[i]))
                mean = self.model.mean_shape().cpu().numpy()
                params.append(BodyParams(self.model.name, mean, self._neutral_pose.copy(), root, pelvis))
                builtin.append(i)
        state = self._state(params)
        if builtin:  # place the pelvis: the model's rotation centre may not be its pelvis (SMPL)
            with torch.no_grad():
                out = self._forward(state)
                pelvis_now = 0.5 * (out.keypoints[:, 11] + out.keypoints[:, 12])
                target = state.transl.clone()
                rows = torch.as_tensor(builtin, device=self.device)
                state.transl[rows] += target[rows] - pelvis_now[rows]

        keypoints = _params_tensor([p.keypoints[:, :2] for p in people], self.device, self.dtype)
        confidence = _params_tensor([p.keypoints[:, 2] for p in people], self.device, self.dtype)

        # 2. visibility, per person
        vis_image = [occluded_parts(p.keypoints[:, 2], cfg.visibility.keypoint_conf_image) for p in people]
        vis_lidar = [occluded_parts(p.keypoints[:, 2], cfg.visibility.keypoint_conf_lidar) for p in people]
        occluded_joints = np.zeros((B, J), dtype=bool)
        if options.use_occlusion_prior:
            for i, occ in enumerate(vis_image):
                for part_i, is_occ in enumerate(occ):
                    if is_occ:
                        occluded_joints[i, self.model.part_joint_index[part_i]] = True

        def visible_masks(verts: np.ndarray) -> list[np.ndarray]:
            masks = []
            for i in range(B):
                if options.use_visibility:
                    masks.append(visible_vertices(verts[i], self.faces_np, self.part_of_face_np, lidar_origin,
                                                  cfg.visibility.culling_threshold, vis_lidar[i]))
                else:
                    masks.append(np.ones(len(verts[i]), dtype=bool))
            return masks

        def problem_for(state: FitState) -> FitProblem:
            masks = visible_masks(self._forward(state).vertices.cpu().numpy())
            vertex_rows, point_rows = [], []
            for i, p in enumerate(people):
                index = np.flatnonzero(masks[i])
                index = index[_subsample(len(index), cfg.optimizer.chamfer_max_vertices, rng)]
                vertex_rows.append(index if use_lidar[i] else index[:0])
                pts = p.points[_subsample(len(p.points), cfg.optimizer.chamfer_max_points, rng)]
                point_rows.append(pts if use_lidar[i] else pts[:0])
            subset, positions = np.unique(np.concatenate(vertex_rows + [np.zeros(0, np.int64)]),
                                          return_inverse=True)
            splits = np.cumsum([len(r) for r in vertex_rows])[:-1]
            vidx, vmask = _pad_rows(np.split(positions, splits), 0, 0)
            pts, pmask = _pad_rows(point_rows, 3, 0.0)
            return FitProblem(
                K=Kt, keypoints=keypoints, confidence=confidence,
                points=torch.as_tensor(pts, dtype=self.dtype, device=self.device),
                point_mask=torch.as_tensor(pmask, device=self.device),
                vertex_subset=torch.as_tensor(subset, dtype=torch.int64, device=self.device),
                vertex_index=torch.as_tensor(vidx, device=self.device),
                vertex_mask=torch.as_tensor(vmask, device=self.device),
                occluded_joints=torch.as_tensor(occluded_joints, dtype=self.dtype, device=self.device),
                init_pose=state.pose.detach().clone(),
                use_lidar=torch.as_tensor(use_lidar, device=self.device),
            )

        # limb refinement of the built-in init: 2D keypoints and priors only, translation fixed
        if builtin and cfg.init.refine_iterations > 0:
            problem = problem_for(state)
            w = cfg.optimizer.weights
            spec = StageSpec("init", ("pose", "root_orient"), cfg.init.refine_iterations, None,
                             w.sigma_px, 0.0, priors=True)
            refine_profile = _refine_profile(cfg)
            diverged = torch.zeros(B, dtype=torch.bool, device=self.device)
            keep = state.clone()
            run_stage(self.model, state, problem, spec, refine_profile, cfg.divergence_factor, diverged)
            external = torch.as_tensor([i not in builtin for i in range(B)], device=self.device)
            state.copy_rows_from(keep, external)

        # 3. ICP on the LiDAR-visible vertices
        icp_ok = np.ones(B, dtype=bool)
        if options.use_icp and cfg.icp.enabled:
            verts = self._forward(state).vertices.cpu().numpy()
            masks = visible_masks(verts)
            translation_only = dataclasses.replace(cfg.icp, estimate_rotation=False)
            for i, p in enumerate(people):
                if not use_lidar[i]:
                    # too few points for L_3D, but enough to fix the depth along the ray, which the image
                    # cannot (an image HMR's depth errors reach metres)
                    if len(p.points) >= cfg.min_points_depth:
                        result = align_mesh_to_points(verts[i][masks[i]], p.points, translation_only)
                        if result.converged:
                            self._apply_rigid(state, i, result.T)
                    continue
                result = align_mesh_to_points(verts[i][masks[i]], p.points, cfg.icp)
                icp_ok[i] = result.converged
                if result.converged:
                    self._apply_rigid(state, i, result.T)
                else:
                    flags[i].add(FLAG_ICP_NOT_CONVERGED)
                    if np.linalg.norm(result.translation) <= cfg.icp.max_translation:
                        T = np.eye(4)
                        T[:3, 3] = result.translation
                        self._apply_rigid(state, i, T)

        # 4. the stages
        problem = problem_for(state)
        if not options.use_chamfer:
            problem.use_lidar = torch.zeros_like(problem.use_lidar)
        final_loss = torch.full((B,), float("nan"))
        if options.optimize:
            report = optimize(self.model, state, problem, cfg.optimizer, cfg.divergence_factor)
            final_loss = report.final_loss.cpu()
            for i in np.flatnonzero(report.diverged.cpu().numpy()):
                flags[i].add(FLAG_DIVERGED)
        return self._results(people, state, problem, flags, icp_ok, vis_image, final_loss, Kt)

    def _results(self, people, state, problem, flags, icp_ok, vis_image, final_loss, Kt) -> list[BodyFit]:
        from smplify3d_ros.fitting.losses import nearest_sq_distances, project

        out = self._forward(state)
        with torch.no_grad():
            uv = project(out.keypoints, Kt)
            err = (uv - problem.keypoints).norm(dim=-1)
            good = problem.confidence >= self.config.init.keypoint_conf
            weights = problem.confidence * good
            reproj = (err * weights).sum(-1) / weights.sum(-1).clamp(min=1e-9)
            subset_vertices = out.vertices[:, problem.vertex_subset]
            visible = torch.gather(subset_vertices, 1, problem.vertex_index[..., None].expand(-1, -1, 3))
            d_vp = nearest_sq_distances(visible, problem.points, problem.point_mask).sqrt()
            d_pv = nearest_sq_distances(problem.points, visible, problem.vertex_mask).sqrt()
        fits = []
        for i, p in enumerate(people):
            n_v, n_p = int(problem.vertex_mask[i].sum()), int(problem.point_mask[i].sum())
            chamfer = float("nan")
            if n_v and n_p:
                chamfer = 0.5 * float(d_vp[i, :n_v].mean() + d_pv[i, :n_p].mean())
            params = BodyParams(
                self.model.name,
                state.shape[i].cpu().double().numpy(),
                state.pose[i].cpu().double().numpy(),
                state.root_orient[i].cpu().double().numpy(),
                state.transl[i].cpu().double().numpy(),
            )
            quality = FitQuality(
                reprojection_px=float(reproj[i]),
                chamfer_m=chamfer,
                num_points=n_p,
                visible_parts=[name for name, occ in zip(PART_NAMES, vis_image[i]) if not occ],
                icp_converged=bool(icp_ok[i]),
                final_loss=float(final_loss[i]),
            )
            fits.append(BodyFit(
                person_id=p.person_id,
                params=params,
                joint_names=list(self.model.joint_names),
                vertices=out.vertices[i].cpu().numpy().astype(np.float32),
                keypoints3d=out.keypoints[i].cpu().numpy().astype(np.float32),
                joints=out.joints[i].cpu().numpy().astype(np.float32),
                quality=quality,
                flags=flags[i],
            ))
        return fits


def _refine_profile(cfg: FittingConfig):
    opt = cfg.optimizer
    weights = dataclasses.replace(opt.weights, pose=cfg.init.refine_pose_weight)
    return dataclasses.replace(opt, lr=cfg.init.refine_lr, weights=weights, early_stop_rel_tol=0.0)


# -- frame level ---------------------------------------------------------------------------------------
def observations_from_frame(frame: Frame, config: Config) -> tuple[list[PersonObservation], np.ndarray]:
    """Undistort the keypoints, move the scan into the camera frame and cut out each person's points.

    Returns the observations and the LiDAR origin in the camera frame.
    """
    from smplify3d_ros.lidar.extract import extract_people

    camera = frame.camera
    P = len(frame.keypoints)
    undistorted = frame.keypoints.astype(np.float64).copy()
    if P and camera.has_distortion:
        uv = undistort_pixels(frame.keypoints[..., :2].reshape(-1, 2), camera)
        undistorted[..., :2] = uv.reshape(P, -1, 2)
    points_cam = transform_points(frame.points_lidar, frame.T_cam_lidar).astype(np.float32)
    pinhole = CameraModel(camera.K, camera.width, camera.height)
    extraction = extract_people(points_cam, undistorted, pinhole, config.lidar)
    people = []
    for i, person in enumerate(extraction.people):
        pid = int(frame.person_ids[i]) if i < len(frame.person_ids) else -1
        people.append(PersonObservation(
            person_id=pid,
            keypoints=undistorted[i],
            bbox=np.asarray(person.bbox, dtype=np.float64),
            points=person.points,
            density=float(person.density),
            init=frame.init_bodies.get(pid) if pid >= 0 else None,
        ))
    return people, frame.T_cam_lidar[:3, 3].copy()


_FITTERS: dict[int, Fitter] = {}


def fit_frame(
    frame_or_observations: Frame | list[PersonObservation],
    config: Config | None = None,
    K: np.ndarray | None = None,
    options: FitOptions | None = None,
) -> list[BodyFit]:
    """Fit every person of a frame. `config` defaults to the default profile (params/jackal_vlp16.yaml).

    With a list of observations (already in the camera frame, keypoints undistorted) pass `K`.
    """
    config = config or load_config()
    key = id(config.fitting)
    fitter = _FITTERS.get(key)
    if fitter is None:
        fitter = _FITTERS[key] = Fitter(config.fitting)
    if isinstance(frame_or_observations, Frame):
        people, origin = observations_from_frame(frame_or_observations, config)
        return fitter.fit(people, frame_or_observations.camera.K, origin, options)
    if K is None:
        raise ValueError("fit_frame on observations needs the camera intrinsics K")
    return fitter.fit(list(frame_or_observations), K, None, options)
