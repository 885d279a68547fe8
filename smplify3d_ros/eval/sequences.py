"""`smplify3d bench --sequences`: people tracked through simulated 10 Hz sequences, against the truth.

Each sequence (`sim.world.simulate_sequence`, scenario `people` by default: two or three people at 2-8 m
walking, stopping, turning round and crossing in front of each other) runs through the frame path the
drivers run, twice per detector kind (the keypoints with the detector's track ids, and anonymous):
- `tracked`: with the drivers' tracker (warm starts, held shape, the motion filter);
- `single_frame`: every frame fitted from scratch (the robot path without tracking).
Per person and overall: MPJPE and PA-MPJPE over the model's joints (mm), the acceleration error (mean over
joints of |a_fit - a_true|, a = the second difference over consecutive frames, mm/frame^2), id switches
(a true person's track id changing between frames: with detector ids only a fit assigned to the wrong
track can switch), the share of warm, cold and lost fits, the fit time per person and frame, and the
median time of a warm fit per person (a frame's warm solve, all its tracked people in one batch,
divided by their number).
With `--frame-step N` only every N-th frame is fitted, as by a node that keeps up with 10 / N Hz (the
acceleration error is then over the frames fitted). Sequences come from report seeds
(`sim.bench.report_seed_start` on), never from tuning seeds.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from smplify3d_ros.eval import metrics
from smplify3d_ros.keypoints import hip_midpoint

VARIANTS = ("tracked", "single_frame")
DETECTORS = ("track_ids", "anonymous")


@dataclass
class PersonTrack:
    """One true person through one run: per frame the fitted joints (or None) and the track id used."""

    truth: list[np.ndarray] = field(default_factory=list)  # (J, 3) per frame, m
    fit: list[np.ndarray | None] = field(default_factory=list)
    track_id: list[int | None] = field(default_factory=list)
    flags: list[set[str]] = field(default_factory=list)


@dataclass
class RunResult:
    seed: int
    variant: str
    detector: str
    people: dict[int, PersonTrack]
    seconds: float  # fit time of the whole run
    fits: int  # people fitted, all frames
    warm_seconds: list[float] = field(default_factory=list)  # per frame with warm fits: per person

    def per_person(self) -> dict[int, dict[str, float]]:
        return {pid: person_figures(track) for pid, track in self.people.items()}


def person_figures(track: PersonTrack) -> dict[str, float]:
    pairs = [(f, t) for f, t in zip(track.fit, track.truth, strict=True) if f is not None]
    mpjpe = [metrics.mpjpe(f, t) for f, t in pairs]
    pa = [metrics.pa_mpjpe(f, t) for f, t in pairs]
    accel = acceleration_errors(track.fit, track.truth)
    ids = [i for i in track.track_id if i is not None]
    flags = [f for f in track.flags if f is not None]
    return {
        "frames": len(track.truth), "fitted": len(pairs),
        "mpjpe_mm": float(np.mean(mpjpe)) if mpjpe else float("nan"),  # metrics give mm
        "pa_mpjpe_mm": float(np.mean(pa)) if pa else float("nan"),
        "accel_error_mm": 1e3 * float(np.mean(accel)) if accel else float("nan"),
        "id_switches": int(sum(a != b for a, b in zip(ids, ids[1:]))),
        "warm": sum("warm_start" in f for f in flags),
    }


def acceleration_errors(fit: list[np.ndarray | None], truth: list[np.ndarray]) -> list[float]:
    """Per frame with a fit on both sides: mean over joints of |a_fit - a_true| (m/frame^2)."""
    out = []
    for k in range(1, len(truth) - 1):
        if fit[k - 1] is None or fit[k] is None or fit[k + 1] is None:
            continue
        a_fit = fit[k + 1] - 2 * fit[k] + fit[k - 1]
        a_true = truth[k + 1] - 2 * truth[k] + truth[k - 1]
        out.append(float(np.linalg.norm(a_fit - a_true, axis=1).mean()))
    return out


def _match(fits: list[Any], sim: Any) -> dict[int, Any]:
    """True person id -> its fit: the nearest fitted pelvis within 1 m (greedy, nearest pairs first)."""
    from smplify3d_ros.tracking.tracker import pelvis

    truths = {p.person_id: hip_midpoint(p.keypoints3d) for p in sim.people}
    pairs = sorted((float(np.linalg.norm(pelvis(f) - c)), pid, k) for k, f in enumerate(fits)
                   for pid, c in truths.items())
    out, used = {}, set()
    for distance, pid, k in pairs:
        if distance <= 1.0 and pid not in out and k not in used:
            out[pid], _ = fits[k], used.add(k)
    return out


def run_sequence(frames: list[Any], setup: Any, variant: str, detector: str, seed: int) -> RunResult:
    """One pass over a simulated sequence through the frame path (with or without the tracker)."""
    from smplify3d_ros.frame_fitter import FrameFitter
    from smplify3d_ros.tracking.tracker import Tracker

    tracker = Tracker(setup.config.tracking) if variant == "tracked" else None
    path = FrameFitter(setup.config, setup.fitter, tracker, setup.warm_fitter if tracker else None)
    people: dict[int, PersonTrack] = {p.person_id: PersonTrack() for p in frames[0].people}
    path.start_background(wait=True)  # background refreshes: their process loads before the clock runs
    try:
        seconds, fitted, warm_seconds = _fit_frames(path, frames, detector, people)
    finally:
        path.close()
    return RunResult(seed, variant, detector, people, seconds, fitted, warm_seconds)


def _fit_frames(path: Any, frames: list[Any], detector: str,
                people: dict[int, PersonTrack]) -> tuple[float, int, list[float]]:
    """`run_sequence`'s pass, filling `people`: (fit seconds, people fitted, warm seconds per person)."""
    seconds, fitted, warm_seconds = 0.0, 0, []
    for sim in frames:
        frame = sim.frame
        if detector == "anonymous":
            frame = dataclasses.replace(frame, person_ids=np.full(len(frame.person_ids), -1, dtype=np.int64))
        result = path.fit(frame)
        seconds += result.latency.get("fit", 0.0)
        if "warm_fit_per_person" in result.latency:
            warm_seconds.append(result.latency["warm_fit_per_person"])
        fitted += len(result.fits)
        matched = _match(result.fits, sim)
        for p in sim.people:
            track = people.setdefault(p.person_id, PersonTrack())
            fit = matched.get(p.person_id)
            track.truth.append(np.asarray(p.joints, np.float64))
            track.fit.append(None if fit is None else np.asarray(fit.joints, np.float64))
            track.track_id.append(None if fit is None else fit.person_id)
            track.flags.append(set() if fit is None else set(fit.flags))
    return seconds, fitted, warm_seconds


