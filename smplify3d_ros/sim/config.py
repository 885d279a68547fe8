"""Simulator parameters (values in params/base/sim.yaml).

Frames used by the simulator: "world" is a REP-103 base frame on the ground under the camera (x forward,
y left, z up); the camera optical frame and the LiDAR frame are placed in it by `MountConfig`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Literal

from smplify3d_ros.settings import from_dict, require, section
from smplify3d_ros.sim.people import SHAPE_PRESETS


def _check_range(pair: tuple[float, float], name: str, low: float = 0.0) -> None:
    require(low <= pair[0] <= pair[1], f"{name}: expected {low} <= min <= max, got {pair}")


def _check_prob(value: float, name: str) -> None:
    require(0.0 <= value <= 1.0, f"{name}: must be in [0, 1], got {value}")


@dataclass
class MountConfig:
    """Jackal-like sensor mount: a level LiDAR above and behind a (possibly pitched) camera."""

    camera_height_m: float
    camera_pitch_deg: float
    lidar_above_camera_m: float
    lidar_behind_camera_m: float

    def __post_init__(self) -> None:
        require(0.05 <= self.camera_height_m <= 3.0, "camera_height_m: must be in [0.05, 3]")
        require(-45.0 <= self.camera_pitch_deg <= 45.0, "camera_pitch_deg: must be in [-45, 45]")
        require(abs(self.lidar_above_camera_m) <= 2.0, "lidar_above_camera_m: must be within 2 m")
        require(abs(self.lidar_behind_camera_m) <= 2.0, "lidar_behind_camera_m: must be within 2 m")


@dataclass
class CameraSimConfig:
    width: int
    height: int
    hfov_deg: float
    distortion_model: str
    dist_coeffs: list[float]

    def __post_init__(self) -> None:
        require(16 <= self.width <= 8192 and 16 <= self.height <= 8192, "width/height: 16 to 8192 px")
        require(10.0 <= self.hfov_deg <= 150.0, "hfov_deg: must be in [10, 150]")
        require(
            self.distortion_model in ("", "plumb_bob", "rational_polynomial", "equidistant"),
            f"distortion_model: unsupported {self.distortion_model!r}",
        )
        require(all(abs(c) < 10.0 for c in self.dist_coeffs), "dist_coeffs: implausibly large coefficient")


@dataclass
class RenderConfig:
    """Lambert shading of the ray-cast camera image."""

    light_direction: tuple[float, float, float]
    ambient: float
    sky_rgb: tuple[int, int, int]
    ground_rgb: tuple[int, int, int]
    ground_checker_m: float
    ground_checker_contrast: float
    wall_rgb: tuple[int, int, int]
    object_rgb: tuple[int, int, int]
    skin_rgb: tuple[int, int, int]
    clothing_palette: list[tuple[int, int, int]]
    visibility_rays: int

    def __post_init__(self) -> None:
        require(any(abs(c) > 0 for c in self.light_direction), "light_direction: must be non-zero")
        require(100 <= self.visibility_rays <= 1_000_000, "visibility_rays: must be in [100, 1e6]")
        _check_prob(self.ambient, "ambient")
        require(self.ground_checker_m > 0, "ground_checker_m: must be > 0")
        _check_prob(self.ground_checker_contrast, "ground_checker_contrast")
        require(len(self.clothing_palette) >= 2, "clothing_palette: need at least 2 colours")
        for rgb in [
            self.sky_rgb,
            self.ground_rgb,
            self.wall_rgb,
            self.object_rgb,
            self.skin_rgb,
            *self.clothing_palette,
        ]:
            require(all(0 <= c <= 255 for c in rgb), f"colour {rgb}: channels must be in [0, 255]")


@dataclass
class LidarSensorConfig:
    """A spinning LiDAR: channels at uniformly spaced elevations, fired column by column."""

    channels: int
    elevation_min_deg: float
    elevation_max_deg: float
    firing_order_deg: list[float]
    firing_interval_s: float
    column_period_s: float
    rate_hz: float
    clockwise: bool
    scan_start_azimuth_deg: float
    ring_zero_at_top: bool
    min_range_m: float
    max_range_m: float
    range_noise_m: float
    angular_noise_deg: float
    dropout: float

    def __post_init__(self) -> None:
        require(1 <= self.channels <= 512, "channels: must be in [1, 512]")
        require(
            -90.0 <= self.elevation_min_deg <= self.elevation_max_deg <= 90.0,
            "elevation_min_deg/elevation_max_deg: need -90 <= min <= max <= 90",
        )
        if self.firing_order_deg:
            require(len(self.firing_order_deg) == self.channels, "firing_order_deg: one entry per channel")
        require(self.firing_interval_s >= 0.0, "firing_interval_s: must be >= 0")
        require(self.rate_hz > 0.0, "rate_hz: must be > 0")
        require(
            0.0 < self.column_period_s * self.rate_hz <= 0.1,
            "column_period_s: must give at least 10 columns per revolution",
        )
        require(
            self.firing_interval_s * max(self.channels - 1, 0) <= self.column_period_s,
            "firing_interval_s: a column's firings must fit in column_period_s",
        )
        require(0.0 <= self.min_range_m < self.max_range_m, "min_range_m/max_range_m: need 0 <= min < max")
        require(0.0 <= self.range_noise_m <= 1.0, "range_noise_m: must be in [0, 1]")
        require(0.0 <= self.angular_noise_deg <= 5.0, "angular_noise_deg: must be in [0, 5]")
        require(0.0 <= self.dropout < 1.0, "dropout: must be in [0, 1)")


@dataclass
class NonRepetitiveLidarConfig:
    """A solid-state LiDAR with a non-repetitive scan (Livox-like): every frame lights new directions
    of a fixed field of view, so the pattern never settles into rings (`sim.lidar`)."""

    pattern: Literal["rosette", "random"]
    hfov_deg: float
    vfov_deg: float
    points_per_second: float
    rate_hz: float
    lines: int
    rosette_hz: tuple[float, float]
    min_range_m: float
    max_range_m: float
    range_noise_m: float
    angular_noise_deg: float
    dropout: float

    def __post_init__(self) -> None:
        require(1.0 <= self.hfov_deg <= 180.0, "hfov_deg: must be in [1, 180]")
        require(1.0 <= self.vfov_deg <= 120.0, "vfov_deg: must be in [1, 120]")
        require(self.rate_hz > 0.0, "rate_hz: must be > 0")
        require(10.0 <= self.points_per_second / self.rate_hz <= 2_000_000,
                "points_per_second: must give 10 to 2e6 points per frame")
        require(1 <= self.lines <= 128, "lines: must be in [1, 128]")
        require(all(f > 0 for f in self.rosette_hz) and self.rosette_hz[0] != self.rosette_hz[1],
                "rosette_hz: two different positive rates")
        require(0.0 <= self.min_range_m < self.max_range_m, "min_range_m/max_range_m: need 0 <= min < max")
        require(0.0 <= self.range_noise_m <= 1.0, "range_noise_m: must be in [0, 1]")
        require(0.0 <= self.angular_noise_deg <= 5.0, "angular_noise_deg: must be in [0, 5]")
        require(0.0 <= self.dropout < 1.0, "dropout: must be in [0, 1)")


SensorConfig = LidarSensorConfig | NonRepetitiveLidarConfig


@dataclass
class IntensityConfig:
    """LiDAR return intensity: reflectivity per surface class, attenuated by the incidence angle."""

    person: float
    ground: float
    static: float
    incidence_weight: float

    def __post_init__(self) -> None:
        for name in ("person", "ground", "static"):
            require(0.0 <= getattr(self, name) <= 255.0, f"{name}: must be in [0, 255]")
        _check_prob(self.incidence_weight, "incidence_weight")


@dataclass
class LidarConfig:
    sensors: dict[str, LidarSensorConfig]  # spinning (ring) scanners
    non_repetitive: dict[str, NonRepetitiveLidarConfig]  # solid-state scanners without rings
    intensity: IntensityConfig

    def __post_init__(self) -> None:
        require(len(self.sensors) + len(self.non_repetitive) > 0, "sensors: at least one sensor")
        both = sorted(set(self.sensors) & set(self.non_repetitive))
        require(not both, f"non_repetitive: {both} already named in sensors")

    @property
    def names(self) -> list[str]:
        """Every sensor's name, spinning first."""
        return [*self.sensors, *self.non_repetitive]

    def sensor(self, name: str) -> SensorConfig:
        """The sensor of that name, whatever its kind."""
        if name in self.sensors:
            return self.sensors[name]
        if name in self.non_repetitive:
            return self.non_repetitive[name]
        raise ValueError(f"unknown LiDAR sensor {name!r}; known: {', '.join(self.names)}")


