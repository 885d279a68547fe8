"""The main table (the robot path by distance and heading band, then the methods with an upstream HMR)
and the thesis's studies (sensors, noise sweeps, calibration, density, ablation)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from smplify3d_ros.eval.bench.methods import (
    MAIN_METHODS,
    METHODS,
    ROBOT_METHOD,
    SENSOR_LABELS,
    SPINNING_SENSORS,
    Case,
    Coverage,
    SceneSet,
    Setup,
    run_scenes,
)
from smplify3d_ros.eval.bench.plots import plot_bands, plot_density, plot_methods, plot_sensors, plot_sweep
from smplify3d_ros.eval.bench.report import (
    band_rows,
    band_table,
    chamfer_verdict,
    family_rows,
    markdown_table,
    summarize,
    surface_line,
    surface_summary,
    target_lines,
    verdict_line,
)


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
class BenchRun:
    """What one bench run covers (the command line's choices)."""

    scenario: str  # key of `sim.bench.scenarios`
    sensor: str  # key of `sim.lidar` sensors
    seeds: Sequence[int]  # one scene per seed
    people: tuple[int, int]  # people per scene, min and max
    distance: tuple[float, float] | None  # people's distance from the camera, m (None: the study's default)
    plot_dir: Path | None  # where plots go (None: no plot)
    progress: bool = True
    methods: Sequence[str] = MAIN_METHODS  # the main table's methods

    def distance_or(self, default: tuple[float, float]) -> tuple[float, float]:
        return self.distance if self.distance is not None else default

    def scenes(self, distance: tuple[float, float], sensor: str | None = None) -> SceneSet:
        return SceneSet(self.scenario, sensor or self.sensor, self.seeds, self.people, distance)


DENSITY_DISTANCE_M = (2.0, 20.0)  # the density study's distances, which it sweeps itself


@dataclass
class Report:
    rows: list[dict[str, Any]]
    cases: list[Case]
    table: str
    plots: list[Path]
    notes: list[str] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)  # more JSON keys
    distance: tuple[float, float] = (0.0, 0.0)  # the distances the run used


def _plot_path(run: BenchRun, name: str) -> Path | None:
    return None if run.plot_dir is None else run.plot_dir / name


def run_main(run: BenchRun, setup_for: Callable[..., Setup], default_distance: tuple[float, float]) -> Report:
    """The robot path by band, then every method overall and for the people with LiDAR points."""
    sensor, distance = run.sensor, run.distance_or(default_distance)
    setup = setup_for(sensor)
    coverage = Coverage()
    cases = run_scenes(setup, run.scenes(distance), run.methods, progress=run.progress, coverage=coverage)
    bench = setup.sim.bench
    missed_m = bench.scenarios[run.scenario].missed_chamfer_m
    rows = [summarize(cases, m, sensor) for m in run.methods]
    min_points = setup.config.fitting.min_points
    with_lidar = [c for c in cases if c.num_points >= min_points]
    subset = [summarize(with_lidar, m, sensor, subset=f"num_points >= {min_points}") for m in run.methods]
    extra: dict[str, Any] = {"rows_with_lidar": subset, "coverage": dataclasses.asdict(coverage)}
    tables = []
    if ROBOT_METHOD in run.methods:
        extra["bands"] = band_rows(cases, ROBOT_METHOD, sensor, bench, missed_m)
        extra["families"] = family_rows(cases, ROBOT_METHOD, sensor, missed_m)
        tables += [f"Robot path ({ROBOT_METHOD}: built-in initializer, raw scan, the node's frame path), by band:",
                   band_table(extra["bands"]), "Robot path by true pose family:", band_table(extra["families"])]
    oracle = [m for m in run.methods if METHODS[m].truth_start]
    if oracle:
        compared = [r for r in rows if r["method"] in (ROBOT_METHOD, *oracle)]
        tables += ["The robot path against a perfect search (the true body as one more start: an oracle, no robot "
                   "has it):", markdown_table(compared)]
    hmr = [m for m in run.methods if METHODS[m].external_init and m != ROBOT_METHOD]
    if "smplify3d_three_stage" in hmr:
        extra["bands_with_hmr"] = band_rows(cases, "smplify3d_three_stage", sensor, bench, missed_m)
    if hmr:
        tables += ["With an upstream HMR (the simulator's estimate: truth plus noise; no robot has one), all "
                   "methods:", markdown_table(rows)]
        if "bands_with_hmr" in extra:
            tables += ["smplify3d_three_stage with an upstream HMR, by band:", band_table(extra["bands_with_hmr"])]
        tables += [f"People with at least {min_points} LiDAR points (fitting.min_points; the others are fitted "
                   "from the image alone):", markdown_table(subset)]
    extra["chamfer_verdict"] = [chamfer_verdict(cases, m, missed_m, bench.off_mpjpe_mm)
                                for m in (ROBOT_METHOD, "smplify3d_three_stage") if m in run.methods]
    extra["surface"] = [surface_summary(cases, m) for m in (ROBOT_METHOD, "smplify3d_three_stage")
                        if m in run.methods]
    plots = _main_plots(run, rows, extra, distance)
    notes = [coverage_line(coverage), *map(verdict_line, extra["chamfer_verdict"]),
             *map(surface_line, extra["surface"])]
    notes += target_lines(rows) + [f"(people with LiDAR) {x}" for x in target_lines(subset)]
    return Report(rows, cases, "\n\n".join(tables), plots, notes, extra, distance)


