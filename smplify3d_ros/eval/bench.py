"""`smplify3d bench`: accuracy of SMPLify-3D and its baselines on simulated scenes (thesis Sec. 4).

Every scene comes from the simulator (`smplify3d_ros.sim.world.simulate_scene`) with a seed, so all
methods, sensors and noise levels see the same people. Per detected person the bench cuts the person's
points out of the full scan the way the node does (`observations_from_frame`), gives the fitter the
simulated image-HMR estimate (`SimFrame.hmr_init`, CLIFF-like) as its initial estimate, and scores each
method's body against the ground truth:

- `hmr_init_root_aligned`: the HMR estimate moved so that its hip midpoint sits on the truth's (the
  usual image-only figure, unreachable in real life);
- `hmr_init`: the HMR estimate as it is (unaligned);
- `hmr_init_icp`: HMR estimate + rigid ICP to the person's points (`FitOptions(optimize=False)`);
- `smplify3d_single_stage`: Eq. 2 in one stage (the profile's scheme set to `single_stage`);
- `smplify3d_three_stage`: the default robust three-stage method (Eq. 11-14);
- `builtin_init_three_stage`: three stages from the built-in initializer, without the HMR estimate.

Errors in mm: PVE (vertices), MPJPE over the 19 body joints, PA-MPJPE, MPJPE after aligning the hip
midpoints. LiDAR methods are always reported unaligned. `--study` runs one of the thesis's sweeps
(sensors, range noise, angular noise, drop-out, LiDAR density and distance, ablation) and saves a plot.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from smplify3d_ros.config import to_dict
from smplify3d_ros.eval import metrics
from smplify3d_ros.fitting.pipeline import FitOptions

DOCS_DIR = Path(__file__).resolve().parents[2] / "docs"

# Command-line sensor names -> keys of `sim.lidar.sensors` (params/base/sim.yaml).
SENSOR_ALIASES = {"vlp16": "vlp16", "ouster32": "os1_32", "ouster64": "os1_64", "ouster128": "os1_128"}
SENSOR_LABELS = {"vlp16": "VLP-16", "os1_32": "Ouster-32", "os1_64": "Ouster-64", "os1_128": "Ouster-128"}

# Targets of the project (three-stage MPJPE / init+ICP MPJPE at 3-8 m) and the thesis's figures.
TARGET_RATIO = {"os1_64": 0.55, "vlp16": 0.65}
THESIS_OUSTER64 = {"pve_mm": 57.2, "mpjpe_mm": 43.9}

ROW_KEYS = (
    "method",
    "sensor",
    "n",
    "pve_mm",
    "mpjpe_mm",
    "pa_mpjpe_mm",
    "mpjpe_root_aligned_mm",
    "pve_std_mm",
    "mpjpe_std_mm",
)
HIP_JOINTS = (0, 1)  # left_hip, right_hip in smplify3d_ros.body.joints.BODY_JOINTS: the root for alignment


@dataclass(frozen=True)
class Method:
    """A way of producing a body from one scene's observations."""

    name: str
    fit: bool = True  # False: score the HMR estimate itself
    root_aligned: bool = False  # score after moving the hip midpoint onto the truth's
    external_init: bool = True  # give the fitter the HMR estimate
    scheme: str | None = None  # override the profile's optimizer scheme
    options: FitOptions = field(default_factory=FitOptions)
    label: str = ""  # name in plots


METHODS: dict[str, Method] = {
    m.name: m
    for m in (
        Method("hmr_init_root_aligned", fit=False, root_aligned=True, label="HMR init (root-aligned)"),
        Method("hmr_init", fit=False, label="HMR init"),
        Method("hmr_init_icp", options=FitOptions(optimize=False), label="HMR init + ICP"),
        Method("smplify3d_single_stage", scheme="single_stage", label="SMPLify-3D single-stage"),
        Method("smplify3d_three_stage", label="SMPLify-3D three-stage"),
        Method("builtin_init_three_stage", external_init=False, label="built-in init, three-stage"),
        Method("ablation_no_chamfer", options=FitOptions(use_chamfer=False), label="without L_3D"),
        Method(
            "ablation_no_occlusion_prior",
            options=FitOptions(use_occlusion_prior=False),
            label="without L_θocc",
        ),
        Method(
            "ablation_no_visibility",
            options=FitOptions(use_visibility=False),
            label="without visibility filter",
        ),
    )
}
MAIN_METHODS = (
    "hmr_init_root_aligned",
    "hmr_init",
    "hmr_init_icp",
    "smplify3d_single_stage",
    "smplify3d_three_stage",
    "builtin_init_three_stage",
)


