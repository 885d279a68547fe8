"""How wrong the simulated image-HMR estimate is (`sim.hmr.simulate_hmr`), measured like an HMR paper."""

from __future__ import annotations

import numpy as np

from smplify3d_ros.body.joints import JOINT_INDEX
from smplify3d_ros.camera import project_points
from smplify3d_ros.eval.metrics import mpjpe, pa_mpjpe, pve, root_aligned
from smplify3d_ros.sim.camera import make_camera
from smplify3d_ros.sim.config import SimConfig
from smplify3d_ros.sim.hmr import simulate_hmr
from smplify3d_ros.sim.world import random_people


def hmr_statistics(model, cfg: SimConfig, n: int = 100, seed: int = 0) -> dict[str, float]:
    """Errors of the simulated HMR over `n` random people at `cfg.hmr.calibration_distance_m`.

    Returns means over people: MPJPE root-aligned (hip midpoint), MPJPE unaligned and PA-MPJPE over the
    model's 19 joints, PVE root-aligned and unaligned (mm), the mean absolute depth error of the pelvis
    (mm) and the mean 2D error of the projected COCO keypoints (px, `cfg.camera`).
    """
    rng = np.random.default_rng(seed)
    camera = make_camera(cfg.camera)
    hips = (JOINT_INDEX["left_hip"], JOINT_INDEX["right_hip"])
    rows = []
    batch = 8
    while len(rows) < n:
        _, people = random_people(rng, cfg, model, batch, cfg.hmr.calibration_distance_m)
        gt = [(p.params, p.joints.astype(np.float64)) for p in people]
        est = simulate_hmr(rng, model, gt, cfg.hmr)
        for k, (person, body) in enumerate(zip(people, model.posed(est), strict=True)):
            pj, pv = body.joints, body.vertices
            gj, gv = person.joints.astype(np.float64), person.vertices.astype(np.float64)
            offset = gj[list(hips)].mean(0) - pj[list(hips)].mean(0)
            uv_p = project_points(body.keypoints3d, camera)
            uv_g = project_points(person.keypoints3d, camera)
            rows.append(
                [
                    mpjpe(root_aligned(pj, gj, hips), gj),
                    mpjpe(pj, gj),
                    pa_mpjpe(pj, gj),
                    pve(pv + offset, gv),
                    pve(pv, gv),
                    1000.0 * abs(np.linalg.norm(est[k].transl) - np.linalg.norm(person.params.transl)),
                    float(np.nanmean(np.linalg.norm(uv_p - uv_g, axis=1))),
                ]
            )
    keys = (
        "mpjpe_root_aligned_mm",
        "mpjpe_mm",
        "pa_mpjpe_mm",
        "pve_root_aligned_mm",
        "pve_mm",
        "pelvis_depth_error_mm",
        "keypoint_reprojection_px",
    )
    values = np.asarray(rows[:n])
    return {k: float(v) for k, v in zip(keys, values.mean(axis=0))}