def coverage_line(c: Coverage) -> str:
    dropped = ", ".join(f"{n} {reason}" for reason, n in sorted(c.dropped.items())) or "none"
    return (f"people: {c.in_scene} in the scenes, {c.detected} detected, {c.fitted} fitted and scored "
            f"(left out by the frame path: {dropped}; the others were not detected)")


def _main_plots(run: BenchRun, rows: list[dict[str, Any]], extra: dict[str, Any],
                distance: tuple[float, float]) -> list[Path]:
    plots = []
    label = f"{SENSOR_LABELS.get(run.sensor, run.sensor)}, {run.scenario}"
    where = f"{len(run.seeds)} scenes, {distance[0]:g}-{distance[1]:g} m"
    path = _plot_path(run, f"bench_{run.scenario}_{run.sensor}.png")
    if path is not None:
        plots.append(plot_methods(rows, path, f"{label}: {rows[0]['n']} people, {where}"))
    path = _plot_path(run, f"bench_{run.scenario}_{run.sensor}_bands.png")
    if path is not None and "bands" in extra:
        plots.append(plot_bands(extra["bands"], extra.get("bands_with_hmr", []), path,
                                f"{label}: robot path by band ({where})"))
    return plots


class _Study:
    """The cases and rows of one study, gathered part by part."""

    def __init__(self, name: str, run: BenchRun, distance: tuple[float, float]) -> None:
        self.name, self.run, self.distance = name, run, distance
        self.cases: list[Case] = []
        self.rows: list[dict[str, Any]] = []

    def add(self, setup: Setup, sensor: str, methods: Sequence[str], value: float | None = None,
            calibration_error: float = 0.0) -> None:
        """Run `methods` on the run's seeds; one summary row per method (with the swept value, if any)."""
        part = run_scenes(setup, self.run.scenes(self.distance, sensor), methods, value=value,
                          progress=self.run.progress, desc="" if value is None else f"{self.name}={value:g}",
                          calibration_error=calibration_error)
        self.cases += part
        extra = {} if value is None else {"study": self.name, "value": value}
        self.rows += [summarize(part, m, sensor, **extra) for m in methods]

    def report(self, plot: Path | None, columns: tuple[str, ...] = ()) -> Report:
        for r in self.rows:
            r.setdefault("study", self.name)
        return Report(self.rows, self.cases, markdown_table(self.rows, columns), [plot] if plot else [],
                      distance=self.distance)


