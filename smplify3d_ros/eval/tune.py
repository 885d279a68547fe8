"""`smplify3d tune`: search an optimizer profile's weights and iteration counts for the robot path.

    smplify3d tune --trials 40 --scenes 30          # profile `robot`, scenario robot, tuning seeds 0-29

The search runs on the TUNING seeds only (`sim.bench.tuning_seeds`, 0-999 by default) with the robot
path's objective: the mean MPJPE (mm) of the built-in initializer + the profile's fit on the frame path
(`frame_fitter.FrameFitter`: people selected, points cut out of the raw scan), each person's error
capped at `--mpjpe-cap` (a far person without LiDAR depth misses by metres whatever the weights: without
the cap, a handful of them would decide the search), plus `--iteration-cost` mm per planned iteration (a
deterministic stand-in for fit time: measured seconds vary with the load of the machine, so they are
recorded, never optimized). The best trial is then scored on as many REPORT
seeds (from `sim.bench.report_seed_start`, 1000), which the search never saw, next to the profile as it
was, and written as a params override file (`--params FILE` of every command, `load_config(FILE)`).

The search space (`SEARCH_SPACE`) lives in this one place, each range with its reason. Trials are
stored in an optuna journal file (`--storage`): a second run with the same file resumes, up to
`--trials` trials in all. The sampler is seeded (`--sampler-seed`) and the fit is deterministic, so an
uninterrupted run repeats exactly; the first trial is always the profile as it was.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from smplify3d_ros.cli import at_least

DEFAULT_OUT = Path("out/tune")  # journal and profile go here unless --storage / --out say otherwise


@dataclass(frozen=True)
class Param:
    """One searched value of `fitting.profiles.<name>`."""

    key: str  # dotted key under the profile ("weights.pose"); "iterations.1" is the mesh stage's count
    low: float
    high: float
    log: bool  # sample the logarithm (weights span decades)
    integer: bool
    reason: str  # why this range


SEARCH_SPACE: tuple[Param, ...] = (
    Param("lr", 0.005, 0.05, True, False,
          "Adam step: below 0.005 thirty iterations barely move a limb; above 0.05 the pose stage oscillates"),
    Param("iterations.0", 2, 20, False, True,
          "scale stage (root, translation): 2 already fixes the 2D alignment's scale; beyond 20 nothing moves"),
    Param("iterations.1", 5, 60, False, True,
          "mesh stage (pose, shape): below 5 the limbs stay at the initializer's; 60 is past the thesis's 50"),
    Param("iterations.2", 2, 40, False, True,
          "image stage (translation): 2 moves the body onto the image; 40 is twice the reference's 20"),
    Param("early_stop_rel_tol", 1e-4, 1e-2, True, False,
          "per-person early stopping: 1e-4 hardly ever stops, 1e-2 stops while limbs still move by cm"),
    Param("weights.pose", 0.5, 10.0, True, False,
          "λ_θ: below 0.5 the pose prior lets knees bend backwards; above 10 limbs ignore the keypoints"),
    Param("weights.bend", 0.1, 10.0, True, False, "λ_a: the same decades as λ_θ, for elbow and knee bending"),
    Param("weights.shape", 0.5, 20.0, True, False,
          "λ_β: 0.5 lets the phenotypes run to [0, 1]'s bounds; 20 keeps everyone at the mean shape"),
    Param("weights.chamfer", 50.0, 3000.0, True, False,
          "λ_3D in the mesh stage: 50 is about the image term's size at 10 m, 3000 makes the image irrelevant"),
    Param("weights.chamfer_final", 50.0, 3000.0, True, False, "λ_3D in the image stage: the same span"),
    Param("weights.occlusion", 5.0, 500.0, True, False,
          "λ_θocc: 5 lets occluded parts drift freely; 500 freezes them at the initial estimate"),
    Param("weights.init_pose", 1.0, 300.0, True, False,
          "prior on visible joints: the built-in estimate's limbs are poor, so from weak (1) to freezing (300)"),
    Param("weights.neutral", 5.0, 200.0, True, False,
          "neutral pose prior: 5 leaves limbs the image sees end-on to chance, 200 holds every limb hanging"),
    Param("neutral_robust_scale", 0.05, 2.0, True, False,
          "its Geman-McClure scale (range widths): 0.05 lets any pose out of it, 2 is quadratic over the range"),
    Param("weights.sigma_px", 20.0, 300.0, True, False,
          "Geman-McClure σ (px), stages 1-2: 20 px rejects a far person's noisy keypoints, 300 px none"),
    Param("weights.sigma_px_final", 10.0, 200.0, True, False, "Geman-McClure σ (px), stage 3: a little tighter"),
)
SIGNIFICANT = 3  # sampled values are rounded to this many digits, so the file holds exactly what was scored


# -- scenes and scoring ------------------------------------------------------------------------------------
@dataclass
class TuneScene:
    """One simulated frame observed once (the observations depend on no searched value)."""

    seed: int
    observed: Any  # frame_fitter.FrameFits without fits
    truth: dict[int, Any]  # person id -> sim.world.SimPerson


@dataclass
class Score:
    """The robot path's accuracy and time over a set of scenes."""

    objective: float  # capped_mpjpe_mm + iteration cost
    mpjpe_mm: float
    capped_mpjpe_mm: float  # the mean of each person's MPJPE capped at the search's cap
    pa_mpjpe_mm: float
    people: int
    seconds_per_person: float  # measured, for information