@dataclass
class SceneConfig:
    """Random static scene and placement of people around the robot."""

    n_people: tuple[int, int]
    distance_range_m: tuple[float, float]
    fov_margin_deg: float
    person_gap_m: float
    occlusion_pair_prob: float
    occlusion_bearing_deg: float
    occlusion_gap_m: tuple[float, float]
    back_facing_prob: float
    back_facing_spread_deg: float
    family_weights: dict[str, float]
    ground_half_size_m: float
    wall_height_m: float
    wall_margin_m: tuple[float, float]
    room_half_width_m: tuple[float, float]
    room_back_m: float
    n_boxes: tuple[int, int]
    box_size_m: tuple[float, float]
    box_height_m: tuple[float, float]
    n_pillars: tuple[int, int]
    pillar_radius_m: tuple[float, float]
    pillar_height_m: float
    object_distance_m: tuple[float, float]
    object_clearance_m: float
    seat_size_m: tuple[float, float]
    carried_box_m: tuple[float, float, float]
    step_size_m: tuple[float, float]
    post_radius_m: float
    placement_tries: int

    def __post_init__(self) -> None:
        require(0 <= self.n_people[0] <= self.n_people[1] <= 20, "n_people: need 0 <= min <= max <= 20")
        _check_range(self.distance_range_m, "distance_range_m", 0.5)
        require(0.0 <= self.fov_margin_deg < 60.0, "fov_margin_deg: must be in [0, 60)")
        require(self.person_gap_m >= 0.0, "person_gap_m: must be >= 0")
        _check_prob(self.occlusion_pair_prob, "occlusion_pair_prob")
        require(0.0 <= self.occlusion_bearing_deg <= 20.0, "occlusion_bearing_deg: must be in [0, 20]")
        _check_range(self.occlusion_gap_m, "occlusion_gap_m", 0.0)
        _check_prob(self.back_facing_prob, "back_facing_prob")
        require(0.0 <= self.back_facing_spread_deg <= 90.0, "back_facing_spread_deg: must be in [0, 90]")
        require(len(self.family_weights) > 0, "family_weights: at least one family")
        require(all(w >= 0 for w in self.family_weights.values()), "family_weights: must be >= 0")
        require(sum(self.family_weights.values()) > 0, "family_weights: must not all be 0")
        require(self.ground_half_size_m >= 10.0, "ground_half_size_m: must be >= 10")
        require(self.wall_height_m > 0, "wall_height_m: must be > 0")
        _check_range(self.wall_margin_m, "wall_margin_m", 0.5)
        _check_range(self.room_half_width_m, "room_half_width_m", 1.0)
        require(self.room_back_m > 0.5, "room_back_m: must be > 0.5")
        require(0 <= self.n_boxes[0] <= self.n_boxes[1] <= 50, "n_boxes: need 0 <= min <= max <= 50")
        _check_range(self.box_size_m, "box_size_m", 0.05)
        _check_range(self.box_height_m, "box_height_m", 0.05)
        require(0 <= self.n_pillars[0] <= self.n_pillars[1] <= 50, "n_pillars: need 0 <= min <= max <= 50")
        _check_range(self.pillar_radius_m, "pillar_radius_m", 0.02)
        require(self.pillar_height_m > 0, "pillar_height_m: must be > 0")
        _check_range(self.object_distance_m, "object_distance_m", 0.5)
        require(self.object_clearance_m >= 0, "object_clearance_m: must be >= 0")
        _check_range(self.seat_size_m, "seat_size_m", 0.1)
        require(all(s > 0 for s in self.carried_box_m), "carried_box_m: sizes must be > 0")
        require(all(s >= 0.1 for s in self.step_size_m), "step_size_m: sizes must be >= 0.1")
        require(0.02 <= self.post_radius_m <= 1.0, "post_radius_m: must be in [0.02, 1]")
        require(self.placement_tries >= 1, "placement_tries: must be >= 1")