@dataclass
class Case:
    """One method's body for one person of one scene, scored against the truth (mm)."""

    method: str
    sensor: str
    scene: int  # the scene's seed
    person_id: int
    distance_m: float  # horizontal distance camera -> true hip midpoint
    num_points: int  # the person's extracted LiDAR points
    density: float  # thesis Eq. 9: extracted points per m² of the true body's projected area
    occluded_parts: bool  # some body part's keypoints are below the image visibility threshold
    visible_fraction: float  # simulator: fraction of the silhouette the camera sees
    pve: float
    mpjpe: float
    pa_mpjpe: float
    mpjpe_root_aligned: float
    flags: list[str] = field(default_factory=list)
    value: float | None = None  # the swept parameter of a study
    seconds: float = 0.0  # fit time of the whole scene's people (same for every person of the scene)


@dataclass
class Setup:
    """What a bench run needs: configuration, body model, fitters per scheme."""

    config: Any
    model: Any
    fitters: dict[str | None, Any]

    @classmethod
    def create(
        cls, profile: str | None, overrides: dict[str, Any] | None, schemes: Iterable[str | None]
    ) -> Setup:
        from smplify3d_ros.body import load_body_model
        from smplify3d_ros.config import load_config
        from smplify3d_ros.fitting.pipeline import Fitter

        config = load_config(profile, overrides)
        model = load_body_model(config.fitting.body.model, config.fitting.body)
        fitters = {}
        for scheme in dict.fromkeys(schemes):
            fitting = config.fitting
            if scheme is not None and fitting.optimizer.scheme != scheme:
                profiles = dict(fitting.profiles)
                profiles[fitting.profile] = dataclasses.replace(fitting.optimizer, scheme=scheme)
                fitting = dataclasses.replace(fitting, profiles=profiles)
            fitters[scheme] = Fitter(fitting, model=model)
        return cls(config, model, fitters)


# -- scoring ----------------------------------------------------------------------------------------------
def _forward(model: Any, params: Any) -> tuple[np.ndarray, np.ndarray]:
    import torch

    dtype = model.anat_frames.dtype
    with torch.no_grad():
        out = model(
            *(
                torch.as_tensor(np.asarray(a, np.float64), dtype=dtype)[None]
                for a in (params.shape, params.pose, params.root_orient, params.transl)
            )
        )
    return out.vertices[0].double().numpy(), out.joints[0].double().numpy()


def score(vertices: np.ndarray, joints: np.ndarray, truth: Any, root_aligned: bool) -> dict[str, float]:
    """PVE, MPJPE, PA-MPJPE and root-aligned MPJPE (mm) of one body against a `SimPerson`."""
    gt_v = np.asarray(truth.vertices, np.float64)
    gt_j = np.asarray(truth.joints, np.float64)
    offset = gt_j[list(HIP_JOINTS)].mean(0) - joints[list(HIP_JOINTS)].mean(0)
    if root_aligned:
        vertices, joints = vertices + offset, joints + offset
    return {
        "pve": float(metrics.pve(vertices, gt_v)),
        "mpjpe": float(metrics.mpjpe(joints, gt_j)),
        "pa_mpjpe": float(metrics.pa_mpjpe(joints, gt_j)),
        "mpjpe_root_aligned": float(metrics.mpjpe(metrics.root_aligned(joints, gt_j, HIP_JOINTS), gt_j)),
    }


def person_context(sim: Any, obs: Any, truth: Any, setup: Setup) -> dict[str, Any]:
    """Per-person facts every method shares: distance, points, Eq. 9 density, occluded parts."""
    from smplify3d_ros.fitting.visibility import occluded_parts
    from smplify3d_ros.sim.scene import make_mount

    mount = make_mount(setup.config.sim.mount)
    hips = np.asarray(truth.keypoints3d, np.float64)[[11, 12]].mean(0)
    lidar_origin = sim.frame.T_cam_lidar[:3, 3]
    density = (
        metrics.lidar_density(
            len(obs.points), truth.vertices, setup.model.faces.cpu().numpy(), lidar_origin, mount.up_cam
        )
        if len(obs.points)
        else 0.0
    )
    threshold = setup.config.fitting.visibility.keypoint_conf_image
    return {
        "distance_m": float(np.hypot(hips[0], hips[2])),
        "num_points": len(obs.points),
        "density": float(density),
        "occluded_parts": bool(occluded_parts(obs.keypoints[:, 2], threshold).any()),
        "visible_fraction": float(sim.visible_fraction.get(obs.person_id, float("nan"))),
    }


