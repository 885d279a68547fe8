"""`smplify3d bench`: the command line (light to import: `--help` loads no torch)."""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from smplify3d_ros.cli import at_least
from smplify3d_ros.eval.bench.methods import MAIN_METHODS, METHODS, Setup, profile_for, resolve_sensor
from smplify3d_ros.eval.bench.studies import ABLATION_METHODS, STUDIES, BenchRun, Report, run_main, run_study
from smplify3d_ros.settings import to_dict

DEFAULT_OUT = Path("out/bench")  # plots go here unless --plot-dir says otherwise (relative to the working directory)


def _pair(text: str, cast: Callable[[str], Any]) -> tuple[Any, Any]:
    parts = text.replace(",", "-").split("-") if cast is int else text.split(",")
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected MIN{',' if cast is float else '-'}MAX, got {text!r}")
    low, high = cast(parts[0]), cast(parts[1])
    if cast is float and not low > 0:  # distances (NaN fails too)
        raise argparse.ArgumentTypeError(f"distances must be > 0 m, got {text!r}")
    if low > high:
        raise argparse.ArgumentTypeError(f"min > max in {text!r}")
    return low, high


def _override(text: str) -> tuple[str, Any]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE (dotted key), got {text!r}")
    return key, yaml.safe_load(value)


def overrides_from(pairs: Iterable[tuple[str, Any]]) -> dict[str, Any]:
    """[("fitting.profiles.robot.iterations", [1, 2, 1])] -> nested mapping for `load_config`."""
    out: dict[str, Any] = {}
    for key, value in pairs:
        node = out
        parts = key.split(".")
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return out


def merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    out = dict(a)
    for k, v in b.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario", default=None,
        help="scenes (sim.bench.scenarios): robot (default: the Jackal's camera and VLP-16, 1.5-15 m, every pose "
        "family, any heading), outdoor_crowd (3 MP camera, Livox-like LiDAR, 5-10 people at 6-15 m), lab (3-8 m, "
        "the studies' default)",
    )
    parser.add_argument(
        "--sensor", default=None,
        help="simulated LiDAR (default: the scenario's): vlp16, ouster32, ouster64, ouster128 (or os1_64, ...), livox",
    )
    parser.add_argument("--scenes", type=at_least(1), default=40,
                        help="number of seeded scenes (default 40; with --sequences: sequences, give e.g. 2)")
    parser.add_argument("--sequences", nargs="?", const="people", default=None, metavar="SCENARIO",
                        help="track people through 10 Hz sequences (sim.sequence.scenarios, default people) "
                             "instead of single scenes: tracked vs single-frame, with and without detector ids")
    parser.add_argument("--frames", type=at_least(1), default=40, help="frames per sequence (--sequences; default 40)")
    parser.add_argument("--frame-step", type=int, default=1, metavar="N",
                        help="fit every N-th frame of each sequence (--sequences): a node that keeps up with "
                        "10 Hz / N only (default 1)")
    parser.add_argument("--seed", type=at_least(0), default=None,
                        help="seed of the first scene (default: sim.bench.report_seed_start, 1000: the report "
                        "seeds; seeds 0-999 are for tuning)")
    parser.add_argument("--people", type=lambda s: _pair(s, int), default=None, metavar="MIN-MAX",
                        help="people per scene (default: the scenario's)")
    parser.add_argument("--distance", type=lambda s: _pair(s, float), default=None, metavar="MIN,MAX",
                        help="people's distance from the camera, m (default: the scenario's; density study 2,20)")
    parser.add_argument("--methods", type=lambda s: s.split(","), default=None, metavar="A,B",
                        help=f"main-table methods (default: all: {','.join(MAIN_METHODS)})")
    parser.add_argument(
        "--study", choices=STUDIES, default=None, help="run a study instead of the main table (scenario lab)"
    )
    parser.add_argument("--json", type=Path, default=None, help="write the rows (and per-person cases) here")
    parser.add_argument("--plot-dir", type=Path, default=DEFAULT_OUT,
                        help=f"where plots go (default: {DEFAULT_OUT} under the working directory)")
    parser.add_argument("--no-plot", action="store_true", help="write no plot")
    parser.add_argument(
        "--params",
        metavar="PROFILE",
        default=None,
        help="params profile name or YAML path (default: the sensor's own, e.g. ouster64, if params/ has "
        "it, else jackal_vlp16)",
    )
    parser.add_argument(
        "--set",
        dest="overrides",
        type=_override,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override one config value (dotted key, YAML value), e.g. "
        "fitting.profiles.robot.iterations=[4,10,4]; repeatable",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


@dataclass
class Plan:
    """A bench run's choices once the scenario's defaults are filled in."""

    run: BenchRun
    seed_set: str  # "report", "tuning" or "mixed": which side of sim.bench's split the seeds are on
    bench: Any  # sim.config.BenchConfig


def plan(args: argparse.Namespace, base: dict[str, Any]) -> Plan:
    """The run's scenario, sensor, seeds and methods (ValueError: unknown names)."""
    from smplify3d_ros.sim.config import load_sim_config

    sim = load_sim_config(args.params, {"sim": base["sim"]} if "sim" in base else None)
    name = args.scenario or ("lab" if args.study else "robot")
    if name not in sim.bench.scenarios:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(sim.bench.scenarios)}")
    scenario = sim.bench.scenarios[name]
    sensor = resolve_sensor(args.sensor or scenario.sensor)
    if sensor not in sim.lidar.names:
        raise ValueError(f"sensor {sensor!r} is not in sim.lidar; known: {', '.join(sim.lidar.names)}")
    methods = tuple(args.methods or MAIN_METHODS)
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        raise ValueError(f"unknown methods {unknown}; known: {', '.join(METHODS)}")
    first = sim.bench.report_seed_start if args.seed is None else args.seed
    seeds = range(first, first + args.scenes)
    tuning = [sim.bench.is_tuning_seed(s) for s in seeds]
    seed_set = "tuning" if all(tuning) else "mixed" if any(tuning) else "report"
    run = BenchRun(name, sensor, seeds, args.people or scenario.n_people, args.distance,
                   None if args.no_plot else args.plot_dir, progress=not args.no_progress, methods=methods)
    return Plan(run, seed_set, sim.bench)