@dataclass
class PeopleConfig:
    """Body shapes: presets from `sim.people.SHAPE_PRESETS`, jittered."""

    preset_weights: dict[str, float]
    phenotype_jitter: float
    pose_variation_scale: float
    limit_variation: float

    def __post_init__(self) -> None:
        require(len(self.preset_weights) > 0, "preset_weights: at least one preset")
        unknown = sorted(set(self.preset_weights) - set(SHAPE_PRESETS))
        require(not unknown, f"preset_weights: unknown presets {unknown}; known: {sorted(SHAPE_PRESETS)}")
        require(all(w >= 0 for w in self.preset_weights.values()), "preset_weights: must be >= 0")
        require(sum(self.preset_weights.values()) > 0, "preset_weights: must not all be 0")
        require(0.0 <= self.phenotype_jitter <= 0.5, "phenotype_jitter: must be in [0, 0.5]")
        require(0.0 <= self.pose_variation_scale <= 3.0, "pose_variation_scale: must be in [0, 3]")
        _check_prob(self.limit_variation, "limit_variation")


@dataclass
class DetectorConfig:
    """2D keypoint detector model (ViTPose-like top-down detector on the rendered image)."""

    sigma_rel_base: float
    sigma_rel_per_m: float
    sigma_px_floor: float
    occluded_sigma_scale: float
    score_visible: tuple[float, float]
    score_self_occluded: tuple[float, float]
    score_occluded: tuple[float, float]
    score_drop_per_m: float
    self_occlusion_depth_m: float
    occlusion_patch_px: int
    swap_prob: float
    missing_prob: float
    min_visible_pixels: int

    def __post_init__(self) -> None:
        require(0.0 <= self.sigma_rel_base <= 0.5, "sigma_rel_base: must be in [0, 0.5]")
        require(0.0 <= self.sigma_rel_per_m <= 0.1, "sigma_rel_per_m: must be in [0, 0.1]")
        require(0.0 <= self.sigma_px_floor <= 50.0, "sigma_px_floor: must be in [0, 50]")
        require(self.occluded_sigma_scale >= 1.0, "occluded_sigma_scale: must be >= 1")
        for name in ("score_visible", "score_self_occluded", "score_occluded"):
            mean, std = getattr(self, name)
            require(0.0 <= mean <= 1.0 and 0.0 <= std <= 0.5, f"{name}: [mean in [0,1], std in [0,0.5]]")
        require(0.0 <= self.score_drop_per_m <= 0.1, "score_drop_per_m: must be in [0, 0.1]")
        require(self.self_occlusion_depth_m > 0, "self_occlusion_depth_m: must be > 0")
        require(0 <= self.occlusion_patch_px <= 10, "occlusion_patch_px: must be in [0, 10]")
        _check_prob(self.swap_prob, "swap_prob")
        _check_prob(self.missing_prob, "missing_prob")
        require(self.min_visible_pixels >= 0, "min_visible_pixels: must be >= 0")


