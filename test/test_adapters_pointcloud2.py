"""PointCloud2 reader and writer: driver layouts, both runtimes, malformed clouds, speed."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from msg_adapters.factory import RclpyFactory, RosbagsFactory, rclpy_available, to_plain
from msg_adapters.pointcloud2 import (
    PointCloudError,
    field_names,
    make_pointcloud2,
    read_fields,
    read_points,
)

TS = get_typestore(Stores.ROS2_JAZZY)
needs_rclpy = pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")
FACTORIES = [pytest.param(RosbagsFactory(), id="rosbags"),
             pytest.param(RclpyFactory(), id="rclpy", marks=needs_rclpy)]
CODES = {"i1": 1, "u1": 2, "i2": 3, "u2": 4, "i4": 5, "u4": 6, "f4": 7, "f8": 8}


def layout(spec: list[tuple[str, str, int]], itemsize: int, order: str = "<") -> np.dtype:
    """Structured dtype from (name, 'f4', offset) triples."""
    return np.dtype({"names": [n for n, _, _ in spec], "formats": [order + t for _, t, _ in spec],
                     "offsets": [o for _, _, o in spec], "itemsize": itemsize})


# Ouster OS1 (ouster-ros "original" point): 48 bytes with padding after z and at the end.
OUSTER = [("x", "f4", 0), ("y", "f4", 4), ("z", "f4", 8), ("intensity", "f4", 16), ("t", "u4", 20),
          ("reflectivity", "u2", 24), ("ring", "u2", 26), ("ambient", "u2", 28), ("range", "u4", 32)]
# velodyne_pointcloud (ROS 2): packed XYZIRT, 22 bytes; and the PCL-aligned 32-byte XYZIR variant.
VLP16_PACKED = [("x", "f4", 0), ("y", "f4", 4), ("z", "f4", 8), ("intensity", "f4", 12), ("ring", "u2", 16),
                ("time", "f4", 18)]
VLP16_ALIGNED = [("x", "f4", 0), ("y", "f4", 4), ("z", "f4", 8), ("intensity", "f4", 16),
                 ("ring", "u2", 20)]


def records(dtype: np.dtype, n: int, rng: np.random.Generator) -> np.ndarray:
    """n records with random values; padding bytes hold garbage (0xAB) so the reader must skip them."""
    rec = np.frombuffer(np.full(n * dtype.itemsize, 0xAB, np.uint8).tobytes(), dtype=dtype).copy()
    for name in dtype.names:
        base = dtype.fields[name][0]
        if base.kind == "f":
            rec[name] = rng.uniform(-20, 20, n)
        else:
            rec[name] = rng.integers(0, 1000, n)
    return rec


def raw_cloud(factory, dtype, rec, width, height, row_step=None, bigendian=False, fields=None):
    """A PointCloud2 whose data are the records' bytes, rows padded to row_step with 0xCD."""
    ps = dtype.itemsize
    row_step = ps * width if row_step is None else row_step
    body = np.full((height, row_step), 0xCD, np.uint8)
    if width * height:
        body[:, : width * ps] = np.frombuffer(rec.tobytes(), np.uint8).reshape(height, width * ps)
    if fields is None:
        fields = [(n, dtype.fields[n][1], CODES[dtype.fields[n][0].str[1:]], 1) for n in dtype.names]
    pf = [factory.make("sensor_msgs/msg/PointField", name=n, offset=o, datatype=d, count=c)
          for n, o, d, c in fields]
    return factory.make(
        "sensor_msgs/msg/PointCloud2", header=factory.header(7.25, "lidar"), height=height, width=width,
        fields=pf, is_bigendian=bigendian, point_step=ps, row_step=row_step, data=body.tobytes(),
        is_dense=False,
    )


def expected_xyz(rec):
    return np.stack([rec["x"], rec["y"], rec["z"]], axis=1).astype(np.float32)


