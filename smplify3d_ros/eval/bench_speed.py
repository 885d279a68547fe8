"""`smplify3d bench-speed`: per-person fit time and accuracy of the optimizer profiles on synthetic people.

For each profile (thesis, robot) and batch size (1, 4): fit the same synthetic people (see
`eval.synthetic`: 300 surface points with 1 cm noise, keypoints with 3 px noise, init = truth pushed
0.5 m in depth with 20° on every limb joint), after a warm-up, `--repeats` times; report the median wall
time divided by the batch size and the MPJPE over all fitted people.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--repeats", type=int, default=20, help="timed fits per row (median reported)")
    parser.add_argument("--profiles", nargs="+", default=["thesis", "robot"])
    parser.add_argument("--batches", nargs="+", type=int, default=[1, 4])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--params", help="params profile or YAML file (default: jackal_vlp16)")


def run(args: argparse.Namespace) -> int:
    import torch

    from smplify3d_ros.body import load_body_model
    from smplify3d_ros.config import load_config
    from smplify3d_ros.eval.synthetic import default_intrinsics, make_person, perturb
    from smplify3d_ros.fitting.fitter import Fitter

    torch.set_num_threads(max(1, torch.get_num_threads()))
    base = load_config(args.params)
    model = load_body_model(base.fitting.body.model, base.fitting.body)
    K = default_intrinsics()
    rng = np.random.default_rng(args.seed)
    people = []
    for i in range(max(args.batches)):
        sp = make_person(model, rng, K, distance=rng.uniform(3.0, 8.0), yaw=rng.uniform(-1.0, 1.0),
                         n_points=300, point_noise=0.01, keypoint_noise_px=3.0, person_id=i)
        sp.observation.init = perturb(model, sp.truth, rng, depth_m=0.5, limb_deg=20.0)
        people.append(sp)
    rows = []
    for profile in args.profiles:
        fitter = Fitter(load_config(args.params, {"fitting": {"profile": profile}}).fitting, model)
        for batch in args.batches:
            group = people[:batch]
            obs = [p.observation for p in group]
            fits = fitter.fit(obs, K)  # warm-up
            times = []
            for _ in range(args.repeats):
                start = time.perf_counter()
                fits = fitter.fit(obs, K)
                times.append(time.perf_counter() - start)
            errors = [np.linalg.norm(f.joints - p.joints, axis=1).mean() for f, p in zip(fits, group)]
            row = {
                "profile": profile,
                "batch": batch,
                "ms_per_person": round(1000.0 * float(np.median(times)) / batch, 1),
                "mpjpe_mm": round(1000.0 * float(np.mean(errors)), 1),
            }
            rows.append(row)
            print(f"{profile:8s} batch {batch}: {row['ms_per_person']:8.1f} ms/person   "
                  f"MPJPE {row['mpjpe_mm']:6.1f} mm", flush=True)
    by = {(r["profile"], r["batch"]): r for r in rows}
    if ("thesis", 1) in by and ("robot", 1) in by:
        for b in args.batches:
            t, r = by[("thesis", b)], by[("robot", b)]
            print(f"batch {b}: robot is {t['ms_per_person'] / r['ms_per_person']:.1f}x faster than thesis, "
                  f"MPJPE {100.0 * (r['mpjpe_mm'] / t['mpjpe_mm'] - 1.0):+.1f}%")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump({"rows": rows}, handle, indent=2)
    return 0
