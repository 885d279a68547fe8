"""Simulated LiDARs: spinning (VLP-16, Ouster OS1) and non-repetitive solid-state (Livox-like); scan
patterns, ray casting, CARLA-style noise.

Spinning scan pattern: channels at uniformly spaced elevations; one column of firings every `column_period_s`
while the head turns at `rate_hz`, so each return's azimuth follows from its firing time (the VLP-16
fires its 16 lasers one after the other, 2.304 us apart, in the order of `firing_order_deg`).

Non-repetitive pattern (`sim.lidar.non_repetitive`): a fixed field of view in front of the sensor, lit
along a curve that never repeats, so that a frame has no rings and the next frame fills other gaps.
`rosette`: each of `lines` emitters sends its beam through two prisms turning in opposite directions at
`rosette_hz`; the deflection is the mean of two counter-rotating unit phasors, a rosette filling the unit
disc (densest at its centre and rim), stretched to the field of view's ellipse and turned by a different
angle per line. Each frame starts at a random moment of the prisms' turn. `random`: directions uniform in
solid angle over the field of view's rectangle, new every frame. The `ring` field carries the line.

Noise (as CARLA's simulated LiDAR models it): Gaussian range noise along the ray, random drop-out of returns;
plus beam pointing noise: the beam travels along a perturbed direction but the return is reported along
the nominal one, which moves points across the ray by about range x sigma.

Output follows the ROS drivers' PointCloud2 layout: points in the LiDAR frame (x forward, y left,
z up), fields x, y, z, intensity (float32), ring (uint16), time (float32, s since the scan's start),
in firing order. Each point also carries the label of the surface it hit (person id >= 0, -1 ground,
-2 static object); that label is ground truth and never part of a message.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from smplify3d_ros.camera import transform_points
from smplify3d_ros.sim.config import IntensityConfig, LidarSensorConfig, NonRepetitiveLidarConfig, SensorConfig
from smplify3d_ros.sim.raycast import LABEL_GROUND, LABEL_STATIC, RayScene


@dataclass
class ScanPattern:
    """Nominal rays of one full revolution, in firing order."""

    elevation: np.ndarray  # (R,) float64 rad
    azimuth: np.ndarray  # (R,) float64 rad, LiDAR frame, counter-clockwise from x
    ring: np.ndarray  # (R,) uint16 driver ring index
    time: np.ndarray  # (R,) float32 s since the scan's start
    columns: int  # firing columns of one revolution (a non-repetitive scan: one per ray)

    def directions(self) -> np.ndarray:
        return spherical_to_unit(self.elevation, self.azimuth)


@dataclass
class LidarScan:
    """One simulated scan in the LiDAR frame, in the driver's field layout."""

    points: np.ndarray  # (N, 3) float32 x, y, z, m
    intensity: np.ndarray  # (N,) float32, 0..255
    ring: np.ndarray  # (N,) uint16
    time: np.ndarray  # (N,) float32 s since the scan's start
    label: np.ndarray  # (N,) int32 ground truth: person id >= 0, -1 ground, -2 static

    def fields(self) -> dict[str, np.ndarray]:
        """The non-xyz PointCloud2 fields, with the driver's dtypes."""
        return {"intensity": self.intensity, "ring": self.ring, "time": self.time}