def observe_scenes(setup: Any, scenario: str, sensor: str, seeds: range, people: tuple[int, int],
                   distance: tuple[float, float]) -> list[TuneScene]:
    """The frame path up to the fit, for every seed (built-in init: no estimate reaches the fitter)."""
    from smplify3d_ros.eval.bench.methods import simulate
    from smplify3d_ros.frame_fitter import FrameFitter

    scenes = []
    for seed in seeds:
        sim = simulate(seed, setup, scenario, sensor, people, distance)
        observed = FrameFitter(setup.config, setup.fitters[None]).observe(sim.frame)
        observed.observations = [dataclasses.replace(o, init=None) for o in observed.observations]
        truth = {p.person_id: p for p in sim.people}
        observed.observations = [o for o in observed.observations if o.person_id in truth]
        scenes.append(TuneScene(seed, observed, truth))
    return scenes


def evaluate(config: Any, model: Any, scenes: list[TuneScene], iteration_cost: float, cap_mm: float) -> Score:
    """Fit every scene's people with `config` and score them against the truth (`cap_mm` 0: no cap)."""
    from smplify3d_ros.eval import metrics
    from smplify3d_ros.fitting.fitter import Fitter
    from smplify3d_ros.frame_fitter import FrameFitter

    frame_fitter = FrameFitter(config, Fitter(config.fitting, model=model))
    errors, aligned, seconds = [], [], 0.0
    for scene in scenes:
        if not scene.observed.observations:
            continue
        start = time.perf_counter()
        fits = frame_fitter.fit_observed(scene.observed).fits
        seconds += time.perf_counter() - start
        for obs, fit in zip(scene.observed.observations, fits, strict=True):
            gt = np.asarray(scene.truth[obs.person_id].joints, np.float64)
            errors.append(float(metrics.mpjpe(fit.joints.astype(np.float64), gt)))
            aligned.append(float(metrics.pa_mpjpe(fit.joints.astype(np.float64), gt)))
    if not errors:
        raise ValueError("no person was fitted in these scenes: more scenes or other seeds")
    capped = float(np.mean(np.minimum(errors, cap_mm))) if cap_mm > 0 else float(np.mean(errors))
    planned = sum(config.fitting.optimizer.iterations)
    return Score(capped + iteration_cost * planned, float(np.mean(errors)), capped, float(np.mean(aligned)),
                 len(errors), seconds / len(errors))


# -- the search space -> configuration ---------------------------------------------------------------------
def base_values(profile: Any, space: tuple[Param, ...]) -> dict[str, float]:
    """The searched keys' values in an `OptimizerProfile` (the first trial)."""
    from smplify3d_ros.settings import to_dict

    values = to_dict(profile)
    out = {}
    for p in space:
        node: Any = values
        for part in p.key.split("."):
            node = node[int(part)] if part.isdigit() else node[part]
        out[p.key] = node
    return out


def profile_overrides(name: str, values: dict[str, float], profile: Any) -> dict[str, Any]:
    """{"fitting": {"profiles": {name: {...}}}} setting `values` (dotted keys) on top of `profile`."""
    from smplify3d_ros.settings import to_dict

    base = to_dict(profile)
    out: dict[str, Any] = {}
    for key, value in values.items():
        parts = key.split(".")
        if parts[-1].isdigit():  # one entry of a list: the whole list, the others as they were
            listed = out.get(parts[0], list(base[parts[0]]))
            listed[int(parts[-1])] = value
            out[parts[0]] = listed
            continue
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return {"fitting": {"profile": name, "profiles": {name: out}}}


def rounded(value: float, integer: bool) -> float | int:
    return int(round(value)) if integer else float(f"{value:.{SIGNIFICANT}g}")