def miscalibrated(T_cam_lidar: np.ndarray, error: float, seed: int) -> np.ndarray:
    """The LiDAR-to-camera transform a robot with a calibration error of `error` believes in: the true one
    rotated by `error` degrees about a random axis through the LiDAR and shifted by `error` cm in a random
    direction. The directions depend on `seed` only, so a sweep scales one error per scene."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng([seed, 11])
    axis, direction = (v / np.linalg.norm(v) for v in rng.normal(size=(2, 3)))
    delta = np.eye(4)
    delta[:3, :3] = Rotation.from_rotvec(np.deg2rad(error) * axis).as_matrix()
    delta[:3, 3] = 0.01 * error * direction
    return T_cam_lidar @ delta


def evaluate_scene(
    sim: Any,
    seed: int,
    sensor: str,
    setup: Setup,
    methods: Sequence[str],
    value: float | None = None,
    calibration_error: float = 0.0,
) -> list[Case]:
    """Cases of every method for every detected person of one simulated scene; with `calibration_error`
    (see `miscalibrated`) the pipeline uses a wrong LiDAR-to-camera transform."""
    from smplify3d_ros.fitting.pipeline import observations_from_frame

    frame = sim.frame
    if calibration_error:
        frame = dataclasses.replace(frame, T_cam_lidar=miscalibrated(frame.T_cam_lidar, calibration_error, seed))
    people, origin = observations_from_frame(frame, setup.config)
    truth = {p.person_id: p for p in sim.people}
    people = [p for p in people if p.person_id in truth and p.person_id in sim.hmr_init]
    if not people:
        return []
    context = [person_context(sim, obs, truth[obs.person_id], setup) for obs in people]
    K = sim.frame.camera.K
    cases = []
    for name in methods:
        method = METHODS[name]
        start = time.perf_counter()
        if method.fit:
            observations = [
                dataclasses.replace(p, init=sim.hmr_init[p.person_id] if method.external_init else None)
                for p in people
            ]
            fits = setup.fitters[method.scheme].fit(observations, K, origin, method.options)
            bodies = [
                (f.vertices.astype(np.float64), f.joints.astype(np.float64), sorted(f.flags)) for f in fits
            ]
        else:
            bodies = [(*_forward(setup.model, sim.hmr_init[p.person_id]), []) for p in people]
        seconds = time.perf_counter() - start
        for obs, ctx, (verts, joints, flags) in zip(people, context, bodies, strict=True):
            errors = score(verts, joints, truth[obs.person_id], method.root_aligned)
            cases.append(
                Case(
                    name,
                    sensor,
                    seed,
                    obs.person_id,
                    **ctx,
                    **errors,
                    flags=flags,
                    value=value,
                    seconds=seconds,
                )
            )
    return cases


def simulate(
    seed: int, setup: Setup, sensor: str, n_people: tuple[int, int], distance: tuple[float, float]
) -> Any:
    from smplify3d_ros.sim.world import simulate_scene

    rng = np.random.default_rng([seed, 7])
    n = int(rng.integers(n_people[0], n_people[1] + 1))
    return simulate_scene(seed, setup.config.sim, sensor=sensor, n_people=n, distance_range=distance)


def run_scenes(
    setup: Setup,
    sensor: str,
    seeds: Sequence[int],
    methods: Sequence[str],
    n_people: tuple[int, int],
    distance: tuple[float, float],
    value: float | None = None,
    progress: bool = True,
    desc: str = "",
    calibration_error: float = 0.0,
) -> list[Case]:
    from tqdm import tqdm

    cases: list[Case] = []
    bar = tqdm(seeds, desc=desc or sensor, unit="scene", disable=not progress, file=sys.stderr)
    for seed in bar:
        sim = simulate(seed, setup, sensor, n_people, distance)
        cases += evaluate_scene(sim, seed, sensor, setup, methods, value, calibration_error)
        bar.set_postfix(people=len({(c.scene, c.person_id) for c in cases}))
    return cases


# -- summaries --------------------------------------------------------------------------------------------
def summarize(cases: Sequence[Case], method: str, sensor: str, **extra: Any) -> dict[str, Any]:
    """One JSON row (mm; std = standard deviation over people)."""
    pick = [c for c in cases if c.method == method and c.sensor == sensor]

    def mean(key: str) -> float | None:
        return round(float(np.mean([getattr(c, key) for c in pick])), 2) if pick else None

    def std(key: str) -> float | None:
        return round(float(np.std([getattr(c, key) for c in pick])), 2) if pick else None

    scene_seconds = {(c.scene, c.value): c.seconds for c in pick}  # one fit call per scene
    row = {
        "method": method,
        "sensor": sensor,
        "n": len(pick),
        "pve_mm": mean("pve"),
        "mpjpe_mm": mean("mpjpe"),
        "pa_mpjpe_mm": mean("pa_mpjpe"),
        "mpjpe_root_aligned_mm": mean("mpjpe_root_aligned"),
        "pve_std_mm": std("pve"),
        "mpjpe_std_mm": std("mpjpe"),
        "mpjpe_median_mm": round(float(np.median([c.mpjpe for c in pick])), 2) if pick else None,
        "seconds_per_person": round(sum(scene_seconds.values()) / len(pick), 3) if pick else None,
    }
    row.update(extra)
    return row


def markdown_table(rows: Sequence[dict[str, Any]], extra_columns: Sequence[str] = ()) -> str:
    def fmt(x: Any) -> str:
        return "-" if x is None else f"{x:.1f}"

    def seconds(x: Any) -> str:
        return "-" if x is None else f"{x:.2f}"

    head = [
        "method",
        "sensor",
        *extra_columns,
        "n",
        "PVE mm",
        "MPJPE mm",
        "PA-MPJPE mm",
        "MPJPE root-aligned mm",
        "MPJPE median mm",
        "s / person",
    ]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] * 2 + ["---:"] * (len(head) - 2)) + "|"]
    for r in rows:
        extra = [str(r.get(c, "")) for c in extra_columns]
        lines.append(
            f"| {r['method']} | {SENSOR_LABELS.get(r['sensor'], r['sensor'])} | "
            + "".join(f"{e} | " for e in extra)
            + f"{r['n']} | {fmt(r['pve_mm'])} ± {fmt(r['pve_std_mm'])} | {fmt(r['mpjpe_mm'])} ± "
            f"{fmt(r['mpjpe_std_mm'])} | {fmt(r['pa_mpjpe_mm'])} | {fmt(r['mpjpe_root_aligned_mm'])} | "
            f"{fmt(r.get('mpjpe_median_mm'))} | {seconds(r.get('seconds_per_person'))} |"
        )
    return "\n".join(lines)


def target_lines(rows: Sequence[dict[str, Any]]) -> list[str]:
    """The project's ratio targets, for every sensor that has both rows."""
    lines = []
    by = {(r["method"], r["sensor"]): r for r in rows}
    for sensor in dict.fromkeys(r["sensor"] for r in rows):
        icp, ours = by.get(("hmr_init_icp", sensor)), by.get(("smplify3d_three_stage", sensor))
        if not icp or not ours or not icp["mpjpe_mm"] or ours["mpjpe_mm"] is None:
            continue
        ratio = ours["mpjpe_mm"] / icp["mpjpe_mm"]
        target = TARGET_RATIO.get(sensor)
        verdict = (
            "" if target is None else f" (target <= {target:.2f}: {'met' if ratio <= target else 'NOT met'})"
        )
        lines.append(
            f"{SENSOR_LABELS.get(sensor, sensor)}: three-stage / init+ICP MPJPE = "
            f"{ours['mpjpe_mm']:.1f} / {icp['mpjpe_mm']:.1f} = {ratio:.2f}{verdict}"
        )
    return lines


