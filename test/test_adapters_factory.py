"""MessageFactory: both runtimes build the same messages; stamps convert exactly."""

from __future__ import annotations

import array
import subprocess
import sys

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from msg_adapters.factory import (
    RclpyFactory,
    RosbagsFactory,
    default_factory,
    normalize_typename,
    rclpy_available,
    split_stamp,
    stamp_to_ns,
    stamp_to_sec,
    to_plain,
)

TS = get_typestore(Stores.ROS2_JAZZY)
needs_rclpy = pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")


def serialize(msg):
    """CDR bytes of a message of either runtime, each serialized by its own runtime."""
    if hasattr(msg, "__msgtype__"):
        return bytes(TS.serialize_cdr(msg, msg.__msgtype__))
    from rclpy.serialization import serialize_message

    return bytes(serialize_message(msg))


def wire_content(msg, typename):
    """What a message says on the wire, runtime-independent (CDR alignment padding is not compared:
    rclpy leaves it uninitialized)."""
    return to_plain(TS.deserialize_cdr(serialize(msg), typename))


def test_stamp_float_and_message_roundtrip():
    assert split_stamp(1.5) == (1, 500_000_000)
    assert split_stamp(-0.25) == (-1, 750_000_000)
    assert stamp_to_ns(3) == 3, "integers are nanoseconds"
    assert stamp_to_ns(3.0) == 3_000_000_000
    # Float seconds near today's epoch: the fraction is kept to well under a microsecond.
    sec, ns = split_stamp(1_700_000_000.123456)
    assert sec == 1_700_000_000 and abs(ns - 123_456_000) < 300
    stamp = RosbagsFactory().time(1.0)
    stamp.sec, stamp.nanosec = 1_700_000_000, 123_456_789
    assert stamp_to_ns(stamp) == 1_700_000_000_123_456_789
    assert split_stamp(stamp) == (1_700_000_000, 123_456_789)
    assert stamp_to_sec(stamp) == pytest.approx(1_700_000_000.123456789, abs=1e-6)


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), "1.0", None, True])
def test_stamp_rejects_garbage(bad):
    with pytest.raises((TypeError, ValueError)):
        stamp_to_ns(bad)


def test_stamp_out_of_int32_range():
    with pytest.raises(ValueError, match="int32"):
        split_stamp(2.0**31 + 5)


def test_normalize_typename():
    assert normalize_typename("sensor_msgs/PointCloud2") == "sensor_msgs/msg/PointCloud2"
    assert normalize_typename("sensor_msgs/msg/PointCloud2") == "sensor_msgs/msg/PointCloud2"
    with pytest.raises(TypeError, match="not a message type"):
        normalize_typename("PointCloud2")


def test_rosbags_make_fills_defaults_and_converts():
    f = RosbagsFactory()
    info = f.make("sensor_msgs/msg/CameraInfo", width=640, k=[1, 0, 2, 0, 1, 3, 0, 0, 1], d=[0.1, 0.2])
    assert info.width == 640 and info.height == 0 and info.distortion_model == ""
    assert info.k.dtype == np.float64 and info.k.shape == (9,) and info.k[2] == 2.0
    assert info.d.dtype == np.float64 and info.d.tolist() == [0.1, 0.2]
    assert info.r.shape == (9,) and info.p.shape == (12,) and info.header.frame_id == ""
    img = f.make("sensor_msgs/msg/Image", data=b"\x01\x02")
    assert img.data.dtype == np.uint8 and img.data.tolist() == [1, 2]
    status = f.make("diagnostic_msgs/msg/DiagnosticStatus", level=b"\x02")
    assert status.level == 2
    # The .msg default w = 1 holds, as in rclpy, also inside a default-built parent.
    assert f.make("geometry_msgs/msg/Quaternion").w == 1.0
    assert f.make("geometry_msgs/msg/Pose").orientation.w == 1.0


@pytest.mark.parametrize("factory", [RosbagsFactory(), pytest.param(RclpyFactory(), marks=needs_rclpy)],
                         ids=["rosbags", "rclpy"])