@dataclass
class SequenceSetup:
    config: Any
    fitter: Any
    warm_fitter: Any


def summarize(runs: list[RunResult]) -> list[dict[str, Any]]:
    """One row per (variant, detector): people-weighted means over every person of every sequence."""
    rows = []
    for variant in VARIANTS:
        for detector in DETECTORS:
            pick = [r for r in runs if r.variant == variant and r.detector == detector]
            if not pick:
                continue
            figures = [f for r in pick for f in r.per_person().values() if f["fitted"]]
            fits = sum(r.fits for r in pick)
            warm = sum(f["warm"] for f in figures)
            rows.append({
                "variant": variant, "detector": detector, "people": len(figures),
                "frames": sum(f["frames"] for f in figures), "fitted": sum(f["fitted"] for f in figures),
                "mpjpe_mm": _mean(figures, "mpjpe_mm", "fitted"),
                "pa_mpjpe_mm": _mean(figures, "pa_mpjpe_mm", "fitted"),
                "accel_error_mm": _mean(figures, "accel_error_mm", "fitted"),
                "id_switches": int(sum(f["id_switches"] for f in figures)),
                "warm_share": warm / fits if fits else 0.0,
                "ms_per_person_frame": 1e3 * sum(r.seconds for r in pick) / max(fits, 1),
                "warm_ms_per_person": _median_ms([s for r in pick for s in r.warm_seconds]),
            })
    return rows


def _median_ms(seconds: list[float]) -> float:
    return 1e3 * float(np.median(seconds)) if seconds else float("nan")


def _mean(figures: list[dict[str, float]], key: str, weight: str) -> float:
    values = [(f[key], f[weight]) for f in figures if np.isfinite(f[key])]
    return float(np.average([v for v, _ in values], weights=[w for _, w in values])) if values else float("nan")