# -- plots ------------------------------------------------------------------------------------------------
def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_methods(rows: Sequence[dict[str, Any]], path: Path, title: str) -> Path:
    """Grouped bars: PVE, MPJPE (mean and median), PA-MPJPE per method."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    keys = [("pve_mm", "PVE"), ("mpjpe_mm", "MPJPE"), ("mpjpe_median_mm", "MPJPE median"),
            ("pa_mpjpe_mm", "PA-MPJPE")]  # fmt: skip
    x = np.arange(len(rows))
    width = 0.8 / len(keys)
    for k, (key, label) in enumerate(keys):
        values = [r[key] if r[key] is not None else np.nan for r in rows]
        bars = ax.bar(x + (k - (len(keys) - 1) / 2) * width, values, width, label=label)
        ax.bar_label(bars, fmt="%.0f", fontsize=7)
    ax.set_xticks(x, [METHODS[r["method"]].label or r["method"] for r in rows], rotation=20, ha="right")
    ax.set_ylabel("error (mm)")
    ax.set_yscale("log")
    ax.set_title(title, pad=28)
    ax.legend(ncol=len(keys), fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def plot_sweep(rows: Sequence[dict[str, Any]], path: Path, xlabel: str, title: str) -> Path:
    """Mean (solid) and median (dotted) MPJPE of each method against the swept value; the median shows
    the typical person, the mean also the failures (ICP not converging, people without points)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for method in dict.fromkeys(r["method"] for r in rows):
        pick = sorted((r for r in rows if r["method"] == method), key=lambda r: r["value"])
        x = [r["value"] for r in pick]
        label = METHODS[method].label
        (line,) = ax.plot(x, [r["mpjpe_mm"] for r in pick], "o-", label=f"{label}: mean")
        median = [r["mpjpe_median_mm"] for r in pick]
        ax.plot(x, median, "s:", color=line.get_color(), alpha=0.7, label=f"{label}: median")
    ax.set_xlabel(xlabel)
    ax.set_ylabel("MPJPE (mm)")
    ax.set_ylim(bottom=0)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return _save(fig, path)


