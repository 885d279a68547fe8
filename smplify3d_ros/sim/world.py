"""The simulator's contract: one synthetic frame (`simulate_scene`) or a moving sequence
(`simulate_sequence`), with everything the pipeline receives and the ground truth to score it.

One frame: random people (pose families, body shapes) on the ground in front of a Jackal-like robot,
walls, boxes and pillars; a ray-cast LiDAR scan; a ray-cast camera image; the 2D keypoint detector
model on that image; a simulated image-HMR estimate per detected person.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from smplify3d_ros.sim.camera import make_camera, render, visible_fraction
from smplify3d_ros.sim.config import ScenarioConfig, SimConfig, scenario_sim_config
from smplify3d_ros.sim.detector import detect
from smplify3d_ros.sim.hmr import simulate_hmr
from smplify3d_ros.sim.lidar import simulate_scan
from smplify3d_ros.sim.people import sample_shape
from smplify3d_ros.sim.poses import FAMILIES, sample_pose
from smplify3d_ros.sim.scene import (
    Mount,
    PersonPlacement,
    PlacedPerson,
    Scene,
    SceneObject,
    assemble,
    footprint,
    ground_plane,
    make_mount,
    place_people,
    pose_people,
    prop_objects,
    random_objects,
    room_for,
    room_walls,
    turn_person,
    vertices_world,
)
from smplify3d_ros.types import BodyParams, Frame


@dataclass
class SimPerson:
    """Ground truth of one simulated person (camera frame)."""

    person_id: int
    params: BodyParams
    vertices: np.ndarray  # (V, 3) float32, m
    keypoints3d: np.ndarray  # (17, 3) float32 COCO-17, m
    joints: np.ndarray  # (J, 3) float32 model joints, m
    family: str = ""  # pose family (sim.poses)
    preset: str = ""  # body shape preset (sim.people)


@dataclass
class SimFrame:
    """One simulated frame: the pipeline's input (`frame`) and the ground truth."""

    frame: Frame  # detector keypoints (distorted px), rendered image, LiDAR points in the LiDAR frame
    point_labels: np.ndarray  # (N,) int32 per LiDAR point: person id >= 0, -1 ground, -2 static object
    people: list[SimPerson]  # every person in the scene, detected or not
    visible_fraction: dict[int, float]  # per person: fraction of the silhouette visible in the image
    lidar_fields: dict[str, np.ndarray]  # intensity float32, ring uint16, time float32 (s since scan start)
    hmr_init: dict[int, BodyParams]  # simulated image-HMR estimate per detected person
    mask: np.ndarray  # (H, W) int32 person id per pixel, -1 elsewhere


_MODELS: dict[str, object] = {}


def _load_model(cfg: SimConfig):
    """The body model, cached here too (`load_body_model` re-reads the configuration on every call)."""
    if cfg.body_model not in _MODELS:
        from smplify3d_ros.body import load_body_model

        _MODELS[cfg.body_model] = load_body_model(cfg.body_model)
    return _MODELS[cfg.body_model]


def _choose_family(rng: np.random.Generator, cfg: SimConfig, families) -> str:
    weights = dict(cfg.scene.family_weights)
    if families is not None:
        families = [families] if isinstance(families, str) else list(families)
        unknown = set(families) - set(FAMILIES)
        if unknown:
            raise ValueError(f"unknown pose families {sorted(unknown)}; known: {', '.join(FAMILIES)}")
        weights = {f: weights.get(f, 1.0) or 1.0 for f in families}
    names = list(weights)
    p = np.array([weights[n] for n in names], dtype=np.float64)
    return names[int(rng.choice(len(names), p=p / p.sum()))]


def random_people(
    rng: np.random.Generator,
    cfg: SimConfig,
    model,
    n_people: int,
    distance_range: tuple[float, float],
    families=None,
) -> tuple[Mount, list[PlacedPerson]]:
    """`n_people` random people (fewer if they do not fit) placed in the camera's view."""
    mount = make_mount(cfg.mount)
    placements = []
    for pid in range(n_people):
        family = _choose_family(rng, cfg, families)
        preset, shape = sample_shape(rng, cfg.people, model.shape_names)
        pose = sample_pose(model, family, rng, variation_scale=cfg.people.pose_variation_scale,
                           limit_variation=cfg.people.limit_variation)
        heading = float(rng.uniform(-np.pi, np.pi))
        placements.append(PersonPlacement(pid, preset, shape, pose, np.zeros(2), heading))
    posed = pose_people(model, placements, mount)
    half_fov = np.deg2rad(cfg.camera.hfov_deg) / 2.0
    placed = place_people(rng, posed, mount, cfg.scene, tuple(distance_range), half_fov)
    if cfg.scene.back_facing_prob > 0:  # no draw otherwise: scenes without it stay as they were
        placed = [_face_away(rng, p, mount, model, cfg) if rng.random() < cfg.scene.back_facing_prob else p
                  for p in placed]
    return mount, placed


