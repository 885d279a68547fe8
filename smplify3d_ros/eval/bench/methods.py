"""The bench's methods and how one simulated scene is scored: every method sees the same people.

Per detected person the bench runs the frame path the node runs (`frame_fitter.FrameFitter`: people
selected, keypoints undistorted, each person's points cut out of the full scan), then each method's fit,
and scores the bodies against the simulator's ground truth (mm).
"""

from __future__ import annotations

import dataclasses
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from smplify3d_ros.eval import metrics
from smplify3d_ros.fitting.options import FitOptions
from smplify3d_ros.keypoints import hip_midpoint

if TYPE_CHECKING:
    from smplify3d_ros.sim.world import SimPerson
    from smplify3d_ros.types import BodyParams

SENSOR_ALIASES = {"vlp16": "vlp16", "ouster32": "os1_32", "ouster64": "os1_64", "ouster128": "os1_128"}
SENSOR_LABELS = {"vlp16": "VLP-16", "os1_32": "Ouster-32", "os1_64": "Ouster-64", "os1_128": "Ouster-128",
                 "livox": "Livox-like"}
SPINNING_SENSORS = ("vlp16", "os1_32", "os1_64", "os1_128")  # the sensors and density studies' sensors
ROBOT_METHOD = "builtin_init_three_stage"  # the robot path: no image HMR upstream, the built-in initializer

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
    truth_start: bool = False  # the true body as one more start beside the built-in ones (an oracle)
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
        # what a perfect search could give the robot path: the true body competes with the built-in starts
        # (in the slot of a track's warm start) and goes on through the same refinement, ICP and stages;
        # where it leads, the fit ends where the objective's minimum near the truth lies
        Method("builtin_init_truth_start", external_init=False, truth_start=True,
               label="built-in init + true start (oracle)"),
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
    heading_deg: float  # true body heading against the direction to the camera: 0 facing it, 180 back to it
    family: str  # true pose family
    preset: str  # true body shape preset
    num_points: int  # the person's extracted LiDAR points
    density: float  # thesis Eq. 9: extracted points per m² of the true body's projected area
    occluded_parts: bool  # some body part's keypoints are below the image visibility threshold
    visible_fraction: float  # simulator: fraction of the silhouette the camera sees
    pve: float
    mpjpe: float
    pa_mpjpe: float
    mpjpe_root_aligned: float
    flags: list[str] = field(default_factory=list)
    chamfer_m: float | None = None  # the fit's own chamfer to its points (fit.quality.chamfer_m; None: no points)
    # the body's chamfer and its points' half, and the true body's, against the same points by one rule
    # (`Fitter.surface_distances`: every visible vertex; the truth's is what a perfect fit would read)
    scored_chamfer_m: float | None = None
    scored_points_to_mesh_m: float | None = None
    truth_chamfer_m: float | None = None
    truth_points_to_mesh_m: float | None = None
    value: float | None = None  # the swept parameter of a study
    seconds: float = 0.0  # fit time of the whole scene's people (same for every person of the scene)
    people_in_fit: int = 1  # people that fit call fitted together: this person's share is seconds / this


@dataclass
class Setup:
    """What a bench run needs: configuration, body model, fitters per scheme (None: the profile's own)."""

    config: Any  # smplify3d_ros.config.Config
    sim: Any  # smplify3d_ros.sim.config.SimConfig
    model: Any
    fitters: dict[str | None, Any]

    @classmethod
    def create(
        cls, profile: str | None, overrides: dict[str, Any] | None, schemes: Iterable[str | None]
    ) -> Setup:
        from smplify3d_ros.body import load_body_model
        from smplify3d_ros.config import load_config
        from smplify3d_ros.fitting.fitter import Fitter
        from smplify3d_ros.sim.config import load_sim_config

        config, sim = load_config(profile, overrides), load_sim_config(profile, overrides)
        model = load_body_model(config.fitting.body.model, config.fitting.body)
        fitters = {}
        for scheme in dict.fromkeys([None, *schemes]):
            fitting = config.fitting
            if scheme is not None and fitting.optimizer.scheme != scheme:
                profiles = dict(fitting.profiles)
                profiles[fitting.profile] = dataclasses.replace(fitting.optimizer, scheme=scheme)
                fitting = dataclasses.replace(fitting, profiles=profiles)
            fitters[scheme] = Fitter(fitting, model=model)
        return cls(config, sim, model, fitters)