def plot_sensors(rows: Sequence[dict[str, Any]], path: Path, title: str) -> Path:
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4.5))
    sensors = list(dict.fromkeys(r["sensor"] for r in rows))
    methods = list(dict.fromkeys(r["method"] for r in rows))
    x = np.arange(len(sensors))
    width = 0.8 / len(methods)
    by = {(r["method"], r["sensor"]): r for r in rows}
    for k, method in enumerate(methods):
        values = [by[(method, s)]["mpjpe_mm"] if (method, s) in by else np.nan for s in sensors]
        offset = x + (k - (len(methods) - 1) / 2) * width
        bars = ax.bar(offset, values, width, label=f"{METHODS[method].label}: mean")
        ax.bar_label(bars, fmt="%.0f", fontsize=8)
        medians = [by[(method, s)]["mpjpe_median_mm"] if (method, s) in by else np.nan for s in sensors]
        ax.plot(offset, medians, "k_", markersize=14, markeredgewidth=2, label="median" if k == 0 else None)
    ax.set_xticks(x, [SENSOR_LABELS.get(s, s) for s in sensors])
    ax.set_ylabel("MPJPE (mm)")
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    return _save(fig, path)


def plot_density(cases: Sequence[Case], path: Path, title: str) -> Path:
    """MPJPE against Eq. 9 density (log bins) and against distance, per sensor."""
    plt = _pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    density_edges = np.array([1, 10, 25, 50, 100, 200, 400, 800, 1600, 3200], dtype=float)
    distance_edges = np.arange(2.0, 22.0, 2.0)
    for sensor in dict.fromkeys(c.sensor for c in cases):
        for method, style in (("smplify3d_three_stage", "o-"), ("hmr_init_icp", "x:")):
            pick = [c for c in cases if c.sensor == sensor and c.method == method]
            if not pick:
                continue
            kind = "3-stage" if method.startswith("smplify") else "init+ICP"
            label = f"{SENSOR_LABELS.get(sensor, sensor)} {kind}"
            for ax, key, edges in (
                (axes[0], "density", density_edges),
                (axes[1], "distance_m", distance_edges),
            ):
                xs, ys = _binned(pick, key, edges)
                ax.plot(xs, ys, style, label=label, alpha=0.9 if style == "o-" else 0.5)
    axes[0].set_xscale("log")
    for ax in axes:
        ax.set_yscale("log")
    axes[0].set_xlabel("LiDAR density on the person (points / m², Eq. 9)")
    axes[1].set_xlabel("distance (m)")
    for ax in axes:
        ax.set_ylabel("median MPJPE per bin (mm)")
        ax.grid(alpha=0.3, which="both")
    axes[0].axvline(200, color="grey", lw=0.8, ls="--")
    axes[1].legend(fontsize=7, ncol=2)
    fig.suptitle(title)
    return _save(fig, path)