def run(args: argparse.Namespace) -> int:
    base = overrides_from(args.overrides)
    if args.sequences is not None:
        from smplify3d_ros.eval import sequences

        args.overrides_mapping = base
        return sequences.run(args)
    try:
        p = plan(args, base)
    except ValueError as e:
        print(f"smplify3d bench: {e}", file=sys.stderr)
        return 2
    if p.seed_set != "report":
        print(f"smplify3d bench: note: seeds {p.run.seeds[0]}-{p.run.seeds[-1]} include tuning seeds "
              f"{p.bench.tuning_seeds[0]}-{p.bench.tuning_seeds[1]}; report figures come from seeds >= "
              f"{p.bench.report_seed_start}", file=sys.stderr)
    schemes = {METHODS[m].scheme for m in (*MAIN_METHODS, *ABLATION_METHODS)}
    cache: dict[str, Setup] = {}
    profiles: dict[str, str | None] = {}

    def setup_for(sensor: str, extra: dict[str, Any] | None = None) -> Setup:
        overrides = merge(base, extra or {})
        profile = profiles[sensor] = profile_for(sensor, args.params)
        key = json.dumps([profile, overrides], sort_keys=True)
        if key not in cache:
            cache.clear()  # one setup alive at a time (fitters hold tensors)
            cache[key] = Setup.create(profile, overrides or None, schemes)
        return cache[key]

    start = time.perf_counter()
    default_distance = p.bench.scenarios[p.run.scenario].distance_m
    report = (run_study(args.study, p.run, setup_for, default_distance) if args.study
              else run_main(p.run, setup_for, default_distance))
    elapsed = time.perf_counter() - start
    print(report.table)
    for line in report.notes:
        print(line)
    for path in report.plots:
        print(f"plot: {path}")
    people = len({(c.scene, c.person_id) for c in report.cases})
    print(f"wall time {elapsed:.0f} s: {len(p.run.seeds)} scenes, {people} people, {len(report.cases)} "
          f"person-method cases (scenario {p.run.scenario}, seeds {p.run.seeds[0]}-{p.run.seeds[-1]}: {p.seed_set})")
    if args.json is not None:
        write_json(args.json, report, _meta(args, p, report, profiles, base, cache, elapsed))
    return 0


def _meta(args: argparse.Namespace, p: Plan, report: Report, profiles: dict[str, str | None],
          base: dict[str, Any], cache: dict[str, Setup], elapsed: float) -> dict[str, Any]:
    setup = next(iter(cache.values()), None)
    return {
        "study": args.study, "scenario": p.run.scenario, "sensor": p.run.sensor, "scenes": args.scenes,
        "seed": p.run.seeds[0], "seeds": [p.run.seeds[0], p.run.seeds[-1]], "seed_set": p.seed_set,
        "tuning_seeds": list(p.bench.tuning_seeds), "report_seed_start": p.bench.report_seed_start,
        "people": list(p.run.people), "distance_m": list(report.distance), "methods": list(p.run.methods),
        "profiles": profiles, "overrides": base,
        "scenario_config": to_dict(p.bench.scenarios[p.run.scenario]),
        "bench_config": {k: v for k, v in to_dict(p.bench).items() if k != "scenarios"},
        "fitting": to_dict(setup.config.fitting) if setup else None,
        "code": code_version(), "seconds": round(elapsed, 1),
    }


def write_json(path: Path, report: Report, meta: dict[str, Any]) -> None:
    doc = {"rows": report.rows, **report.extra, "meta": meta,
           "cases": [dataclasses.asdict(c) for c in report.cases]}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1))
    print(f"wrote {path}")


def code_version() -> str:
    """The commit of the working tree; with uncommitted changes to the code or parameters, "-dirty-" and
    a hash of that diff (two runs with equal strings ran the same code)."""
    import hashlib
    import subprocess

    root = Path(__file__).resolve().parents[3]
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=root, capture_output=True, text=True, check=True
        ).stdout.strip()
        code = ["smplify3d_ros", "msg_adapters", "params"]  # not docs/: the bench's own outputs live there
        diff = subprocess.run(
            ["git", "diff", "HEAD", "--", *code], cwd=root, capture_output=True, check=True
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return commit + (f"-dirty-{hashlib.sha1(diff).hexdigest()[:8]}" if diff else "")


def main() -> int:  # `python -m smplify3d_ros.eval.bench.cli`
    parser = argparse.ArgumentParser(prog="smplify3d bench", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args())


if __name__ == "__main__":
    raise SystemExit(main())