@pytest.mark.parametrize("factory", FACTORIES)
def test_ouster_organized_with_invalid_returns(factory):
    rng = np.random.default_rng(0)
    dtype = layout(OUSTER, 48)
    h, w = 4, 16
    rec = records(dtype, h * w, rng)
    rec["x"][3] = rec["y"][3] = rec["z"][3] = 0.0  # Ouster's "no return"
    rec["y"][10] = np.nan
    rec["z"][20] = np.inf
    msg = raw_cloud(factory, dtype, rec, w, h)
    cloud = read_points(msg, extra_fields=["ring", "range", "intensity", "t"])
    keep = np.setdiff1d(np.arange(h * w), [3, 10, 20])
    np.testing.assert_array_equal(cloud.index, keep)
    np.testing.assert_array_equal(cloud.xyz, expected_xyz(rec)[keep])
    np.testing.assert_array_equal(cloud.fields["ring"], rec["ring"][keep])
    np.testing.assert_array_equal(cloud.fields["range"], rec["range"][keep])
    np.testing.assert_array_equal(cloud.fields["t"], rec["t"][keep])
    assert cloud.fields["ring"].dtype == np.uint16 and cloud.fields["range"].dtype == np.uint32
    assert cloud.xyz.dtype == np.float32 and cloud.xyz.shape == (len(keep), 3)
    assert (cloud.width, cloud.height, cloud.frame_id, cloud.stamp_ns) == (w, h, "lidar", 7_250_000_000)
    # Zero points are kept on request; NaN/inf never.
    assert len(read_points(msg, drop_origin=False)) == h * w - 2


@pytest.mark.parametrize("factory", FACTORIES)
@pytest.mark.parametrize("spec,step", [(VLP16_PACKED, 22), (VLP16_ALIGNED, 32)], ids=["vlp16-22", "vlp16-32"])
def test_velodyne_layouts(factory, spec, step):
    rng = np.random.default_rng(1)
    dtype = layout(spec, step)
    rec = records(dtype, 100, rng)
    cloud = read_points(raw_cloud(factory, dtype, rec, 100, 1), ["ring", "intensity"])
    np.testing.assert_array_equal(cloud.xyz, expected_xyz(rec))
    np.testing.assert_array_equal(cloud.fields["ring"], rec["ring"])
    np.testing.assert_array_equal(cloud.fields["intensity"], rec["intensity"])


@pytest.mark.parametrize("factory", FACTORIES)
def test_any_field_order_float64_big_endian_and_row_padding(factory):
    rng = np.random.default_rng(2)
    spec = [("ring", "u2", 0), ("z", "f8", 2), ("x", "f8", 10), ("y", "f8", 18), ("intensity", "f4", 28)]
    dtype = layout(spec, 36, order=">")
    h, w = 3, 5
    rec = records(dtype, h * w, rng)
    msg = raw_cloud(factory, dtype, rec, w, h, row_step=w * 36 + 7, bigendian=True)
    cloud = read_points(msg, ["ring", "intensity"])
    np.testing.assert_allclose(cloud.xyz, np.stack([rec["x"], rec["y"], rec["z"]], 1), rtol=1e-6)
    np.testing.assert_array_equal(cloud.fields["ring"], rec["ring"])
    assert cloud.fields["ring"].dtype == np.dtype("=u2")  # native byte order for callers
    assert field_names(msg) == ["ring", "z", "x", "y", "intensity"]


def test_duck_typed_message_with_list_data_and_count_zero():
    dtype = layout([("x", "f4", 0), ("y", "f4", 4), ("z", "f4", 8)], 12)
    rec = records(dtype, 3, np.random.default_rng(3))
    fields = [SimpleNamespace(name=n, offset=4 * i, datatype=7, count=0) for i, n in enumerate("xyz")]
    msg = SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=1, nanosec=500_000_000), frame_id="f"),
        height=1, width=3, fields=fields, is_bigendian=False, point_step=12, row_step=36,
        data=list(rec.tobytes()), is_dense=True,
    )
    cloud = read_points(msg)
    np.testing.assert_array_equal(cloud.xyz, expected_xyz(rec))
    assert cloud.stamp_ns == 1_500_000_000


@needs_rclpy
def test_rclpy_message_read_back_through_a_bag_roundtrip():
    from rclpy.serialization import serialize_message

    dtype = layout(OUSTER, 48)
    rec = records(dtype, 50, np.random.default_rng(4))
    msg = raw_cloud(RclpyFactory(), dtype, rec, 50, 1)
    from_bag = TS.deserialize_cdr(bytes(serialize_message(msg)), "sensor_msgs/msg/PointCloud2")
    a, b = read_points(msg, ["ring"]), read_points(from_bag, ["ring"])
    np.testing.assert_array_equal(a.xyz, b.xyz)
    np.testing.assert_array_equal(a.fields["ring"], b.fields["ring"])


@pytest.mark.parametrize("factory", FACTORIES)
def test_empty_clouds(factory):
    dtype = layout(OUSTER, 48)
    empty = raw_cloud(factory, dtype, records(dtype, 0, np.random.default_rng(0)), 0, 1)
    cloud = read_points(empty, ["ring"])
    assert cloud.xyz.shape == (0, 3) and cloud.fields["ring"].shape == (0,)
    assert cloud.fields["ring"].dtype == np.uint16
    bare = factory.make("sensor_msgs/msg/PointCloud2")  # no fields at all
    assert read_points(bare).xyz.shape == (0, 3)
    assert read_fields(empty, ["x", "ring"])["ring"].shape == (0,)


def test_read_fields_keeps_all_points_and_counts():
    dtype = np.dtype({"names": ["x", "y", "z", "rgb3"], "formats": ["<f4", "<f4", "<f4", ("<u1", (3,))],
                      "offsets": [0, 4, 8, 12], "itemsize": 16})
    rec = np.zeros(2, dtype)
    rec["x"] = [np.nan, 1.0]
    rec["rgb3"] = [[1, 2, 3], [4, 5, 6]]
    fields = [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("rgb3", 12, 2, 3)]
    msg = raw_cloud(RosbagsFactory(), dtype, rec, 2, 1, fields=fields)
    out = read_fields(msg, ["x", "rgb3"])
    assert np.isnan(out["x"][0]) and out["x"][1] == 1.0
    np.testing.assert_array_equal(out["rgb3"], [[1, 2, 3], [4, 5, 6]])
    assert read_points(msg, ["rgb3"]).fields["rgb3"].tolist() == [[4, 5, 6]]


# ----------------------------------------------------------------------------------------------- malformed
def _xyz_cloud(**overrides):
    dtype = layout([("x", "f4", 0), ("y", "f4", 4), ("z", "f4", 8), ("i", "f4", 12)], 16)
    rec = records(dtype, 4, np.random.default_rng(5))
    msg = raw_cloud(RosbagsFactory(), dtype, rec, 4, 1)
    for key, value in overrides.items():
        setattr(msg, key, value)
    return msg


def _fields(*spec):
    return [RosbagsFactory().make("sensor_msgs/msg/PointField", name=n, offset=o, datatype=d, count=c)
            for n, o, d, c in spec]