def _face_away(rng: np.random.Generator, person: PlacedPerson, mount: Mount, model, cfg: SimConfig) -> PlacedPerson:
    """The person turned to face away from the camera, within `back_facing_spread_deg` of its ray."""
    bearing = float(np.arctan2(person.placement.position[1], person.placement.position[0]))
    spread = np.deg2rad(cfg.scene.back_facing_spread_deg)
    target = bearing + rng.uniform(-spread, spread)
    return turn_person(person, target - person.placement.heading, mount, model)


def static_objects(
    rng: np.random.Generator,
    cfg: SimConfig,
    model,
    mount: Mount,
    people: list[PlacedPerson],
    walls: bool,
    keep_out: list[tuple[np.ndarray, float]] | None = None,
) -> list[SceneObject]:
    """Ground, the people's props, walls around everyone, and boxes/pillars clear of the people."""
    objects = [ground_plane(cfg.scene.ground_half_size_m)]
    circles = list(keep_out or [])
    for person in people:
        props = prop_objects(person, model, mount, cfg.scene)
        objects += props
        circles.append(footprint(vertices_world(person, mount)))
        for prop in props:
            circles.append(footprint(prop.vertices))
    room = room_for(rng, cfg.scene, circles) if walls else None
    half_fov = np.deg2rad(cfg.camera.hfov_deg) / 2.0
    objects += random_objects(rng, cfg.scene, circles, room, half_fov)
    if room is not None:
        objects += room_walls(*room, cfg.scene.wall_height_m)
    return objects


def observe(
    rng: np.random.Generator, model, cfg: SimConfig, scene: Scene, sensor: str, stamp_ns: int
) -> SimFrame:
    """Run the sensors, the detector and the HMR model on an assembled scene."""
    lidar = cfg.lidar.sensor(sensor)  # unknown names fail here, before any rendering
    camera = make_camera(cfg.camera)
    mount = scene.mount
    rendering = render(scene.ray_scene, camera, scene.face_colors, cfg.render, mount.T_world_cam)
    scan = simulate_scan(scene.ray_scene, mount.T_cam_lidar, lidar, cfg.lidar.intensity, rng)
    people = scene.people
    detections = detect(
        rng, [(p.person_id, p.keypoints3d, p.vertices) for p in people], rendering, camera, cfg.detector
    )
    detected = {d.person_id for d in detections}
    gt = [(p.params, p.joints) for p in people if p.person_id in detected]
    estimates = simulate_hmr(rng, model, gt, cfg.hmr)
    hmr_init = {
        pid: est for pid, est in zip([p.person_id for p in people if p.person_id in detected], estimates)
    }
    frame = Frame(
        stamp_ns=stamp_ns,
        camera=camera,
        keypoints=(np.stack([d.keypoints for d in detections]) if detections else np.zeros((0, 17, 3))),
        person_ids=np.array([d.person_id for d in detections], dtype=np.int64),
        points_lidar=scan.points,
        T_cam_lidar=mount.T_cam_lidar,
        image=rendering.image,
    )
    return SimFrame(
        frame=frame,
        point_labels=scan.label,
        people=[SimPerson(p.person_id, p.params, p.vertices, p.keypoints3d, p.joints, p.placement.pose.family,
                          p.placement.preset) for p in people],
        visible_fraction={
            p.person_id: visible_fraction(
                scene.ray_scene, camera, p.person_id, p.vertices, cfg.render.visibility_rays
            )
            for p in people
        },
        lidar_fields=scan.fields(),
        hmr_init=hmr_init,
        mask=rendering.mask,
    )