@dataclass
class HmrConfig:
    """Simulated image-HMR (CLIFF-like) initial estimate; see `sim.hmr` for the model."""

    shape_shrink: float
    shape_noise: float
    pose_depth_sigma_deg: float
    pose_sigma_deg: float
    root_yaw_sigma_deg: float
    root_tilt_sigma_deg: float
    depth_log_sigma: float
    depth_log_bias: float
    lateral_sigma_rel: float
    calibration_distance_m: tuple[float, float]

    def __post_init__(self) -> None:
        _check_prob(self.shape_shrink, "shape_shrink")
        require(0.0 <= self.shape_noise <= 0.5, "shape_noise: must be in [0, 0.5]")
        for name in ("pose_depth_sigma_deg", "pose_sigma_deg", "root_yaw_sigma_deg", "root_tilt_sigma_deg"):
            require(0.0 <= getattr(self, name) <= 90.0, f"{name}: must be in [0, 90]")
        require(0.0 <= self.depth_log_sigma <= 1.0, "depth_log_sigma: must be in [0, 1]")
        require(abs(self.depth_log_bias) <= 1.0, "depth_log_bias: must be in [-1, 1]")
        require(0.0 <= self.lateral_sigma_rel <= 0.5, "lateral_sigma_rel: must be in [0, 0.5]")
        _check_range(self.calibration_distance_m, "calibration_distance_m", 0.5)