def _binned(
    cases: Sequence[Case], key: str, edges: np.ndarray, min_count: int = 3
) -> tuple[list[float], list[float]]:
    values = np.array([getattr(c, key) for c in cases])
    errors = np.array([c.mpjpe for c in cases])
    xs, ys = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        inside = (values >= lo) & (values < hi)
        if inside.sum() >= min_count:
            xs.append(float(np.median(values[inside])))
            ys.append(float(np.median(errors[inside])))
    return xs, ys


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _pyplot().close(fig)
    return path


# -- studies ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sweep:
    """A study that sweeps one simulated-sensor parameter."""

    key: str  # field of the sensor's LidarSensorConfig
    values: tuple[float, ...]
    to_config: Callable[[float], float]  # swept value -> config value
    xlabel: str


SWEEPS = {
    "range_noise": Sweep(
        "range_noise_m", (0.0, 10.0, 20.0, 30.0, 40.0, 50.0), lambda mm: mm / 1000.0, "range noise σ (mm)"
    ),
    "angular_noise": Sweep(
        "angular_noise_deg", (0.0, 0.02, 0.04, 0.06, 0.08, 0.1), lambda d: d, "angular noise σ (deg)"
    ),
    "dropout": Sweep("dropout", (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6), lambda p: p, "drop-out fraction"),
}
CALIBRATION_ERRORS = (0.0, 0.5, 1.0, 2.0, 3.0)  # deg of rotation and cm of translation, see `miscalibrated`
STUDIES = ("sensors", *SWEEPS, "calibration", "density", "ablation")
STUDY_METHODS = ("hmr_init_icp", "smplify3d_three_stage")
CALIBRATION_METHODS = ("hmr_init_icp", "smplify3d_single_stage", "smplify3d_three_stage")
PARTLY_HIDDEN = 0.9  # ablation subset: people this much or less visible (others, objects, image border)
ABLATION_METHODS = (
    "smplify3d_three_stage",
    "ablation_no_chamfer",
    "ablation_no_occlusion_prior",
    "ablation_no_visibility",
)


@dataclass
class Report:
    rows: list[dict[str, Any]]
    cases: list[Case]
    table: str
    plots: list[Path]
    notes: list[str] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)  # more JSON keys


def run_main(args: argparse.Namespace, setup_for: Callable[..., Setup]) -> Report:
    sensor = resolve_sensor(args.sensor)
    setup = setup_for(sensor)
    seeds = range(args.seed, args.seed + args.scenes)
    cases = run_scenes(setup, sensor, seeds, MAIN_METHODS, args.people, args.distance, progress=args.progress)
    rows = [summarize(cases, m, sensor) for m in MAIN_METHODS]
    min_points = setup.config.fitting.min_points
    with_lidar = [c for c in cases if c.num_points >= min_points]
    subset = [summarize(with_lidar, m, sensor, subset=f"num_points >= {min_points}") for m in MAIN_METHODS]
    plots = []
    if args.plot_dir is not None:
        plots.append(
            plot_methods(
                rows,
                args.plot_dir / f"bench_{sensor}.png",
                f"{SENSOR_LABELS[sensor]}: {rows[0]['n']} people, {len(seeds)} scenes, "
                f"{args.distance[0]:g}-{args.distance[1]:g} m",
            )
        )
    table = markdown_table(rows)
    notes = target_lines(rows)
    table += f"\n\nPeople with at least {min_points} LiDAR points (fitting.min_points; the others are fitted "
    table += "from the image alone):\n\n" + markdown_table(subset)
    notes += [f"(people with LiDAR) {line}" for line in target_lines(subset)]
    return Report(rows, cases, table, plots, notes, {"rows_with_lidar": subset})


def _add_part(
    cases: list[Case], rows: list[dict[str, Any]], args: argparse.Namespace, setup: Setup, sensor: str,
    seeds: Sequence[int], methods: Sequence[str], distance: tuple[float, float], study: str | None = None,
    value: float | None = None, calibration_error: float = 0.0,
) -> None:
    """Run `methods` on `seeds` and append the cases and one summary row per method (with the study and
    swept value, when given)."""
    part = run_scenes(setup, sensor, seeds, methods, args.people, distance, value=value, progress=args.progress,
                      desc="" if value is None else f"{study}={value:g}", calibration_error=calibration_error)
    cases += part
    extra = {} if value is None else {"study": study, "value": value}
    rows += [summarize(part, m, sensor, **extra) for m in methods]