def test_make_errors(factory):
    with pytest.raises(TypeError, match="no field.*colour"):
        factory.make("std_msgs/msg/ColorRGBA", colour=1.0)
    with pytest.raises(TypeError, match="unknown message type"):
        factory.make("sensor_msgs/msg/NoSuchThing")
    with pytest.raises(ValueError, match="needs 9 values"):
        factory.make("sensor_msgs/msg/CameraInfo", k=[1.0, 2.0])


@needs_rclpy
def test_rclpy_make_converts_numpy():
    f = RclpyFactory()
    cloud = f.make("sensor_msgs/msg/PointCloud2", width=np.uint32(3), data=np.arange(4, dtype=np.uint8),
                   is_dense=np.bool_(True))
    assert isinstance(cloud.data, array.array) and list(cloud.data) == [0, 1, 2, 3]
    assert cloud.width == 3 and type(cloud.width) is int and cloud.is_dense is True
    info = f.make("sensor_msgs/msg/CameraInfo", d=np.array([0.5, 0.25]), k=np.eye(3))
    assert list(info.d) == [0.5, 0.25] and info.k[4] == 1.0
    status = f.make("diagnostic_msgs/msg/DiagnosticStatus", level=2)
    assert status.level == b"\x02"


@needs_rclpy
def test_both_factories_serialize_identically():
    msgs = []
    for f in (RclpyFactory(), RosbagsFactory()):
        header = f.header(12.25, "camera")
        msgs.append(f.make("sensor_msgs/msg/CameraInfo", header=header, width=4, height=3,
                           distortion_model="plumb_bob", d=[0.1, 0, 0, 0, 0], k=np.eye(3).ravel()))
    content = [wire_content(m, "sensor_msgs/msg/CameraInfo") for m in msgs]
    assert content[0] == content[1] == to_plain(msgs[0]) == to_plain(msgs[1])
    assert content[0]["d"] == [0.1, 0, 0, 0, 0] and content[0]["k"][8] == 1.0
    assert msgs[0].header.stamp.sec == 12 and msgs[0].header.stamp.nanosec == 250_000_000


@pytest.mark.parametrize("factory", [RosbagsFactory(), pytest.param(RclpyFactory(), marks=needs_rclpy)],
                         ids=["rosbags", "rclpy"])
def test_header_copies_stamp_message_exactly(factory):
    src = factory.time(0.0)
    src.sec, src.nanosec = 1_700_000_001, 999_999_999
    header = factory.header(src, "cam")
    assert (header.stamp.sec, header.stamp.nanosec, header.frame_id) == (1_700_000_001, 999_999_999, "cam")
    assert factory.duration(1.5).nanosec == 500_000_000


@pytest.mark.parametrize("factory", [RosbagsFactory(), pytest.param(RclpyFactory(), marks=needs_rclpy)],
                         ids=["rosbags", "rclpy"])
def test_points(factory):
    xyz = np.array([[1.0, 2.0, 3.0], [-4.5, 0.0, 1e-3]])
    pts = factory.points(xyz)
    assert [(p.x, p.y, p.z) for p in pts] == [tuple(r) for r in xyz.tolist()]
    assert pts[0] == factory.make("geometry_msgs/msg/Point", x=1.0, y=2.0, z=3.0)
    pts[1].x = 7.0  # the fast rclpy path leaves a normal, settable message
    assert pts[1].x == 7.0
    assert factory.points(np.zeros((0, 3))) == []


def test_default_factory_matches_environment():
    assert default_factory().name == ("rclpy" if rclpy_available() else "rosbags")


def test_works_without_rclpy():
    """The replay path: no rclpy, every writer falls back to rosbags messages."""
    code = (
        "import sys\n"
        "for m in ('rclpy', 'sensor_msgs', 'visualization_msgs'): sys.modules[m] = None\n"
        "import numpy as np, msg_adapters as ma\n"
        "assert ma.default_factory().name == 'rosbags'\n"
        "msg = ma.make_pointcloud2(1.0, 'c', {'x': np.zeros(2, np.float32)})\n"
        "assert type(msg).__module__.startswith('rosbags'), type(msg)\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], check=False, capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr
