"""BodyFit[] -> MarkerArray: content, deletes, decimation, malformed input, speed."""

from __future__ import annotations

import time

import numpy as np
import pytest

from msg_adapters.factory import RclpyFactory, RosbagsFactory, rclpy_available, to_plain
from msg_adapters.markers import (
    LINE_LIST,
    TEXT_VIEW_FACING,
    TRIANGLE_LIST,
    compressible_order,
    decimate_faces,
    fits_to_markers,
    person_color,
)
from smplify3d_ros.keypoints import COCO17_SKELETON, KP
from smplify3d_ros.types import BodyFit, BodyParams, FitQuality

needs_rclpy = pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")
FACTORIES = [pytest.param(RosbagsFactory(), id="rosbags"),
             pytest.param(RclpyFactory(), id="rclpy", marks=needs_rclpy)]


def grid_mesh(nu: int, nv: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed-ish cylinder: nu x nv vertices, 2 (nu - 1)(nv - 1) triangles."""
    a, h = np.meshgrid(np.linspace(0, 2 * np.pi, nu), np.linspace(-0.9, 0.9, nv), indexing="ij")
    verts = np.stack([0.2 * np.cos(a), h, 4.0 + 0.2 * np.sin(a)], -1).reshape(-1, 3).astype(np.float32)
    i, j = np.meshgrid(np.arange(nu - 1), np.arange(nv - 1), indexing="ij")
    v00 = (i * nv + j).ravel()
    faces = np.concatenate([np.stack([v00, v00 + nv, v00 + 1], 1),
                            np.stack([v00 + 1, v00 + nv, v00 + nv + 1], 1)])
    return verts, faces.astype(np.int64)


def make_fit(pid: int, verts: np.ndarray, shift: float = 0.0) -> BodyFit:
    rng = np.random.default_rng(pid + 10)
    kp3d = (rng.normal(scale=0.3, size=(17, 3)) + [shift, 0.0, 4.0]).astype(np.float32)
    names = ["pelvis", "left_hip", "right_hip"]
    params = BodyParams("anny", np.full(4, 0.5), rng.normal(scale=0.1, size=(3, 3)),
                        np.array([0.0, 3.1, 0.0]), np.array([shift, 0.1, 4.0]))
    quality = FitQuality(3.0, 0.02, 500, ["torso"], True, 1.0)
    return BodyFit(pid, params, names, verts + np.float32(shift), kp3d, np.zeros((3, 3), np.float32), quality)


VERTS, FACES = grid_mesh(12, 10)


def by_ns(array) -> dict[tuple[str, int], object]:
    return {(m.ns, m.id): m for m in array.markers}


@pytest.mark.parametrize("factory", FACTORIES)
def test_markers_per_person_and_deletes(factory):
    fits = [make_fit(3, VERTS), make_fit(12, VERTS, shift=1.0)]
    array, ids = fits_to_markers(fits, FACES, 8.5, "cam", previous_ids={3, 4, 9}, factory=factory)
    assert ids == {3, 12}
    m = by_ns(array)
    adds = {k for k, v in m.items() if v.action == 0}
    assert adds == {("mesh", 3), ("skeleton", 3), ("label", 3), ("mesh", 12), ("skeleton", 12), ("label", 12)}
    deletes = sorted(k for k, v in m.items() if v.action == 2)
    assert deletes == sorted([(ns, i) for ns in ("mesh", "skeleton", "label") for i in (4, 9)])
    assert len(array.markers) == 12
    mesh = m["mesh", 12]
    assert mesh.type == TRIANGLE_LIST and mesh.header.frame_id == "cam" and mesh.header.stamp.sec == 8
    assert len(mesh.points) == 3 * len(FACES)
    got = np.array([[p.x, p.y, p.z] for p in mesh.points])
    np.testing.assert_allclose(got, fits[1].vertices[compressible_order(FACES).reshape(-1)], atol=1e-6)
    assert (mesh.pose.position.x, mesh.pose.position.y, mesh.pose.position.z) == (0.0, 0.0, 0.0)  # no grid
    assert (mesh.color.r, mesh.color.g, mesh.color.b) == pytest.approx(person_color(12))
    assert mesh.pose.orientation.w == 1.0 and mesh.scale.x == 1.0
    skel = m["skeleton", 3]
    assert skel.type == LINE_LIST and len(skel.points) == 2 * len(COCO17_SKELETON) and skel.scale.x > 0
    a, b = COCO17_SKELETON[0]
    np.testing.assert_allclose([skel.points[0].x, skel.points[1].z], [fits[0].keypoints3d[a, 0],
                                                                      fits[0].keypoints3d[b, 2]], atol=1e-6)
    label = m["label", 3]
    assert label.type == TEXT_VIEW_FACING and label.text == "id 3" and label.scale.z > 0
    np.testing.assert_allclose([label.pose.position.x, label.pose.position.y],
                               fits[0].keypoints3d[KP["nose"], :2] + [0.0, -0.3], atol=1e-6)


def test_colours_fixed_per_id_and_distinct():
    assert person_color(3) == person_color(3) == person_color(13)
    assert len({person_color(i) for i in range(10)}) == 10
    assert person_color(-1) == person_color(9)


def test_nobody_now_deletes_everyone_and_nothing_else():
    array, ids = fits_to_markers([], FACES, 1.0, "cam", previous_ids=[5], factory=RosbagsFactory())
    assert ids == set() and sorted((m.ns, m.id, m.action) for m in array.markers) == [
        ("label", 5, 2), ("mesh", 5, 2), ("skeleton", 5, 2)]
    array, _ = fits_to_markers([], FACES, 1.0, "cam", factory=RosbagsFactory())
    assert array.markers == []


def test_no_faces_no_mesh():
    array, _ = fits_to_markers([make_fit(1, VERTS)], None, 1.0, "cam", factory=RosbagsFactory())
    assert sorted(m.ns for m in array.markers) == ["label", "skeleton"]


@pytest.mark.parametrize("factory", FACTORIES)
def test_max_triangles_decimates(factory):
    fit = make_fit(2, VERTS)
    array, _ = fits_to_markers([fit], FACES, 1.0, "cam", factory=factory, max_triangles=50)
    mesh = by_ns(array)["mesh", 2]
    kept = compressible_order(decimate_faces(FACES, 50))
    assert len(kept) <= 50 and len(mesh.points) == 3 * len(kept)
    got = np.array([[p.x, p.y, p.z] for p in mesh.points])
    np.testing.assert_allclose(got, fit.vertices[kept.reshape(-1)], atol=1e-6)
    assert decimate_faces(FACES, None) is FACES and decimate_faces(FACES, 10**6) is FACES


def test_non_finite_vertices_drop_their_triangles_and_bones():
    fit = make_fit(1, VERTS)
    fit.vertices = fit.vertices.copy()
    fit.vertices[0] = np.nan
    fit.keypoints3d[KP["left_ankle"]] = np.nan
    array, _ = fits_to_markers([fit], FACES, 1.0, "cam", factory=RosbagsFactory())
    m = by_ns(array)
    n_bad = int((FACES == 0).any(axis=1).sum())
    assert n_bad > 0 and len(m["mesh", 1].points) == 3 * (len(FACES) - n_bad)
    assert all(np.isfinite([p.x, p.y, p.z]).all() for p in m["mesh", 1].points)
    assert len(m["skeleton", 1].points) == 2 * (len(COCO17_SKELETON) - 1)


@pytest.mark.parametrize("faces,fits,match", [
    (np.zeros((4, 2), np.int64), [make_fit(1, VERTS)], r"faces must be an \(F, 3\) integer array"),
    (np.zeros((4, 3), np.float32) + 0.5, [make_fit(1, VERTS)], "integer array"),
    (np.full((1, 3), -1), [make_fit(1, VERTS)], "negative vertex"),
    (np.array([[0, 1, len(VERTS)]]), [make_fit(1, VERTS)], f"faces index vertex {len(VERTS)}"),
    (FACES, [make_fit(1, VERTS), make_fit(1, VERTS)], "two fits carry person id 1"),
    (FACES, [make_fit(2**31, VERTS)], "does not fit a Marker id"),
])
def test_malformed_input(faces, fits, match):
    with pytest.raises(ValueError, match=match):
        fits_to_markers(fits, faces, 1.0, "cam", factory=RosbagsFactory())


@needs_rclpy
def test_rclpy_markers_serialize_and_match_rosbags():
    from rclpy.serialization import serialize_message
    from rosbags.typesys import Stores, get_typestore

    fits = [make_fit(4, VERTS)]
    a, _ = fits_to_markers(fits, FACES, 2.0, "cam", {7}, RclpyFactory())
    b, _ = fits_to_markers(fits, FACES, 2.0, "cam", {7}, RosbagsFactory())
    assert to_plain(a) == to_plain(b)
    ts = get_typestore(Stores.ROS2_JAZZY)
    typename = "visualization_msgs/msg/MarkerArray"
    wire_a = ts.deserialize_cdr(bytes(serialize_message(a)), typename)
    wire_b = ts.deserialize_cdr(ts.serialize_cdr(b, typename), typename)  # colours are float32 on the wire
    assert to_plain(wire_a) == to_plain(wire_b)


@pytest.mark.parametrize("factory", FACTORIES)
def test_27k_triangle_mesh_in_one_message(factory):
    """The whole mesh as one triangle list (its time printed: speed is measured, never asserted)."""
    verts, faces = grid_mesh(120, 115)
    assert len(faces) > 27_000
    fit = make_fit(1, verts)
    fits_to_markers([fit], faces, 1.0, "cam", factory=factory)  # warm-up (imports, caches)
    best = 1e9
    for _ in range(3):
        t0 = time.perf_counter()
        array, _ = fits_to_markers([fit], faces, 1.0, "cam", factory=factory)
        best = min(best, time.perf_counter() - t0)
    assert len(by_ns(array)["mesh", 1].points) == 3 * len(faces)
    print(f"{factory.name}: {best * 1e3:.1f} ms for {len(faces)} triangles")


def test_a_grid_rounds_the_mesh_within_half_a_cell_and_shrinks_its_compressed_size(anny_model):
    import zstandard

    from msg_adapters.markers import snap
    from smplify3d_ros.eval.synthetic import default_intrinsics, make_person

    grid = 2.0**-8
    person = make_person(anny_model, np.random.default_rng(3), default_intrinsics(), distance=5.0, yaw=0.4,
                         n_points=10, point_noise=0.0, keypoint_noise_px=0.0)
    verts = anny_model.posed([person.truth])[0].vertices.astype(np.float32)  # a fit's vertices: float32
    faces = anny_model.faces.cpu().numpy()
    store = RosbagsFactory().typestore
    sizes = {}
    for g in (0.0, grid):
        array, _ = fits_to_markers([make_fit(1, verts)], faces, 1.0, "cam", factory=RosbagsFactory(),
                                   max_triangles=6000, grid_m=g)
        mesh = by_ns(array)[("mesh", 1)]
        origin = np.array([mesh.pose.position.x, mesh.pose.position.y, mesh.pose.position.z])
        xyz = np.array([(p.x, p.y, p.z) for p in mesh.points]) + origin  # where RViz draws them
        want = verts.astype(np.float64)[compressible_order(decimate_faces(faces, 6000)).reshape(-1)]
        if g:
            assert np.abs(xyz - want).max() <= g / 2 and np.array_equal(xyz, snap(want - origin, g) + origin)
            assert np.array_equal(xyz / g, np.round(xyz / g)) and np.array_equal(origin / g, np.round(origin / g))
            assert ((xyz - origin >= 4.0) & (xyz - origin < 8.0)).all(), "one binary exponent per coordinate"
        else:
            assert np.array_equal(xyz, want)
        sizes[g] = len(zstandard.compress(bytes(store.serialize_cdr(array, "visualization_msgs/msg/MarkerArray"))))
    print(f"compressed mesh marker: exact {sizes[0.0]} B, on a 1/256 m grid {sizes[grid]} B")
    assert sizes[grid] < 0.5 * sizes[0.0]


def test_the_compressible_order_keeps_every_triangle_and_its_winding():
    rng = np.random.default_rng(0)
    faces = rng.permutation(FACES)
    ordered = compressible_order(faces)

    def canonical(f):  # a triangle up to rotation (which keeps its winding), as a sorted set
        return sorted(tuple(np.roll(t, -int(np.argmin(t)))) for t in f)

    assert canonical(ordered) == canonical(faces) and len(ordered) == len(faces)
    assert (ordered[:, 0] == ordered.min(axis=1)).all()
    assert compressible_order(FACES[:0]).shape == (0, 3)