def run_study(args: argparse.Namespace, setup_for: Callable[..., Setup]) -> Report:
    study = args.study
    sensor = resolve_sensor(args.sensor)
    seeds = range(args.seed, args.seed + args.scenes)
    cases: list[Case] = []
    rows: list[dict[str, Any]] = []
    plot_path = None if args.plot_dir is None else args.plot_dir / f"study_{study}_{sensor}.png"
    plots = []
    columns: tuple[str, ...] = ()
    if study == "sensors":
        for s in SENSOR_LABELS:
            _add_part(cases, rows, args, setup_for(s), s, seeds, STUDY_METHODS, args.distance)
        if plot_path is not None:
            plot_path = plot_path.with_name(f"study_{study}.png")
            plots.append(
                plot_sensors(
                    rows,
                    plot_path,
                    f"MPJPE per sensor ({len(seeds)} scenes, {args.distance[0]:g}-{args.distance[1]:g} m)",
                )
            )
    elif study in SWEEPS:
        sweep = SWEEPS[study]
        for value in sweep.values:
            overrides = {"sim": {"lidar": {"sensors": {sensor: {sweep.key: sweep.to_config(value)}}}}}
            _add_part(cases, rows, args, setup_for(sensor, overrides), sensor, seeds, STUDY_METHODS, args.distance,
                      study, value)
        columns = ("value",)
        if plot_path is not None:
            plots.append(
                plot_sweep(
                    rows,
                    plot_path,
                    sweep.xlabel,
                    f"{SENSOR_LABELS[sensor]}: {study.replace('_', ' ')} ({len(seeds)} scenes)",
                )
            )
    elif study == "calibration":
        setup = setup_for(sensor)
        for value in CALIBRATION_ERRORS:
            _add_part(cases, rows, args, setup, sensor, seeds, CALIBRATION_METHODS, args.distance, study, value,
                      calibration_error=value)
        columns = ("value",)
        if plot_path is not None:
            plots.append(plot_sweep(rows, plot_path, "LiDAR-camera calibration error (deg and cm)",
                                    f"{SENSOR_LABELS[sensor]}: calibration error ({len(seeds)} scenes)"))
    elif study == "density":
        distance = (2.0, 20.0) if args.distance_given is None else args.distance
        args.distance = distance  # for the JSON's meta
        for s in SENSOR_LABELS:
            _add_part(cases, rows, args, setup_for(s), s, seeds, STUDY_METHODS, distance)
        if plot_path is not None:
            plot_path = plot_path.with_name(f"study_{study}.png")
            plots.append(
                plot_density(
                    cases,
                    plot_path,
                    f"Error against LiDAR density and distance "
                    f"({len(seeds)} scenes per sensor, {distance[0]:g}-"
                    f"{distance[1]:g} m)",
                )
            )
    elif study == "ablation":
        cases = run_scenes(
            setup_for(sensor),
            sensor,
            seeds,
            ABLATION_METHODS,
            args.people,
            args.distance,
            progress=args.progress,
        )
        rows = [summarize(cases, m, sensor, subset="all") for m in ABLATION_METHODS]
        hidden = [c for c in cases if c.visible_fraction < PARTLY_HIDDEN]
        rows += [
            summarize(hidden, m, sensor, subset=f"visible < {PARTLY_HIDDEN:g}") for m in ABLATION_METHODS
        ]
        columns = ("subset",)
        if plot_path is not None:
            plots.append(
                plot_methods(
                    rows[: len(ABLATION_METHODS)],
                    plot_path,
                    f"{SENSOR_LABELS[sensor]}: ablation ({rows[0]['n']} people)",
                )
            )
    else:
        raise ValueError(f"unknown study {study!r}; known: {', '.join(STUDIES)}")
    for r in rows:
        r.setdefault("study", study)
    return Report(rows, cases, markdown_table(rows, columns), plots)


def profile_for(sensor: str, profile: str | None) -> str | None:
    """The params profile of a run: the one given, else the sensor's own (params/ouster64.yaml for
    os1_64) when it exists, else the default (jackal_vlp16)."""
    from smplify3d_ros.config import params_dir

    if profile is not None:
        return profile
    name = {v: k for k, v in SENSOR_ALIASES.items()}.get(sensor, sensor)
    return name if (params_dir() / f"{name}.yaml").exists() and sensor != "vlp16" else None