# -- scoring ----------------------------------------------------------------------------------------------
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
    """Per-person facts every method shares: distance, points, Eq. 9 density, occluded parts, the true
    body's chamfer to the points."""
    from smplify3d_ros.fitting.visibility import occluded_parts
    from smplify3d_ros.sim.scene import make_mount

    mount = make_mount(setup.sim.mount)
    hips = hip_midpoint(truth.keypoints3d)
    lidar_origin = sim.frame.T_cam_lidar[:3, 3]
    density = (
        metrics.lidar_density(
            len(obs.points), truth.vertices, setup.model.faces.cpu().numpy(), lidar_origin, mount.up_cam
        )
        if len(obs.points)
        else 0.0
    )
    threshold = setup.config.fitting.visibility.keypoint_conf_image
    chamfer, to_mesh = setup.fitters[None].surface_distances(obs, truth.vertices, lidar_origin)  # nan: no points
    return {
        "truth_chamfer_m": _finite(chamfer),
        "truth_points_to_mesh_m": _finite(to_mesh),
        "distance_m": float(np.hypot(hips[0], hips[2])),
        "heading_deg": heading_to_camera_deg(truth.params.root_orient, hips, mount.up_cam),
        "family": truth.family,
        "preset": truth.preset,
        "num_points": len(obs.points),
        "density": float(density),
        "occluded_parts": bool(occluded_parts(obs.keypoints[:, 2], threshold).any()),
        "visible_fraction": float(sim.visible_fraction.get(obs.person_id, float("nan"))),
    }


def heading_to_camera_deg(root_orient: np.ndarray, position: np.ndarray, up: np.ndarray) -> float:
    """Angle (deg, 0-180) between a body's forward direction and the direction from the body to the
    camera, both horizontal: 0 faces the camera, 90 is side-on, 180 shows the back. Canonical body axes
    (types.BodyParams): z forward."""
    from scipy.spatial.transform import Rotation

    up = up / np.linalg.norm(up)
    forward = Rotation.from_rotvec(root_orient).as_matrix()[:, 2]
    to_camera = -np.asarray(position, np.float64)
    a, b = forward - (forward @ up) * up, to_camera - (to_camera @ up) * up
    cos = a @ b / max(np.linalg.norm(a) * np.linalg.norm(b), 1e-12)
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


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


@dataclass
class Coverage:
    """Who of the scenes' people the scores cover: the rest never reached a fit."""

    in_scene: int = 0  # people placed in the scenes
    detected: int = 0  # ... that the detector model found
    fitted: int = 0  # ... that the frame path kept and fitted (the people the cases score)
    dropped: dict[str, int] = field(default_factory=dict)  # frame_fitter's reasons -> people left out

    def add(self, sim: Any, observed: Any, fitted: int) -> None:
        self.in_scene += len(sim.people)
        self.detected += len(sim.frame.keypoints)
        self.fitted += fitted
        for reason, n in observed.people_dropped.items():
            self.dropped[reason] = self.dropped.get(reason, 0) + int(n)


def evaluate_scene(
    sim: Any,
    seed: int,
    sensor: str,
    setup: Setup,
    methods: Sequence[str],
    value: float | None = None,
    calibration_error: float = 0.0,
    coverage: Coverage | None = None,
) -> list[Case]:
    """Cases of every method for every detected person of one simulated scene; with `calibration_error`
    (see `miscalibrated`) the pipeline uses a wrong LiDAR-to-camera transform. `coverage` counts who
    the cases leave out."""
    from smplify3d_ros.frame_fitter import FrameFitter

    frame = sim.frame
    if calibration_error:
        frame = dataclasses.replace(frame, T_cam_lidar=miscalibrated(frame.T_cam_lidar, calibration_error, seed))
    observed = FrameFitter(setup.config, setup.fitters[None]).observe(frame)
    truth = {p.person_id: p for p in sim.people}
    people = [p for p in observed.observations if p.person_id in truth and p.person_id in sim.hmr_init]
    if coverage is not None:
        coverage.add(sim, observed, len(people))
    if not people:
        return []
    context = [person_context(sim, obs, truth[obs.person_id], setup) for obs in people]
    cases = []
    for name in methods:
        method = METHODS[name]
        start = time.perf_counter()
        if method.fit:
            observations = [
                dataclasses.replace(p, init=sim.hmr_init[p.person_id] if method.external_init else None,
                                    hypothesis=_true_start(truth[p.person_id]) if method.truth_start else None)
                for p in people
            ]
            fitter = FrameFitter(setup.config, setup.fitters[method.scheme])
            fits = fitter.fit_observed(dataclasses.replace(observed, observations=observations), method.options).fits
            bodies = [(f.vertices.astype(np.float64), f.joints.astype(np.float64), sorted(f.flags),
                       _finite(f.quality.chamfer_m)) for f in fits]
        else:
            bodies = [(b.vertices, b.joints, [], None) for b in setup.model.posed([sim.hmr_init[p.person_id]
                                                                                   for p in people])]
        seconds = time.perf_counter() - start
        for obs, ctx, (verts, joints, flags, chamfer) in zip(people, context, bodies, strict=True):
            errors = score(verts, joints, truth[obs.person_id], method.root_aligned)
            surface = (setup.fitters[None].surface_distances(obs, verts, observed.lidar_origin)
                       if chamfer is not None else (float("nan"), float("nan")))
            cases.append(Case(name, sensor, seed, obs.person_id, **ctx, **errors, flags=flags, chamfer_m=chamfer,
                              scored_chamfer_m=_finite(surface[0]), scored_points_to_mesh_m=_finite(surface[1]),
                              value=value, seconds=seconds, people_in_fit=len(people)))
    return cases