@dataclass
class ScenarioConfig:
    """One moving-people scenario of `simulate_sequence`."""

    n_people: tuple[int, int]
    distance_m: tuple[float, float]
    heading_spread_deg: float
    approach: bool
    lateral_offset_deg: float
    pause_s: tuple[float, float]
    turn_s: float
    path_half_length_m: float

    def __post_init__(self) -> None:
        require(1 <= self.n_people[0] <= self.n_people[1] <= 10, "n_people: need 1 <= min <= max <= 10")
        _check_range(self.pause_s, "pause_s")
        require(self.path_half_length_m >= 0.0, "path_half_length_m: must be >= 0 (0: beyond the image edges)")
        require(0.0 <= self.turn_s <= max(self.pause_s[0], 0.0) or self.turn_s == 0.0,
                "turn_s: must be in [0, the shortest pause]")
        _check_range(self.distance_m, "distance_m", 0.5)
        require(0.0 <= self.heading_spread_deg <= 90.0, "heading_spread_deg: must be in [0, 90]")
        require(0.0 <= self.lateral_offset_deg <= 60.0, "lateral_offset_deg: must be in [0, 60]")


@dataclass
class SequenceConfig:
    walk_speed_mps: tuple[float, float]
    stride_length_per_height: float
    depth_gap_m: float
    scenarios: dict[str, ScenarioConfig]

    def __post_init__(self) -> None:
        _check_range(self.walk_speed_mps, "walk_speed_mps", 0.1)
        require(0.3 <= self.stride_length_per_height <= 2.0, "stride_length_per_height: must be in [0.3, 2]")
        require(self.depth_gap_m >= 0.3, "depth_gap_m: must be >= 0.3")


@dataclass
class BenchScenarioConfig:
    """One kind of scene of `smplify3d bench`: the sensors and what varies, on top of `sim.scene` and
    `sim.people` (a None keeps their value)."""

    sensor: str  # a `sim.lidar` sensor name
    camera: CameraSimConfig | None  # None: `sim.camera`
    n_people: tuple[int, int]
    distance_m: tuple[float, float]
    walls: bool
    family_weights: dict[str, float] | None
    pose_variation_scale: float | None
    limit_variation: float | None
    back_facing_prob: float | None
    occlusion_pair_prob: float | None
    fov_margin_deg: float | None
    missed_chamfer_m: float  # a fit with LiDAR points whose chamfer exceeds this missed them (sensor-dependent)

    def __post_init__(self) -> None:
        require(0.0 < self.missed_chamfer_m <= 2.0, "missed_chamfer_m: must be in (0, 2]")
        require(1 <= self.n_people[0] <= self.n_people[1] <= 20, "n_people: need 1 <= min <= max <= 20")
        _check_range(self.distance_m, "distance_m", 0.5)
        if self.family_weights is not None:
            require(len(self.family_weights) > 0 and sum(self.family_weights.values()) > 0
                    and all(w >= 0 for w in self.family_weights.values()),
                    "family_weights: non-negative, not all 0")
        for name in ("limit_variation", "back_facing_prob", "occlusion_pair_prob"):
            value = getattr(self, name)
            if value is not None:
                _check_prob(value, name)


