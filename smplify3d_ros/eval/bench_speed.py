"""`smplify3d bench-speed`: per-person fit time and accuracy of the optimizer profiles on the robot path.

The people are what a robot without an image-HMR network fits: simulated scenes (`sim.world`, VLP-16 by
default, 3-8 m), observed by the node's frame path (`FrameFitter.observe`: keypoints from the detector
model, each person's points cut out of the scan) and fitted from the built-in initializer. The first
`--people` detected people with LiDAR points of consecutive seeds are kept.

For each profile (thesis and robot, both in one run, one torch thread) and batch size (1: each person
alone; 5: the people together, as one frame): after a warm-up, `--repeats` timed fits; the row reports
the median wall time per person (batch 1: the median over every person and repeat; batch 5: the median
batch time over the repeats, divided by the batch) and the MPJPE of the fitted bodies.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from smplify3d_ros.cli import at_least


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", help="write the rows to this JSON file")
    parser.add_argument("--repeats", type=at_least(1), default=5,
                        help="timed fits per person or batch (median reported)")
    parser.add_argument("--profiles", nargs="+", default=["thesis", "robot"])
    parser.add_argument("--batches", nargs="+", type=at_least(1), default=[1, 5])
    parser.add_argument("--people", type=at_least(1), default=5,
                        help="people fitted (the largest batch is capped to it)")
    parser.add_argument("--seed", type=at_least(0), default=0, help="first scene seed")
    parser.add_argument("--sensor", default="vlp16", help="simulated LiDAR (sim.lidar.sensors key)")
    parser.add_argument("--distance", default="3,8", help="people's distance range, m (MIN,MAX)")
    parser.add_argument("--params", help="params profile or YAML file (default: jackal_vlp16)")


def robot_path_people(config, sim_config, args) -> tuple[list, list, np.ndarray]:
    """(observations without an initial estimate, their true joints, K) of the first `args.people` people
    with LiDAR points in consecutive simulated scenes."""
    from smplify3d_ros.frame_fitter import FrameFitter
    from smplify3d_ros.sim.world import simulate_scene

    low, high = (float(x) for x in args.distance.split(","))
    observer = FrameFitter(config, fitter=_NoFitter())
    people, joints, K = [], [], None
    seed = args.seed
    while len(people) < args.people:
        sim = simulate_scene(seed, sim_config, sensor=args.sensor, n_people=3, distance_range=(low, high))
        truth = {p.person_id: p for p in sim.people}
        for obs in observer.observe(sim.frame).observations:
            if obs.person_id in truth and len(obs.points) >= config.fitting.min_points and len(people) < args.people:
                people.append(dataclasses.replace(obs, person_id=len(people), init=None))
                joints.append(np.asarray(truth[obs.person_id].joints, np.float64))
                K = sim.frame.camera.K
        seed += 1
    return people, joints, K


class _NoFitter:
    """Stands in for a `Fitter` where only `FrameFitter.observe` is used."""


def time_fits(fitter, groups: list[list], K: np.ndarray, repeats: int) -> tuple[list[float], list]:
    """Seconds per person of each timed fit of each group (after one warm-up each), and the last fits."""
    per_person, fits = [], []
    for group in groups:
        fitter.fit(group, K)  # warm-up: caches, first-call allocations
        for _ in range(repeats):
            start = time.perf_counter()
            result = fitter.fit(group, K)
            per_person.append((time.perf_counter() - start) / len(group))
        fits += result
    return per_person, fits


def run(args: argparse.Namespace) -> int:
    from smplify3d_ros.body import load_body_model
    from smplify3d_ros.config import load_config
    from smplify3d_ros.fitting.fitter import Fitter
    from smplify3d_ros.runtime.heap import freeze_startup_heap
    from smplify3d_ros.sim.config import load_sim_config

    base = load_config(args.params)
    model = load_body_model(base.fitting.body.model, base.fitting.body)
    people, joints, K = robot_path_people(base, load_sim_config(args.params), args)
    rows = []
    for profile in args.profiles:
        config = load_config(args.params, {"fitting": {"profile": profile, "num_threads": 1}}).fitting
        fitter = Fitter(config, model)
        freeze_startup_heap()  # as the node does after startup (runtime/heap.py)
        for batch in args.batches:
            batch = min(batch, len(people))
            groups = [[p] for p in people] if batch == 1 else [people[i : i + batch]
                                                                for i in range(0, len(people) - batch + 1, batch)]
            seconds, fits = time_fits(fitter, groups, K, args.repeats)
            errors = [1000.0 * np.linalg.norm(f.joints - joints[f.person_id], axis=1).mean() for f in fits]
            row = {
                "profile": profile,
                "batch": batch,
                "people": len(fits),
                "ms_per_person": round(1000.0 * float(np.median(seconds)), 1),
                "mpjpe_mm": round(float(np.mean(errors)), 1),
            }
            rows.append(row)
            print(f"{profile:8s} batch {batch}: {row['ms_per_person']:8.1f} ms/person (median)   "
                  f"MPJPE {row['mpjpe_mm']:6.1f} mm over {row['people']} people", flush=True)
    _compare(rows, args.batches)
    if args.json:
        meta = {"sensor": args.sensor, "distance_m": args.distance, "seed": args.seed, "repeats": args.repeats,
                "torch_threads": 1, "init": "built-in (robot path)"}
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump({"rows": rows, "meta": meta}, handle, indent=2)
    return 0


def _compare(rows: list[dict], batches: list[int]) -> None:
    by = {(r["profile"], r["batch"]): r for r in rows}
    for b in sorted({r["batch"] for r in rows}):
        if ("thesis", b) in by and ("robot", b) in by:
            t, r = by[("thesis", b)], by[("robot", b)]
            print(f"batch {b}: robot is {t['ms_per_person'] / r['ms_per_person']:.1f}x faster than thesis, "
                  f"MPJPE {r['mpjpe_mm']:.1f} vs {t['mpjpe_mm']:.1f} mm")