def _true_start(person: SimPerson) -> BodyParams:
    """A simulated person's true body as a start (`PersonObservation.hypothesis`), whose `transl` is the
    hip midpoint, as the built-in starts' are (`Fitter._placed_state`), not the model's root."""
    params = person.params.copy()
    params.transl = hip_midpoint(person.keypoints3d)
    return params


def _finite(x: float) -> float | None:
    return float(x) if np.isfinite(x) else None


def simulate(
    seed: int, setup: Setup, scenario: str, sensor: str, n_people: tuple[int, int], distance: tuple[float, float]
) -> Any:
    """One scene of a bench scenario (`sim.bench.scenarios`) with the run's sensor, people and distances."""
    from smplify3d_ros.sim.world import simulate_scenario

    rng = np.random.default_rng([seed, 7])  # its own stream: the scene's people do not shift the scene
    n = int(rng.integers(n_people[0], n_people[1] + 1))
    return simulate_scenario(seed, setup.sim, scenario, sensor=sensor, n_people=n, distance_range=distance)


@dataclass
class SceneSet:
    """Which scenes a bench run scores: a scenario, its sensor, seeds, people per scene and distances."""

    scenario: str  # key of `sim.bench.scenarios`
    sensor: str  # key of `sim.lidar` sensors
    seeds: Sequence[int]
    people: tuple[int, int]
    distance: tuple[float, float]


def run_scenes(
    setup: Setup,
    scenes: SceneSet,
    methods: Sequence[str],
    value: float | None = None,
    progress: bool = True,
    desc: str = "",
    calibration_error: float = 0.0,
    coverage: Coverage | None = None,
) -> list[Case]:
    from tqdm import tqdm

    cases: list[Case] = []
    bar = tqdm(scenes.seeds, desc=desc or scenes.sensor, unit="scene", disable=not progress, file=sys.stderr)
    for seed in bar:
        sim = simulate(seed, setup, scenes.scenario, scenes.sensor, scenes.people, scenes.distance)
        cases += evaluate_scene(sim, seed, scenes.sensor, setup, methods, value, calibration_error, coverage)
        bar.set_postfix(people=len({(c.scene, c.person_id) for c in cases}))
    return cases


def profile_for(sensor: str, profile: str | None) -> str | None:
    """The params profile of a run: the one given, else the sensor's own (params/ouster64.yaml for
    os1_64) when it exists, else the default (jackal_vlp16)."""
    from smplify3d_ros.settings import params_dir

    if profile is not None:
        return profile
    name = {v: k for k, v in SENSOR_ALIASES.items()}.get(sensor, sensor)
    return name if (params_dir() / f"{name}.yaml").exists() and sensor != "vlp16" else None


def resolve_sensor(name: str) -> str:
    """A sensor's `sim.lidar` key from its name or alias (ouster64 -> os1_64)."""
    if name in SENSOR_LABELS:
        return name
    if name in SENSOR_ALIASES:
        return SENSOR_ALIASES[name]
    raise ValueError(f"unknown sensor {name!r}; known: {', '.join(dict.fromkeys([*SENSOR_ALIASES, *SENSOR_LABELS]))}")