def suggest(trial: Any, space: tuple[Param, ...]) -> dict[str, float]:
    out = {}
    for p in space:
        if p.integer:
            out[p.key] = trial.suggest_int(p.key, int(p.low), int(p.high), log=p.log)
        else:
            out[p.key] = rounded(trial.suggest_float(p.key, p.low, p.high, log=p.log), False)
    return out


# -- the command -------------------------------------------------------------------------------------------
def add_arguments(parser: argparse.ArgumentParser) -> None:
    from smplify3d_ros.eval.bench.cli import _override

    parser.add_argument("--profile-name", default=None,
                        help="the fitting.profiles entry to search (default: the config's fitting.profile, robot)")
    parser.add_argument("--params", metavar="PROFILE", default=None,
                        help="params profile name or YAML path the search starts from (default: jackal_vlp16)")
    parser.add_argument("--scenario", default="robot", help="bench scenario (sim.bench.scenarios; default robot)")
    parser.add_argument("--sensor", default=None, help="simulated LiDAR (default: the scenario's)")
    parser.add_argument("--trials", type=at_least(1), default=40,
                        help="trials in all, counting resumed ones (default 40)")
    parser.add_argument("--scenes", type=at_least(1), default=30,
                        help="scenes searched on, and as many reported on (default 30)")
    parser.add_argument("--seed", type=at_least(0), default=None,
                        help="first tuning seed (default: the first of sim.bench.tuning_seeds, 0)")
    parser.add_argument("--iteration-cost", type=float, default=0.2, metavar="MM",
                        help="objective mm per planned iteration of the three stages (default 0.2: 60 iterations "
                        "cost 12 mm); 0 optimizes accuracy alone")
    parser.add_argument("--mpjpe-cap", type=float, default=500.0, metavar="MM",
                        help="each person's MPJPE counts at most this much (default 500: a miss is a miss, "
                        "however far); 0: no cap")
    parser.add_argument("--sampler-seed", type=int, default=0, help="seed of the TPE sampler (default 0)")
    parser.add_argument("--storage", type=Path, default=None,
                        help=f"optuna journal file, resumed when it exists (default {DEFAULT_OUT}/<name>.journal)")
    parser.add_argument("--out", type=Path, default=None,
                        help=f"profile YAML to write (default {DEFAULT_OUT}/<name>_tuned.yaml)")
    parser.add_argument("--no-report", action="store_true", help="do not score the best trial on the report seeds")
    parser.add_argument("--set", dest="overrides", type=_override, action="append", default=[], metavar="KEY=VALUE",
                        help="override one config value for every trial (dotted key, YAML value); repeatable")
    parser.add_argument("--no-progress", action="store_true", help="print no line per trial")


@dataclass
class Search:
    """A search's fixed inputs: configuration, scenes and what the journal must agree on."""

    name: str  # the profile searched
    params: str | None  # --params: the profile file the trials start from
    base: dict[str, Any]  # --set overrides of every trial
    setup: Any  # eval.bench.methods.Setup: the configuration as it was, body model, simulator configuration
    scenario: str
    sensor: str
    tuning: range
    report: range
    iteration_cost: float
    cap_mm: float

    def describe(self) -> dict[str, Any]:
        """What a resumed journal must have been made with."""
        return {"profile": self.name, "params": self.params, "base": self.base, "scenario": self.scenario,
                "sensor": self.sensor, "tuning_seeds": [self.tuning[0], self.tuning[-1]],
                "iteration_cost": self.iteration_cost, "cap_mm": self.cap_mm,
                "space": [dataclasses.asdict(p) for p in SEARCH_SPACE]}

    def config(self, values: dict[str, float] | None) -> Any:
        """The configuration of one trial (None: the profile as it was, but selected)."""
        from smplify3d_ros.config import load_config
        from smplify3d_ros.eval.bench.cli import merge

        profile = self.setup.config.fitting.profiles[self.name]
        return load_config(self.params, merge(self.base, profile_overrides(self.name, values or {}, profile)))

    def scenes(self, seeds: range) -> list[TuneScene]:
        sc = self.setup.sim.bench.scenarios[self.scenario]
        return observe_scenes(self.setup, self.scenario, self.sensor, seeds, sc.n_people, sc.distance_m)