def _sensors(study: _Study, setup_for: Callable[..., Setup]) -> Report:
    for sensor in SPINNING_SENSORS:
        study.add(setup_for(sensor), sensor, STUDY_METHODS)
    d, path = study.distance, _plot_path(study.run, "study_sensors.png")
    title = f"MPJPE per sensor ({len(study.run.seeds)} scenes, {d[0]:g}-{d[1]:g} m)"
    return study.report(path and plot_sensors(study.rows, path, title))


def _sweep(study: _Study, setup_for: Callable[..., Setup]) -> Report:
    sweep, sensor = SWEEPS[study.name], study.run.sensor
    for value in sweep.values:
        overrides = {"sim": {"lidar": {"sensors": {sensor: {sweep.key: sweep.to_config(value)}}}}}
        study.add(setup_for(sensor, overrides), sensor, STUDY_METHODS, value)
    path = _plot_path(study.run, f"study_{study.name}_{sensor}.png")
    title = f"{SENSOR_LABELS[sensor]}: {study.name.replace('_', ' ')} ({len(study.run.seeds)} scenes)"
    return study.report(path and plot_sweep(study.rows, path, sweep.xlabel, title), ("value",))


def _calibration(study: _Study, setup_for: Callable[..., Setup]) -> Report:
    sensor = study.run.sensor
    setup = setup_for(sensor)
    for value in CALIBRATION_ERRORS:
        study.add(setup, sensor, CALIBRATION_METHODS, value, calibration_error=value)
    path = _plot_path(study.run, f"study_calibration_{sensor}.png")
    title = f"{SENSOR_LABELS[sensor]}: calibration error ({len(study.run.seeds)} scenes)"
    return study.report(path and plot_sweep(study.rows, path, "LiDAR-camera calibration error (deg and cm)",
                                            title), ("value",))


def _density(study: _Study, setup_for: Callable[..., Setup]) -> Report:
    for sensor in SPINNING_SENSORS:
        study.add(setup_for(sensor), sensor, STUDY_METHODS)
    d, path = study.distance, _plot_path(study.run, "study_density.png")
    title = f"Error against LiDAR density and distance ({len(study.run.seeds)} scenes per sensor, {d[0]:g}-{d[1]:g} m)"
    return study.report(path and plot_density(study.cases, path, title))


def _ablation(study: _Study, setup_for: Callable[..., Setup]) -> Report:
    sensor = study.run.sensor
    study.cases = run_scenes(setup_for(sensor), study.run.scenes(study.distance), ABLATION_METHODS,
                             progress=study.run.progress)
    hidden = [c for c in study.cases if c.visible_fraction < PARTLY_HIDDEN]
    study.rows = [summarize(study.cases, m, sensor, subset="all") for m in ABLATION_METHODS]
    study.rows += [summarize(hidden, m, sensor, subset=f"visible < {PARTLY_HIDDEN:g}") for m in ABLATION_METHODS]
    path = _plot_path(study.run, f"study_ablation_{sensor}.png")
    title = f"{SENSOR_LABELS[sensor]}: ablation ({study.rows[0]['n']} people)"
    return study.report(path and plot_methods(study.rows[: len(ABLATION_METHODS)], path, title), ("subset",))


_STUDY_RUNNERS: dict[str, Callable[[_Study, Callable[..., Setup]], Report]] = {
    "sensors": _sensors, **{name: _sweep for name in SWEEPS}, "calibration": _calibration, "density": _density,
    "ablation": _ablation,
}


def run_study(name: str, run: BenchRun, setup_for: Callable[..., Setup],
              default_distance: tuple[float, float]) -> Report:
    """One of the thesis's studies (`STUDIES`) on the run's scenes (`default_distance`: the scenario's)."""
    if name not in _STUDY_RUNNERS:
        raise ValueError(f"unknown study {name!r}; known: {', '.join(STUDIES)}")
    default = DENSITY_DISTANCE_M if name == "density" else default_distance
    return _STUDY_RUNNERS[name](_Study(name, run, run.distance_or(default)), setup_for)