def simulate_scene(
    seed: int,
    cfg: SimConfig,
    sensor: str = "vlp16",
    n_people: int | None = None,
    distance_range: tuple[float, float] | None = None,
    pose_families=None,
    walls: bool = True,
) -> SimFrame:
    """One random frame, fully determined by `seed` and `cfg`.

    `n_people` (default: random in `cfg.scene.n_people`; fewer when they do not fit), `distance_range`
    (m, default `cfg.scene.distance_range_m`), `pose_families` (a family name or a list; default: all,
    weighted by `cfg.scene.family_weights`), `walls`: enclose the scene in a room.
    """
    rng = np.random.default_rng(seed)
    model = _load_model(cfg)
    if n_people is None:
        n_people = int(rng.integers(cfg.scene.n_people[0], cfg.scene.n_people[1] + 1))
    distance_range = tuple(distance_range) if distance_range is not None else cfg.scene.distance_range_m
    mount, people = random_people(rng, cfg, model, n_people, distance_range, pose_families)
    objects = static_objects(rng, cfg, model, mount, people, walls)
    scene = assemble(rng, model, mount, people, objects, cfg.render)
    return observe(rng, model, cfg, scene, sensor, stamp_ns=0)


def simulate_scenario(
    seed: int,
    cfg: SimConfig,
    scenario: str,
    sensor: str | None = None,
    n_people: int | None = None,
    distance_range: tuple[float, float] | None = None,
) -> SimFrame:
    """One random frame of a bench scenario (`cfg.bench.scenarios`): its camera, families, headings and
    distances on top of `cfg`; `sensor`, `n_people` and `distance_range` override the scenario's."""
    sc = cfg.bench.scenarios.get(scenario)
    if sc is None:
        raise ValueError(f"unknown scenario {scenario!r}; known: {', '.join(cfg.bench.scenarios)}")
    return simulate_scene(seed, scenario_sim_config(cfg, scenario), sensor or sc.sensor, n_people,
                          distance_range, walls=sc.walls)


# -- sequences ----------------------------------------------------------------------------------------
@dataclass
class _Walker:
    """A person walking back and forth along a straight segment at constant speed; at each end they stand
    for `pause` seconds, turning round over `turn` of them (pause 0: an instant turn)."""

    person_id: int
    preset: str
    shape: np.ndarray
    centre: np.ndarray  # (2,) world, m: the segment's middle
    direction: np.ndarray  # (2,) unit
    half_length: float  # m
    speed: float  # m/s
    start: float  # m along the path at t = 0 (path coordinate in [0, 4 * half_length))
    stride: float  # m per gait cycle
    phase0: float
    pause: float = 0.0  # s standing at each end of the segment
    turn: float = 0.0  # s of the pause spent turning round

    def at(self, t: float) -> tuple[np.ndarray, float, float, bool]:
        """(position, heading, gait phase, walking) at time t."""
        L = self.half_length
        leg = 2 * L / self.speed  # s to walk the segment once
        cycle = 2 * (leg + self.pause)
        clock = self.start / self.speed + t
        laps, tau = divmod(clock, cycle)
        walked = laps * 2 * leg  # s spent walking, for the gait phase
        for sign in (1.0, -1.0):  # out along `direction`, then back
            direction = sign * self.direction
            heading = float(np.arctan2(direction[1], direction[0]))
            if tau < leg:
                phase = (self.phase0 + self.speed * (walked + tau - self.start / self.speed) / self.stride) % 1.0
                return self.centre + sign * (self.speed * tau - L) * self.direction, heading, phase, True
            walked, tau = walked + leg, tau - leg
            if tau < self.pause:
                turned = np.pi * min(tau / self.turn, 1.0) if self.turn > 0 else 0.0
                phase = (self.phase0 + self.speed * (walked - self.start / self.speed) / self.stride) % 1.0
                return self.centre + sign * L * self.direction, heading + turned, phase, False
            tau -= self.pause
        raise AssertionError("unreachable: tau < cycle")