def resolve_sensor(name: str) -> str:
    if name in SENSOR_LABELS:
        return name
    if name in SENSOR_ALIASES:
        return SENSOR_ALIASES[name]
    raise ValueError(f"unknown sensor {name!r}; known: {', '.join([*SENSOR_ALIASES, *SENSOR_LABELS])}")


# -- command line -----------------------------------------------------------------------------------------
def _pair(text: str, cast: Callable[[str], Any]) -> tuple[Any, Any]:
    parts = text.replace(",", "-").split("-") if cast is int else text.split(",")
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2:
        raise argparse.ArgumentTypeError(f"expected MIN{',' if cast is float else '-'}MAX, got {text!r}")
    low, high = cast(parts[0]), cast(parts[1])
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
        "--sensor",
        default="vlp16",
        help="simulated LiDAR: vlp16 (default), ouster32, ouster64, ouster128 (or os1_64, ...)",
    )
    parser.add_argument("--scenes", type=int, default=40, help="number of seeded scenes (default 40)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first scene")
    parser.add_argument(
        "--people",
        type=lambda s: _pair(s, int),
        default=(1, 3),
        metavar="MIN-MAX",
        help="people per scene (default 1-3)",
    )
    parser.add_argument(
        "--distance",
        type=lambda s: _pair(s, float),
        default=None,
        metavar="MIN,MAX",
        help="people's distance from the camera, m (default 3,8; density study 2,20)",
    )
    parser.add_argument(
        "--study", choices=STUDIES, default=None, help="run a study instead of the main table"
    )
    parser.add_argument("--json", type=Path, default=None, help="write the rows (and per-person cases) here")
    parser.add_argument(
        "--plot-dir", type=Path, default=DOCS_DIR, help=f"where plots go (default {DOCS_DIR})"
    )
    parser.add_argument("--no-plot", action="store_true", help="write no plot")
    parser.add_argument(
        "--profile",
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


def run(args: argparse.Namespace) -> int:
    args.distance_given = args.distance
    args.distance = args.distance or (3.0, 8.0)
    args.progress = not args.no_progress
    if args.no_plot:
        args.plot_dir = None
    try:
        resolve_sensor(args.sensor)
    except ValueError as e:
        print(e, file=sys.stderr)
        return 2
    base = overrides_from(args.overrides)
    schemes = {METHODS[m].scheme for m in (*MAIN_METHODS, *ABLATION_METHODS)}
    cache: dict[str, Setup] = {}

    profiles: dict[str, str | None] = {}

    def setup_for(sensor: str, extra: dict[str, Any] | None = None) -> Setup:
        overrides = merge(base, extra or {})
        profile = profiles[sensor] = profile_for(sensor, args.profile)
        key = json.dumps([profile, overrides], sort_keys=True)
        if key not in cache:
            cache.clear()  # one setup alive at a time (fitters hold tensors)
            cache[key] = Setup.create(profile, overrides or None, schemes)
        return cache[key]

    start = time.perf_counter()
    report = run_study(args, setup_for) if args.study else run_main(args, setup_for)
    elapsed = time.perf_counter() - start
    print(report.table)
    for line in report.notes:
        print(line)
    for path in report.plots:
        print(f"plot: {path}")
    print(f"{len(report.cases)} person-method cases in {elapsed:.0f} s")
    if args.json is not None:
        meta = {
            "study": args.study,
            "sensor": resolve_sensor(args.sensor),
            "scenes": args.scenes,
            "seed": args.seed,
            "people": list(args.people),
            "distance_m": list(args.distance),
            "profiles": profiles,
            "overrides": base,
            "fitting": to_dict(next(iter(cache.values())).config.fitting) if cache else None,
            "code": code_version(),
            "seconds": round(elapsed, 1),
        }
        doc = {
            "rows": report.rows,
            **report.extra,
            "meta": meta,
            "cases": [dataclasses.asdict(c) for c in report.cases],
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(doc, indent=1))
        print(f"wrote {args.json}")
    return 0


def code_version() -> str:
    """The commit of the working tree; with uncommitted changes to the code or parameters, "-dirty-" and
    a hash of that diff (two runs with equal strings ran the same code)."""
    import hashlib
    import subprocess

    root = Path(__file__).resolve().parents[2]
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


def main() -> int:  # `python -m smplify3d_ros.eval.bench`
    parser = argparse.ArgumentParser(prog="smplify3d bench", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args())


if __name__ == "__main__":
    raise SystemExit(main())
