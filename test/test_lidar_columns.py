"""A column (post) standing among a person's points: `lidar.columns.column_mask` and the extraction.

The hand-built scenes cast a VLP-16-like scan (16 rings, -15..15 deg in 2 deg steps, 0.2 deg azimuth
steps, 0.55 m above the floor) at vertical cylinders in the ground plane: a post, and a body of two leg
columns up to the hip under a wider torso column up to the shoulders.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from smplify3d_ros.lidar.columns import column_mask
from smplify3d_ros.lidar.config import ExtractionConfig
from smplify3d_ros.settings import base_values, from_dict

CONFIG = from_dict(ExtractionConfig, dict(base_values()["lidar"]), "lidar")
SENSOR_HEIGHT = 0.55


def scan(cylinders: list[tuple[float, float, float, float, float]], noise_m: float = 0.01,
         seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cast the scan at vertical cylinders (x, y, radius, bottom, top; the sensor at the origin, y ahead):
    (N, 2) ground-plane hits, (N,) heights, (N,) index of the cylinder hit."""
    rng = np.random.default_rng(seed)
    xy, height, label = [], [], []
    for elevation in np.radians(np.arange(-15.0, 15.1, 2.0)):
        for azimuth in np.radians(np.arange(-20.0, 20.0, 0.2)):
            ray = np.array([np.sin(azimuth), np.cos(azimuth)])
            best = (np.inf, -1)
            for k, (cx, cy, r, bottom, top) in enumerate(cylinders):
                along = ray @ np.array([cx, cy])
                miss = along**2 - (cx * cx + cy * cy - r * r)
                if miss < 0:
                    continue
                t = along - np.sqrt(miss)
                z = SENSOR_HEIGHT + t * np.tan(elevation)
                if 0 < t < best[0] and bottom <= z <= top:
                    best = (t, k)
            if best[1] >= 0:
                t = best[0] + rng.normal(0.0, noise_m)
                xy.append(t * ray)
                height.append(SENSOR_HEIGHT + best[0] * np.tan(elevation))
                label.append(best[1])
    return np.array(xy), np.array(height), np.array(label)


def body(x: float, y: float) -> list[tuple[float, float, float, float, float]]:
    """A standing body's columns: two legs (floor to hip), a torso (hip to shoulder)."""
    return [(x - 0.1, y, 0.07, 0.0, 0.85), (x + 0.1, y, 0.07, 0.0, 0.85), (x, y, 0.16, 0.85, 1.45)]


def test_a_post_among_a_persons_points_is_found_and_nothing_of_the_body():
    """A post (radius 0.12 m) 3.2 m out beside and in front of a body 3.5 m out, as a person leaning on it
    is seen from behind: every point of the post is the column's, no point of the body."""
    xy, height, label = scan([(-0.25, 3.2, 0.12, 0.0, 2.5), *body(0.1, 3.5)])
    post = label == 0
    assert post.sum() > 100 and (~post).sum() > 100
    found = column_mask(xy, height, CONFIG)
    assert found[post].mean() > 0.97 and not found[~post].any()


def test_a_body_alone_has_no_column():
    """Legs are columns too, but thinner than `column_min_radius_m` and they stop at the hip, under the
    torso; the torso starts above `column_max_foot_m`. Near (2.2 m) and farther (5 m) alike."""
    for depth in (2.2, 5.0):
        xy, height, _ = scan(body(0.0, depth), seed=1)
        assert len(xy) > 50
        assert not column_mask(xy, height, CONFIG).any()


def test_a_post_that_does_not_reach_the_floor_or_the_top_is_no_column():
    """A column standing on the floor and rising to the person's highest points: a cylinder that starts
    at the hip (a torso), or one the scan sees only up to half the person's height, is not one."""
    for cylinder in ((-0.25, 3.2, 0.12, 0.8, 2.5), (-0.25, 3.2, 0.12, 0.0, 0.7)):
        xy, height, _ = scan([cylinder, *body(0.1, 3.5)], seed=2)
        assert not column_mask(xy, height, CONFIG).any()


def test_columns_off():
    xy, height, _ = scan([(-0.25, 3.2, 0.12, 0.0, 2.5), *body(0.1, 3.5)])
    assert not column_mask(xy, height, dataclasses.replace(CONFIG, column_max_radius_m=0.0)).any()
    assert not column_mask(np.zeros((0, 2)), np.zeros(0), CONFIG).any()


def test_the_post_a_person_leans_on_seen_from_near_is_taken_from_their_points():
    """A simulated robot-path scene (tuning seed 153 at 2-8 m): a woman leaning on a post 3.4 m out, the
    post beside her. The VLP-16's top ring passes below the top of her box, so nothing of the post rises
    above it (`without_posts` does not fire), and 155 of her 252 points were the post's. The column test
    takes them: what she keeps is hers."""
    from smplify3d_ros.frame_fitter import extract_frame_people
    from smplify3d_ros.sim.config import load_sim_config
    from smplify3d_ros.sim.world import simulate_scenario

    n_people = int(np.random.default_rng([153, 7]).integers(1, 4))  # the bench's draw for this scene
    sim = simulate_scenario(153, load_sim_config(), "robot", sensor="vlp16", n_people=n_people,
                            distance_range=(2.0, 8.0))
    k = list(sim.frame.person_ids).index(0)
    own = np.flatnonzero(sim.point_labels == 0)
    off = extract_frame_people(sim.frame, dataclasses.replace(CONFIG, column_max_radius_m=0.0))[1].people[k].indices
    on = extract_frame_people(sim.frame, CONFIG)[1].people[k].indices
    assert np.isin(off, own).mean() < 0.5
    assert np.isin(on, own).mean() > 0.9 and np.isin(own, on).mean() > 0.9


def test_degenerate_points_give_no_column():
    """Points on one vertical line, on one ring, or all at one spot: no circle, no error."""
    line = np.column_stack([np.zeros(60), np.linspace(3.0, 3.5, 60)]), np.linspace(0.0, 1.5, 60)
    ring = np.column_stack([np.linspace(-0.3, 0.3, 60), np.full(60, 3.0)]), np.full(60, 0.8)
    spot = np.tile([[0.1, 3.0]], (60, 1)), np.linspace(0.0, 1.5, 60)
    for xy, height in (line, ring, spot):
        assert not column_mask(xy, height, CONFIG).any()