def _walkers(
    rng: np.random.Generator, cfg: SimConfig, model, sc: ScenarioConfig, n_frames: int, rate_hz: float
) -> list[_Walker]:
    n = int(rng.integers(sc.n_people[0], sc.n_people[1] + 1))
    half_fov = np.deg2rad(cfg.camera.hfov_deg) / 2.0 - np.deg2rad(cfg.scene.fov_margin_deg)
    duration = n_frames / rate_hz
    lo, hi = sc.distance_m
    gap = cfg.sequence.depth_gap_m
    first = rng.uniform(lo, max(lo, hi - (n - 1) * gap))
    depths = [min(first + i * gap + rng.uniform(0.0, 0.3 * gap), hi + (n - 1) * gap) for i in range(n)]
    walkers = []
    for pid in range(n):
        preset, shape = sample_shape(rng, cfg.people, model.shape_names)
        speed = float(rng.uniform(*cfg.sequence.walk_speed_mps))
        spread = np.deg2rad(rng.uniform(-sc.heading_spread_deg, sc.heading_spread_deg))
        if sc.approach:  # radially towards the camera and back, at a bearing near the image's edge
            bearing = np.deg2rad(sc.lateral_offset_deg) * rng.choice([-1.0, 1.0])
            radial = np.array([np.cos(bearing + spread), np.sin(bearing + spread)])
            centre = 0.5 * (lo + hi) * np.array([np.cos(bearing), np.sin(bearing)])
            direction, half_length = -radial, 0.5 * (hi - lo)
            start = 2.0 * half_length  # at the near end, turning back out
        else:  # across the view; everyone passes the image centre mid-sequence (mutual occlusion)
            sign = 1.0 if pid % 2 == 0 else -1.0
            direction = sign * np.array([-np.sin(spread), np.cos(spread)])
            centre = np.array([depths[pid], 0.0])
            half_length = sc.path_half_length_m or depths[pid] * np.tan(half_fov) + 1.0  # 0: out of view
            start = (half_length - speed * duration / 2.0) % (4 * half_length)
            if n == 1:
                start = float(rng.uniform(0.0, 4 * half_length))
        walkers.append(
            _Walker(
                pid,
                preset,
                shape,
                centre,
                direction,
                half_length,
                speed,
                start,
                stride=1.0,
                phase0=float(rng.random()),
                pause=float(rng.uniform(*sc.pause_s)) if sc.pause_s[1] > 0 else 0.0,
                turn=sc.turn_s,
            )
        )  # stride: set from the stature
    return walkers


def simulate_sequence(
    seed: int, cfg: SimConfig, scenario: str, n_frames: int, rate_hz: float = 10.0, sensor: str = "vlp16"
) -> Iterator[SimFrame]:
    """Frames of people walking along straight paths (walking gait), at `rate_hz`, stamps from 0 s.

    Scenarios (`cfg.sequence.scenarios`): "walk" one person crossing at 3 to 8 m; "crossing" 2 to 3
    people crossing at different depths, occluding each other mid-sequence; "close" one person walking
    towards the robot and back at 1.5 to 3 m near the image's edge, partly out of the frame; "far" one
    or two people crossing at 10 to 15 m; "people" 2 to 3 people at 2 to 8 m walking, stopping, turning
    round and crossing each other (the tracking sequences). The static scene stays fixed; each frame has
    fresh sensor, detector and HMR noise.
    """
    if scenario not in cfg.sequence.scenarios:
        raise ValueError(f"unknown scenario {scenario!r}; known: {', '.join(cfg.sequence.scenarios)}")
    sc = cfg.sequence.scenarios[scenario]
    rng = np.random.default_rng(seed)
    model = _load_model(cfg)
    mount = make_mount(cfg.mount)
    walkers = _walkers(rng, cfg, model, sc, n_frames, rate_hz)
    # stride from each body's stature (standing pose, one forward pass)
    standing = [
        PersonPlacement(
            w.person_id,
            w.preset,
            w.shape,
            sample_pose(model, "standing", np.random.default_rng(0), variation_scale=0.0),
            np.zeros(2),
            0.0,
        )
        for w in walkers
    ]
    for w, person in zip(walkers, pose_people(model, standing, mount)):
        w.stride = cfg.sequence.stride_length_per_height * float(vertices_world(person, mount)[:, 2].max())
    # keep the static objects off every path
    keep_out = []
    for w in walkers:
        for s in np.arange(-w.half_length, w.half_length + 0.5, 0.5):
            keep_out.append((w.centre + s * w.direction, 0.6))
    objects = static_objects(rng, cfg, model, mount, [], walls=True, keep_out=keep_out)
    for k in range(n_frames):
        t = k / rate_hz
        placements = []
        for w in walkers:
            position, heading, phase, walking = w.at(t)
            pose_rng = np.random.default_rng([seed, w.person_id])  # same joint offsets every frame
            pose = sample_pose(model, "walking" if walking else "standing", pose_rng,
                               phase=phase if walking else None, variation_scale=cfg.people.pose_variation_scale)
            placements.append(PersonPlacement(w.person_id, w.preset, w.shape, pose, position, heading))
        people = pose_people(model, placements, mount)
        scene = assemble(np.random.default_rng([seed, 1]), model, mount, people, objects, cfg.render)
        yield observe(np.random.default_rng([seed, 2, k]), model, cfg, scene, sensor, stamp_ns=round(k * 1e9 / rate_hz))
