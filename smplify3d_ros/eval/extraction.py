"""`smplify3d bench-extract`: precision and recall of person point extraction on simulated scenes.

Each scene comes from the simulator (`smplify3d_ros.sim.world.simulate_scene`), whose per-point labels
say which person (if any) every LiDAR return hit. Per detected person the bench compares the extracted
points with that person's labelled points over the whole scan (so points outside the image, and shoe
soles within `ground_clearance_m` of the floor, count as misses). The target set is people at 2 to 12 m
who are at least half visible: there precision should reach 0.95 and recall 0.90. The bench reports;
it does not assert.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from smplify3d_ros.cli import at_least
from smplify3d_ros.fitting.config import InitConfig
from smplify3d_ros.keypoints import HIP_INDICES
from smplify3d_ros.lidar.config import ExtractionConfig
from smplify3d_ros.sim.config import SimConfig

TARGET_DISTANCE_M = (2.0, 12.0)  # the target set: people at these distances ...
TARGET_VISIBLE = 0.5  # ... at least this visible
TARGET_PRECISION, TARGET_RECALL = 0.95, 0.90
DISTANCE_BINS_M = (0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, np.inf)  # rows of the summary table


@dataclass
class Case:
    """One person in one scene."""

    scene: int  # the scene's seed
    person_id: int
    distance_m: float  # horizontal distance camera -> hip midpoint
    visible_fraction: float  # simulator's fraction of the person not occluded in the image
    n_true: int  # scan points that hit this person
    n_extracted: int
    n_correct: int  # extracted points that hit this person
    precision: float  # n_correct / n_extracted (1.0 when nothing was extracted)
    recall: float  # n_correct / n_true (1.0 when the person has no points)

    @property
    def in_target(self) -> bool:
        lo, hi = TARGET_DISTANCE_M
        return lo <= self.distance_m <= hi and self.visible_fraction >= TARGET_VISIBLE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--json", type=Path, default=None, help="write the results to this JSON file")
    parser.add_argument("--scenes", type=at_least(1), default=30, help="number of simulated scenes")
    parser.add_argument("--seed", type=at_least(0), default=0, help="seed of the first scene")
    parser.add_argument("--params", metavar="PROFILE", default=None, help="params profile name or YAML path")
    parser.add_argument("--sensor", default="vlp16", help="simulated LiDAR (sim.lidar.sensors key)")


def evaluate_scene(seed: int, sim_config: SimConfig, config: ExtractionConfig, sensor: str,
                   init: InitConfig | None = None) -> tuple[list[Case], float]:
    """Cases of one simulated scene and the extraction time (s); `init`: the fitter's initializer settings,
    whose image-size bound on each person's depth the extraction applies as the node's does."""
    from smplify3d_ros.frame_fitter import extract_frame_people  # torch and trimesh: not at import
    from smplify3d_ros.sim.world import simulate_scene

    sim = simulate_scene(seed, sim_config, sensor=sensor)
    frame = sim.frame
    start = time.perf_counter()
    _, result = extract_frame_people(frame, config, init=init)
    elapsed = time.perf_counter() - start
    truth = np.asarray(sim.point_labels)
    people = {p.person_id: p for p in sim.people}
    cases = []
    for k, pid in enumerate(np.asarray(frame.person_ids).tolist()):
        extracted = result.people[k].indices
        n_true = int(np.sum(truth == pid))
        n_correct = int(np.sum(truth[extracted] == pid))
        hips = np.asarray(people[pid].keypoints3d)[list(HIP_INDICES)].mean(axis=0) if pid in people else None
        distance = float(np.hypot(hips[0], hips[2])) if hips is not None else float("nan")
        cases.append(Case(
            scene=seed, person_id=int(pid), distance_m=distance,
            visible_fraction=float(sim.visible_fraction.get(pid, float("nan"))),
            n_true=n_true, n_extracted=len(extracted), n_correct=n_correct,
            precision=n_correct / len(extracted) if len(extracted) else 1.0,
            recall=n_correct / n_true if n_true else 1.0,
        ))
    return cases, elapsed


def summarize(cases: list[Case]) -> dict[str, float]:
    """Point-weighted (micro) precision and recall over cases, and the number of cases."""
    extracted = sum(c.n_extracted for c in cases)
    true = sum(c.n_true for c in cases)
    correct = sum(c.n_correct for c in cases)
    return {
        "precision": correct / extracted if extracted else 1.0,
        "recall": correct / true if true else 1.0,
        "cases": len(cases),
        "cases_below_target": sum(c.precision < TARGET_PRECISION or c.recall < TARGET_RECALL for c in cases),
    }


def print_report(cases: list[Case], timing_ms: float) -> None:
    print(f"{'distance m':>12} {'cases':>6} {'precision':>10} {'recall':>8} {'pts/person':>11}")
    for lo, hi in itertools.pairwise(DISTANCE_BINS_M):
        rows = [c for c in cases if lo <= c.distance_m < hi]
        if rows:
            s = summarize(rows)
            mean_true = np.mean([c.n_true for c in rows])
            print(f"{lo:>5.0f} - {hi:<4.0f} {s['cases']:>6d} {s['precision']:>10.3f} {s['recall']:>8.3f} "
                  f"{mean_true:>11.0f}")
    target = [c for c in cases if c.in_target]
    for name, rows in (("all", cases), ("target", target)):
        s = summarize(rows)
        print(f"{name:>12} {s['cases']:>6d} {s['precision']:>10.3f} {s['recall']:>8.3f}")
    lo, hi = TARGET_DISTANCE_M
    print(f"target: people at {lo:.0f}-{hi:.0f} m, >= {TARGET_VISIBLE:.0%} visible; "
          f"goal precision >= {TARGET_PRECISION}, recall >= {TARGET_RECALL}")
    worst = sorted(target, key=lambda c: min(c.precision - TARGET_PRECISION, c.recall - TARGET_RECALL))[:8]
    worst = [c for c in worst if c.precision < TARGET_PRECISION or c.recall < TARGET_RECALL]
    if worst:
        print("target cases below goal (scene, person, distance, visible, n_true, n_extracted, P, R):")
        for c in worst:
            print(f"  {c.scene:>5d} {c.person_id:>3d} {c.distance_m:6.2f} {c.visible_fraction:5.2f} "
                  f"{c.n_true:>5d} {c.n_extracted:>5d} {c.precision:6.3f} {c.recall:6.3f}")
    print(f"extraction time: median {timing_ms:.2f} ms per scan")


def run(args: argparse.Namespace) -> int:
    from smplify3d_ros.config import load_config
    from smplify3d_ros.sim.config import load_sim_config

    config, sim = load_config(args.params), load_sim_config(args.params)
    cases: list[Case] = []
    times = []
    for seed in range(args.seed, args.seed + args.scenes):
        scene_cases, elapsed = evaluate_scene(seed, sim, config.lidar, args.sensor, config.fitting.init)
        cases += scene_cases
        times.append(elapsed)
    timing_ms = 1000.0 * float(np.median(times)) if times else 0.0
    print_report(cases, timing_ms)
    target = summarize([c for c in cases if c.in_target])
    if args.json is not None:
        report = {
            "precision": target["precision"],  # target set: 2-12 m, at least half visible
            "recall": target["recall"],
            "timing_ms": timing_ms,  # median extraction time per scan
            "target": target,
            "all": summarize(cases),
            "scenes": args.scenes,
            "seed": args.seed,
            "sensor": args.sensor,
            "cases": [asdict(c) | {"in_target": c.in_target} for c in cases],
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2))
        print(f"wrote {args.json}")
    return 0


def main() -> int:  # `python -m smplify3d_ros.eval.extraction`
    parser = argparse.ArgumentParser(prog="smplify3d bench-extract", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args())


if __name__ == "__main__":
    raise SystemExit(main())