def markdown(rows: list[dict[str, Any]]) -> str:
    head = ("run", "detector", "people", "fitted / frames", "MPJPE mm", "PA-MPJPE mm", "accel. error mm/frame²",
            "id switches", "warm fits", "ms / person / frame", "warm fit ms / person (median)")
    lines = ["| " + " | ".join(head) + " |", "|---|---|" + "---:|" * (len(head) - 2)]
    for r in rows:
        lines.append(f"| {r['variant']} | {r['detector']} | {r['people']} | {r['fitted']} / {r['frames']} | "
                     f"{r['mpjpe_mm']:.1f} | {r['pa_mpjpe_mm']:.1f} | {r['accel_error_mm']:.1f} | "
                     f"{r['id_switches']} | {100 * r['warm_share']:.0f} % | {r['ms_per_person_frame']:.0f} | "
                     + ("-" if not np.isfinite(r["warm_ms_per_person"]) else f"{r['warm_ms_per_person']:.0f}")
                     + " |")
    return "\n".join(lines)


def run(args: Any) -> int:
    """The `--sequences` branch of `smplify3d bench` (see the module docstring)."""
    step = args.frame_step
    if step < 1:  # before anything loads
        print("smplify3d bench: --frame-step must be >= 1", file=sys.stderr)
        return 2
    from tqdm import tqdm

    from smplify3d_ros.config import load_config
    from smplify3d_ros.eval.bench.methods import profile_for, resolve_sensor
    from smplify3d_ros.fitting.fitter import Fitter
    from smplify3d_ros.frame_fitter import warm_fitter_for
    from smplify3d_ros.sim.config import load_sim_config
    from smplify3d_ros.sim.world import simulate_sequence

    scenario, overrides = args.sequences, args.overrides_mapping or None
    try:  # names are checked before anything is fitted: a clear line, not an internal error
        sensor = resolve_sensor(args.sensor or "vlp16")
    except ValueError as e:
        print(f"smplify3d bench: {e}", file=sys.stderr)
        return 2
    params = profile_for(sensor, args.params)  # the sensor's own profile (ouster64.yaml), as the scenes' runs
    config, sim = load_config(params, overrides), load_sim_config(params, overrides)
    if scenario not in sim.sequence.scenarios:
        print(f"smplify3d bench: unknown sequence scenario {scenario!r}; known: {', '.join(sim.sequence.scenarios)}",
              file=sys.stderr)
        return 2
    fitter = Fitter(config.fitting)
    setup = SequenceSetup(config, fitter, warm_fitter_for(config, fitter))
    first = sim.bench.report_seed_start if args.seed is None else args.seed
    seeds = range(first, first + args.scenes)
    runs: list[RunResult] = []
    start = time.perf_counter()
    for seed in tqdm(seeds, desc="sequences", unit="seq", disable=args.no_progress, file=sys.stderr):
        frames = list(simulate_sequence(seed, sim, scenario, args.frames, 10.0, sensor=sensor))[::step]
        for variant in VARIANTS:
            for detector in DETECTORS:
                runs.append(run_sequence(frames, setup, variant, detector, seed))
    rows = summarize(runs)
    print(f"Sequences: scenario {scenario!r}, {len(seeds)} x {args.frames} frames at 10 Hz"
          + (f", one in {step} fitted ({10.0 / step:.1f} Hz)" if step > 1 else "")
          + f", seeds {seeds[0]}-{seeds[-1]}, sensor {sensor}; robot path (built-in initializer, raw scan)\n")
    print(markdown(rows))
    print(f"\n{time.perf_counter() - start:.0f} s")
    if args.json is not None:
        per_person = [{"seed": r.seed, "variant": r.variant, "detector": r.detector, "person": pid, **f}
                      for r in runs for pid, f in r.per_person().items()]
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"rows": rows, "people": per_person, "meta": {
            "scenario": scenario, "seeds": [seeds[0], seeds[-1]], "frames": args.frames, "frame_step": step,
            "sensor": sensor, "params": params, "overrides": overrides}}, indent=1))
        print(f"wrote {args.json}")
    return 0


__all__ = ["PersonTrack", "RunResult", "acceleration_errors", "run", "run_sequence", "summarize"]