def make_search(args: argparse.Namespace) -> Search:
    from smplify3d_ros.eval.bench.cli import overrides_from
    from smplify3d_ros.eval.bench.methods import Setup, resolve_sensor

    base = overrides_from(args.overrides)
    setup = Setup.create(args.params, base or None, ())
    bench = setup.sim.bench
    if args.scenario not in bench.scenarios:
        raise ValueError(f"unknown scenario {args.scenario!r}; known: {', '.join(bench.scenarios)}")
    first = bench.tuning_seeds[0] if args.seed is None else args.seed
    tuning = range(first, first + args.scenes)
    if not (bench.is_tuning_seed(tuning[0]) and bench.is_tuning_seed(tuning[-1])):
        raise ValueError(f"seeds {tuning[0]}-{tuning[-1]} leave the tuning seeds {bench.tuning_seeds[0]}-"
                         f"{bench.tuning_seeds[1]} (sim.bench.tuning_seeds)")
    name = args.profile_name or setup.config.fitting.profile
    if name not in setup.config.fitting.profiles:
        raise ValueError(f"unknown profile {name!r}; known: {', '.join(setup.config.fitting.profiles)}")
    sensor = resolve_sensor(args.sensor or bench.scenarios[args.scenario].sensor)
    report = range(bench.report_seed_start, bench.report_seed_start + args.scenes)
    return Search(name, args.params, base, setup, args.scenario, sensor, tuning, report, args.iteration_cost,
                  args.mpjpe_cap)