def spherical_to_unit(elevation: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    ce = np.cos(elevation)
    return np.stack([ce * np.cos(azimuth), ce * np.sin(azimuth), np.sin(elevation)], axis=-1)


def channel_elevations_deg(sensor: LidarSensorConfig) -> np.ndarray:
    """(C,) elevations from bottom to top."""
    return np.linspace(sensor.elevation_min_deg, sensor.elevation_max_deg, sensor.channels)


def firing_slots(sensor: LidarSensorConfig) -> np.ndarray:
    """(C,) int: position of each channel (bottom to top) within its column's firing sequence."""
    elevations = channel_elevations_deg(sensor)
    if not sensor.firing_order_deg:
        return np.zeros(sensor.channels, dtype=np.int64)
    order = np.asarray(sensor.firing_order_deg, dtype=np.float64)
    channel_of_slot = np.argmin(np.abs(order[:, None] - elevations[None, :]), axis=1)
    spacing = (elevations[-1] - elevations[0]) / max(sensor.channels - 1, 1)
    mismatch = np.abs(order - elevations[channel_of_slot])
    if np.any(mismatch > 0.01 * max(spacing, 1e-9)) or len(set(channel_of_slot)) != sensor.channels:
        raise ValueError("firing_order_deg must be a permutation of the channels' uniform elevations")
    slots = np.empty(sensor.channels, dtype=np.int64)
    slots[channel_of_slot] = np.arange(sensor.channels)
    return slots


def scan_pattern(sensor: SensorConfig, rng: np.random.Generator | None = None) -> ScanPattern:
    """The nominal rays of one revolution (spinning) or frame (non-repetitive, drawn with `rng`), ordered
    by firing time."""
    if isinstance(sensor, NonRepetitiveLidarConfig):
        return non_repetitive_pattern(sensor, rng if rng is not None else np.random.default_rng(0))
    return spinning_pattern(sensor)


def _rosette(sensor: NonRepetitiveLidarConfig, time: np.ndarray, line: np.ndarray,
             rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) in the unit disc: the mean of two counter-rotating phasors, turned per line."""
    start = rng.uniform(0.0, 3600.0)  # s into the prisms' turn: their rates never bring a frame back
    w1, w2 = 2.0 * np.pi * np.asarray(sensor.rosette_hz, dtype=np.float64)
    t = start + time.astype(np.float64)
    turn = np.pi * line / sensor.lines
    z = 0.5 * (np.exp(1j * w1 * t) + np.exp(-1j * w2 * t)) * np.exp(1j * turn)
    return z.real, z.imag


def non_repetitive_pattern(sensor: NonRepetitiveLidarConfig, rng: np.random.Generator) -> ScanPattern:
    """One frame's rays of a solid-state scanner (module docstring), lines firing in turn."""
    n = round(sensor.points_per_second / sensor.rate_hz)
    time = np.arange(n, dtype=np.float64) / sensor.points_per_second
    line = np.arange(n) % sensor.lines
    half_h, half_v = np.deg2rad(sensor.hfov_deg) / 2.0, np.deg2rad(sensor.vfov_deg) / 2.0
    if sensor.pattern == "rosette":
        x, y = _rosette(sensor, time, line, rng)
        azimuth, elevation = half_h * x, half_v * y
    else:  # uniform in solid angle: azimuth uniform, sine of the elevation uniform
        azimuth = rng.uniform(-half_h, half_h, n)
        elevation = np.arcsin(rng.uniform(-np.sin(half_v), np.sin(half_v), n))
    return ScanPattern(
        elevation=elevation,
        azimuth=azimuth,
        ring=line.astype(np.uint16),
        time=time.astype(np.float32),
        columns=n,
    )


def spinning_pattern(sensor: LidarSensorConfig) -> ScanPattern:
    """The nominal rays of one revolution of a spinning LiDAR, ordered by firing time."""
    columns = round(1.0 / (sensor.rate_hz * sensor.column_period_s))
    elevations = np.deg2rad(channel_elevations_deg(sensor))
    slots = firing_slots(sensor)
    order = np.argsort(slots, kind="stable")  # channels in firing order
    col = np.repeat(np.arange(columns), sensor.channels)
    channel = np.tile(order, columns)
    time = col * sensor.column_period_s + slots[channel] * sensor.firing_interval_s
    sign = -1.0 if sensor.clockwise else 1.0
    azimuth = np.deg2rad(sensor.scan_start_azimuth_deg) + sign * 2.0 * np.pi * sensor.rate_hz * time
    azimuth = np.mod(azimuth + np.pi, 2.0 * np.pi) - np.pi
    ring = (sensor.channels - 1 - channel) if sensor.ring_zero_at_top else channel
    return ScanPattern(
        elevation=elevations[channel],
        azimuth=azimuth,
        ring=ring.astype(np.uint16),
        time=time.astype(np.float32),
        columns=columns,
    )


def _intensity(label: np.ndarray, cos_incidence: np.ndarray, cfg: IntensityConfig) -> np.ndarray:
    reflectivity = np.select(
        [label >= 0, label == LABEL_GROUND, label == LABEL_STATIC], [cfg.person, cfg.ground, cfg.static], 0.0
    )
    factor = 1.0 - cfg.incidence_weight + cfg.incidence_weight * np.abs(cos_incidence)
    return np.clip(reflectivity * factor, 0.0, 255.0).astype(np.float32)


def simulate_scan(
    scene: RayScene,
    T_scene_lidar: np.ndarray,
    sensor: SensorConfig,
    intensity: IntensityConfig,
    rng: np.random.Generator,
    pattern: ScanPattern | None = None,
) -> LidarScan:
    """Cast one revolution (one frame) into `scene`; `T_scene_lidar` places the LiDAR in the scene's frame."""
    pattern = scan_pattern(sensor, rng) if pattern is None else pattern
    n = len(pattern.time)
    elevation, azimuth = pattern.elevation, pattern.azimuth
    if sensor.angular_noise_deg > 0:
        sigma = np.deg2rad(sensor.angular_noise_deg)
        elevation = elevation + rng.normal(0.0, sigma, n)
        azimuth = azimuth + rng.normal(0.0, sigma, n)
    beam = spherical_to_unit(elevation, azimuth)
    R, t = T_scene_lidar[:3, :3], T_scene_lidar[:3, 3]
    hits = scene.cast(t, beam @ R.T)
    distance = hits.distance
    measured = distance + (rng.normal(0.0, sensor.range_noise_m, n) if sensor.range_noise_m > 0 else 0.0)
    keep = hits.hit & (distance <= sensor.max_range_m) & (measured >= sensor.min_range_m)
    if sensor.dropout > 0:
        keep &= rng.random(n) >= sensor.dropout
    nominal = pattern.directions()[keep]
    points = nominal * measured[keep, None]
    cos_incidence = np.einsum("ij,ij->i", hits.normal[keep], beam[keep] @ R.T)
    return LidarScan(
        points=points.astype(np.float32),
        intensity=_intensity(hits.label[keep], cos_incidence, intensity),
        ring=pattern.ring[keep],
        time=pattern.time[keep],
        label=hits.label[keep].astype(np.int32),
    )


def points_in_frame(scan: LidarScan, T_frame_lidar: np.ndarray) -> np.ndarray:
    """The scan's points in another frame (e.g. the camera frame), float32."""
    return transform_points(scan.points, T_frame_lidar).astype(np.float32)