XYZI = [("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1), ("i", 12, 7, 1)]


@pytest.mark.parametrize("overrides,match", [
    ({"data": np.zeros(63, np.uint8)}, "data has 63 bytes, expected row_step 64"),
    ({"data": np.zeros(65, np.uint8)}, "data has 65 bytes"),
    ({"row_step": 60}, "row_step 60 < width 4 x point_step 16"),
    ({"point_step": 0}, "point_step is 0"),
    ({"fields": _fields(*XYZI[1:])}, "no field 'x'"),
    ({"fields": _fields(("x", 0, 9, 1), *XYZI[1:])}, "'x' has unsupported datatype 9"),
    ({"fields": _fields(("x", 0, 3, 1), *XYZI[1:])}, "coordinate field 'x' must be one float32 or float64"),
    ({"fields": _fields(*XYZI[:3], ("i", 14, 7, 1))}, "'i' .* does not fit in point_step 16"),
    ({"fields": _fields(("x", 0, 7, 1), ("y", 2, 7, 1), ("z", 8, 7, 1))}, "fields 'x' and 'y' overlap"),
    ({"fields": _fields(*XYZI, ("x", 12, 7, 1))}, "field 'x' appears 2 times"),
    ({"data": "not bytes"}, "data is not a byte buffer"),
])
def test_malformed_clouds_raise_clear_errors(overrides, match):
    with pytest.raises(PointCloudError, match=match):
        read_points(_xyz_cloud(**overrides))


def test_missing_extra_field_names_the_fields():
    with pytest.raises(PointCloudError, match=r"no field 'ring' \(fields: x, y, z, i\)"):
        read_points(_xyz_cloud(), ["ring"])


def test_unknown_unused_fields_are_ignored():
    msg = _xyz_cloud(fields=_fields(*XYZI[:3], ("weird", 12, 42, 1)))
    assert len(read_points(msg)) == 4


def test_point_cloud_error_is_a_value_error():
    assert issubclass(PointCloudError, ValueError)


# ------------------------------------------------------------------------------------------------- writer
@pytest.mark.parametrize("factory", FACTORIES)
def test_make_pointcloud2_roundtrip_all_dtypes(factory):
    rng = np.random.default_rng(6)
    n = 50
    cols = {
        "x": rng.normal(size=n).astype(np.float32), "y": rng.normal(size=n).astype(np.float64),
        "z": rng.normal(size=n).astype(np.float32), "person": rng.integers(-5, 5, n).astype(np.int32),
        "joint": rng.integers(0, 60000, n).astype(np.uint16),
        "flag": rng.integers(0, 255, n).astype(np.uint8),
        "t": rng.integers(0, 2**32 - 1, n).astype(np.uint32), "s": rng.integers(-9, 9, n).astype(np.int8),
        "h": rng.integers(-300, 300, n).astype(np.int16),
    }
    msg = make_pointcloud2(3.5, "camera", cols, factory)
    assert (msg.height, msg.width, msg.is_bigendian, msg.is_dense) == (1, n, False, True)
    assert msg.point_step == 4 + 8 + 4 + 4 + 2 + 1 + 4 + 1 + 2 and msg.row_step == msg.point_step * n
    assert [(f.name, f.datatype) for f in msg.fields] == [
        ("x", 7), ("y", 8), ("z", 7), ("person", 5), ("joint", 4), ("flag", 2), ("t", 6), ("s", 1), ("h", 3)]
    back = read_fields(msg, list(cols))
    for name, col in cols.items():
        np.testing.assert_array_equal(back[name], col)
        assert back[name].dtype == col.dtype
    assert msg.header.frame_id == "camera" and msg.header.stamp.nanosec == 500_000_000


@needs_rclpy
def test_make_pointcloud2_same_message_from_both_factories():
    from rclpy.serialization import serialize_message

    cols = {"x": np.arange(3, dtype=np.float32), "y": np.ones(3, np.float32), "z": np.zeros(3, np.float32),
            "person": np.array([1, 2, 3], np.int32)}
    a = make_pointcloud2(1.0, "c", cols, RclpyFactory())
    b = make_pointcloud2(1.0, "c", cols, RosbagsFactory())
    assert to_plain(a) == to_plain(b)
    wire = TS.deserialize_cdr(bytes(serialize_message(a)), "sensor_msgs/msg/PointCloud2")
    assert to_plain(wire) == to_plain(b)


def test_make_pointcloud2_nan_clears_is_dense_and_empty_columns_work():
    msg = make_pointcloud2(0.0, "c", {"x": np.array([np.nan], np.float32)}, RosbagsFactory())
    assert msg.is_dense is False
    empty = make_pointcloud2(0.0, "c", {"x": np.zeros(0, np.float32), "person": np.zeros(0, np.int32)},
                             RosbagsFactory())
    assert empty.width == 0 and len(empty.data) == 0 and [f.name for f in empty.fields] == ["x", "person"]


@pytest.mark.parametrize("columns,match", [
    ({}, "at least one column"),
    ({"x": np.zeros(3, np.int64)}, "column 'x' has dtype int64"),
    ({"x": np.zeros(3, bool)}, "column 'x' has dtype bool"),
    ({"x": np.zeros((3, 2), np.float32)}, "must be 1-D"),
    ({"x": np.zeros(3, np.float32), "y": np.zeros(2, np.float32)}, "column 'y' has 2 values"),
])
def test_make_pointcloud2_rejects_bad_columns(columns, match):
    with pytest.raises(PointCloudError, match=match):
        make_pointcloud2(0.0, "c", columns, RosbagsFactory())


@pytest.mark.parametrize("factory", FACTORIES)
def test_read_points_of_a_30k_point_organized_scan(factory):
    """NaN returns dropped from a 30-ring scan (its time printed: speed is measured, never asserted)."""
    rng = np.random.default_rng(7)
    dtype = layout(OUSTER, 48)
    rec = records(dtype, 30_000, rng)
    rec["x"][::10] = np.nan
    msg = raw_cloud(factory, dtype, rec, 1000, 30)  # organized, like a 30-ring scan
    best = min(_timed(lambda: read_points(msg, ["ring", "intensity"])) for _ in range(15))
    print(f"read_points took {best * 1e3:.2f} ms for 30k points")
    assert len(read_points(msg)) == 27_000


def _timed(fn):
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0