def open_study(search: Search, storage_path: Path, sampler_seed: int) -> Any:
    """The optuna study in the journal file (created, or resumed when it was made by the same search)."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage_path.parent.mkdir(parents=True, exist_ok=True)
    storage = optuna.storages.JournalStorage(optuna.storages.journal.JournalFileBackend(str(storage_path)))
    study = optuna.create_study(study_name=f"tune-{search.name}", storage=storage, direction="minimize",
                                sampler=optuna.samplers.TPESampler(seed=sampler_seed), load_if_exists=True)
    made_by = json.dumps(search.describe(), sort_keys=True)
    if "search" not in study.user_attrs:
        study.set_user_attr("search", made_by)
        profile = search.setup.config.fitting.profiles[search.name]
        study.enqueue_trial(base_values(profile, SEARCH_SPACE))  # trial 0: the profile as it was
    elif study.user_attrs["search"] != made_by:
        raise ValueError(f"{storage_path} holds another search (profile, seeds, scenario, space or objective "
                         "differ): give another --storage")
    return study


def optimize(search: Search, study: Any, scenes: list[TuneScene], trials: int, progress: bool) -> None:
    """Run trials until the study has `trials` finished ones."""
    import optuna

    def objective(trial: Any) -> float:
        score = evaluate(search.config(suggest(trial, SEARCH_SPACE)), search.setup.model, scenes,
                         search.iteration_cost, search.cap_mm)
        for key, value in dataclasses.asdict(score).items():
            trial.set_user_attr(key, value)
        if progress:
            print(f"trial {trial.number}: objective {score.objective:.1f} (MPJPE {score.mpjpe_mm:.1f} mm, capped "
                  f"{score.capped_mpjpe_mm:.1f} mm, {score.seconds_per_person:.2f} s / person)", flush=True)
        return score.objective

    done = len([t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE])
    if trials > done:
        with warnings.catch_warnings():  # trial 0 is the profile as it was, which may lie outside the space
            warnings.filterwarnings("ignore", message="Fixed parameter .* is out of range")
            study.optimize(objective, n_trials=trials - done)


def run(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    try:
        search = make_search(args)
        storage = args.storage or DEFAULT_OUT / f"{search.name}.journal"
        study = open_study(search, storage, args.sampler_seed)
    except ValueError as e:
        print(f"smplify3d tune: {e}", file=sys.stderr)
        return 2
    scenes = search.scenes(search.tuning)
    optimize(search, study, scenes, args.trials, not args.no_progress)
    best = study.best_trial
    values = {p.key: best.params[p.key] for p in SEARCH_SPACE}
    values = {p.key: rounded(values[p.key], p.integer) for p in SEARCH_SPACE}
    lines = [f"best trial {best.number} of {len(study.trials)}: objective {best.value:.1f}, MPJPE "
             f"{best.user_attrs['mpjpe_mm']:.1f} mm (capped {best.user_attrs['capped_mpjpe_mm']:.1f}) on tuning seeds "
             f"{search.tuning[0]}-{search.tuning[-1]} "
             f"({best.user_attrs['people']} people)"]
    report = None
    if not args.no_report:
        report_scenes = search.scenes(search.report)
        report = {key: evaluate(search.config(v), search.setup.model, report_scenes, search.iteration_cost,
                                search.cap_mm) for key, v in (("tuned", values), ("as_was", None))}
        tuned, was = report["tuned"], report["as_was"]
        lines += [f"report seeds {search.report[0]}-{search.report[-1]} ({tuned.people} people), tuned / as it "
                  f"was: objective {tuned.objective:.1f} / {was.objective:.1f}, MPJPE {tuned.mpjpe_mm:.1f} / "
                  f"{was.mpjpe_mm:.1f} mm (capped {tuned.capped_mpjpe_mm:.1f} / {was.capped_mpjpe_mm:.1f}), "
                  f"PA-MPJPE {tuned.pa_mpjpe_mm:.1f} / {was.pa_mpjpe_mm:.1f} mm, "
                  f"{tuned.seconds_per_person:.2f} / {was.seconds_per_person:.2f} s / person"]
    out = args.out or DEFAULT_OUT / f"{search.name}_tuned.yaml"
    write_profile(out, search, values, best, len(study.trials), report)
    for line in lines:
        print(line)
    print(f"wrote {out}; wall time {time.perf_counter() - start:.0f} s")
    return 0


def write_profile(path: Path, search: Search, values: dict[str, float], best: Any, trials: int,
                  report: dict[str, Score] | None) -> None:
    """A params override file: the starting profile's own overrides, the --set ones, the best trial's
    values; a header says how they were found and how they score."""
    from smplify3d_ros.eval.bench.cli import code_version, merge
    from smplify3d_ros.settings import load_yaml, resolve_profile

    profile = search.setup.config.fitting.profiles[search.name]
    tuned = profile_overrides(search.name, values, profile)
    doc = merge(merge(load_yaml(resolve_profile(search.params)), search.base), tuned)
    was = base_values(profile, SEARCH_SPACE)
    comments = {}
    for p in SEARCH_SPACE:
        key = p.key.split(".")[0] if p.key.split(".")[-1].isdigit() else p.key
        span = f"[{p.low:g}, {p.high:g}]{' log' if p.log else ''}"
        comments.setdefault(key, []).append(f"{p.key.split('.')[-1] if key != p.key else ''} {span}, was "
                                            f"{was[p.key]:g}".strip())
    comments = {("fitting", "profiles", search.name, *k.split(".")): "searched " + "; ".join(v)
                for k, v in comments.items()}
    header = [
        f"Profile `{search.name}` tuned by `smplify3d tune` (code {code_version()}), starting from "
        f"{search.params or 'jackal_vlp16'}{' with --set ' + json.dumps(search.base) if search.base else ''}.",
        f"Search: {trials} trials (optuna TPE sampler), scenario {search.scenario}, sensor {search.sensor}, "
        f"tuning seeds {search.tuning[0]}-{search.tuning[-1]} ({best.user_attrs['people']} people).",
        f"Objective: mean MPJPE (mm) of the robot path (built-in initializer, this profile, the frame path), "
        f"each person's capped at {search.cap_mm:g} mm, + {search.iteration_cost:g} mm per planned iteration.",
        f"Best: trial {best.number}, objective {best.value:.1f} (MPJPE {best.user_attrs['mpjpe_mm']:.1f} mm, capped "
        f"{best.user_attrs['capped_mpjpe_mm']:.1f} mm) on the tuning seeds.",
    ]
    if report is not None:
        tuned, was = report["tuned"], report["as_was"]
        header.append(f"Report seeds {search.report[0]}-{search.report[-1]} (never searched on, {tuned.people} "
                      f"people): objective {tuned.objective:.1f} (MPJPE {tuned.mpjpe_mm:.1f} mm, capped "
                      f"{tuned.capped_mpjpe_mm:.1f}); the profile as it was {was.objective:.1f} (MPJPE "
                      f"{was.mpjpe_mm:.1f} mm, capped {was.capped_mpjpe_mm:.1f}).")
    header.append("Use it with `--params <this file>` (smplify3d bench, replay, the node's params_file).")
    text = "".join(f"# {line}\n" for line in header) + "\n".join(_emit(doc, comments)) + "\n"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text, encoding="utf-8")


def _emit(node: dict[str, Any], comments: dict[tuple[str, ...], str], where: tuple[str, ...] = ()) -> list[str]:
    """YAML lines of a nested mapping, a comment after each key `comments` names."""
    lines = []
    pad = "  " * len(where)
    for key, value in node.items():
        path = (*where, key)
        note = f"  # {comments[path]}" if path in comments else ""
        if isinstance(value, dict) and value:
            lines.append(f"{pad}{key}:{note}")
            lines += _emit(value, comments, path)
        else:
            text = yaml.safe_dump(value, default_flow_style=True, width=10_000).splitlines()[0]
            lines.append(f"{pad}{key}: {text}{note}")
    return lines