@dataclass
class BenchConfig:
    """What `smplify3d bench` and `smplify3d tune` share: the seed split, the report's bands, scenarios."""

    tuning_seeds: tuple[int, int]  # first and last seed (inclusive) that tuning may look at
    report_seed_start: int  # reported scenes start here, past every tuning seed
    distance_bands_m: list[float]  # band edges, increasing
    heading_bands_deg: tuple[float, float]  # facing below the first, side-on below the second, back from it
    off_mpjpe_mm: float  # a fit this far off the truth is wrong, when the report checks the chamfer's verdict
    scenarios: dict[str, BenchScenarioConfig]

    def __post_init__(self) -> None:
        first, last = self.tuning_seeds
        require(0 <= first <= last, "tuning_seeds: need 0 <= first <= last")
        require(self.report_seed_start > last, "report_seed_start: must lie past the last tuning seed")
        edges = self.distance_bands_m
        require(len(edges) >= 2 and all(a < b for a, b in zip(edges, edges[1:])),
                "distance_bands_m: at least two increasing edges")
        require(0.0 < self.heading_bands_deg[0] < self.heading_bands_deg[1] < 180.0,
                "heading_bands_deg: need 0 < facing < back < 180")
        require(self.off_mpjpe_mm > 0, "off_mpjpe_mm: must be > 0")
        require(len(self.scenarios) > 0, "scenarios: at least one")

    def is_tuning_seed(self, seed: int) -> bool:
        return self.tuning_seeds[0] <= seed <= self.tuning_seeds[1]


@dataclass
class SimConfig:
    """The simulator section of the configuration."""

    body_model: str
    mount: MountConfig
    camera: CameraSimConfig
    render: RenderConfig
    lidar: LidarConfig
    scene: SceneConfig
    people: PeopleConfig
    detector: DetectorConfig
    hmr: HmrConfig
    sequence: SequenceConfig
    bench: BenchConfig

    def __post_init__(self) -> None:
        require(bool(self.body_model), "body_model: must be a model name")
        for name, scenario in self.bench.scenarios.items():
            require(scenario.sensor in self.lidar.names,
                    f"bench.scenarios.{name}.sensor: unknown {scenario.sensor!r}; known: {self.lidar.names}")


def scenario_sim_config(cfg: SimConfig, name: str) -> SimConfig:
    """`cfg` with a bench scenario's camera, scene and people values in place (its None values keep cfg's)."""
    if name not in cfg.bench.scenarios:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(cfg.bench.scenarios)}")
    sc = cfg.bench.scenarios[name]

    def given(**values: object) -> dict[str, object]:
        return {k: v for k, v in values.items() if v is not None}

    scene = dataclasses.replace(cfg.scene, n_people=sc.n_people, distance_range_m=sc.distance_m, **given(
        family_weights=sc.family_weights, back_facing_prob=sc.back_facing_prob,
        occlusion_pair_prob=sc.occlusion_pair_prob, fov_margin_deg=sc.fov_margin_deg))
    people = dataclasses.replace(cfg.people, **given(
        pose_variation_scale=sc.pose_variation_scale, limit_variation=sc.limit_variation))
    return dataclasses.replace(cfg, camera=sc.camera or cfg.camera, scene=scene, people=people)


def default_sim_config() -> SimConfig:
    """The simulator section from params/base/sim.yaml alone (tests, tools)."""
    from smplify3d_ros.settings import base_values

    return from_dict(SimConfig, base_values()["sim"], "sim")


def load_sim_config(profile=None, overrides=None) -> SimConfig:
    """The `sim` section of a profile (see `smplify3d_ros.settings.load_sections`)."""
    return section(SimConfig, "sim", profile, overrides)
