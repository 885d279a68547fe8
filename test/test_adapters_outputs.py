"""BodyFit[] -> joints cloud, body points cloud, PoseArray; DiagnosticArray."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msg_adapters.diagnostics import diagnostics_array, format_value
from msg_adapters.factory import RclpyFactory, RosbagsFactory, rclpy_available, to_plain
from msg_adapters.outputs import (
    fits_to_body_points_cloud,
    fits_to_joints_cloud,
    fits_to_pose_array,
)
from msg_adapters.pointcloud2 import read_fields
from smplify3d_ros.geometry import rotvec_to_quaternion
from smplify3d_ros.keypoints import KP
from smplify3d_ros.types import BodyFit, BodyParams, FitQuality

needs_rclpy = pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")
FACTORIES = [pytest.param(RosbagsFactory(), id="rosbags"),
             pytest.param(RclpyFactory(), id="rclpy", marks=needs_rclpy)]


def make_fit(pid: int, n_verts: int = 30, root=(0.0, 0.0, 0.0)) -> BodyFit:
    rng = np.random.default_rng(abs(pid))
    params = BodyParams("anny", np.full(3, 0.5), np.zeros((2, 3)), np.array(root, float),
                        np.array([0, 0, 4.0]))
    return BodyFit(
        pid, params, ["a", "b"], rng.normal(size=(n_verts, 3)).astype(np.float32),
        rng.normal(size=(17, 3)).astype(np.float32), np.zeros((2, 3), np.float32),
        FitQuality(1.0, 0.01, 10, [], True, 0.5),
    )


@pytest.mark.parametrize("factory", FACTORIES)
def test_joints_cloud(factory):
    fits = [make_fit(4), make_fit(-1)]
    fits[1].keypoints3d[KP["nose"]] = np.nan  # skipped
    msg = fits_to_joints_cloud(fits, 3.0, "cam", factory)
    assert [(f.name, f.datatype) for f in msg.fields] == [("x", 7), ("y", 7), ("z", 7), ("person", 5),
                                                          ("joint", 4)]
    cols = read_fields(msg, ["x", "y", "z", "person", "joint"])
    assert msg.width == 33 and msg.is_dense
    assert cols["person"].tolist() == [4] * 17 + [-1] * 16
    assert cols["joint"].tolist() == list(range(17)) + list(range(1, 17))
    np.testing.assert_array_equal(np.c_[cols["x"], cols["y"], cols["z"]][:17], fits[0].keypoints3d)
    np.testing.assert_array_equal(cols["x"][17:], fits[1].keypoints3d[1:, 0])


@pytest.mark.parametrize("factory", FACTORIES)
def test_body_points_cloud_with_stride(factory):
    fits = [make_fit(1, 30), make_fit(2, 11)]
    msg = fits_to_body_points_cloud(fits, 3.0, "cam", factory, stride=3)
    cols = read_fields(msg, ["x", "y", "z", "person"])
    assert cols["person"].tolist() == [1] * 10 + [2] * 4
    np.testing.assert_array_equal(np.c_[cols["x"], cols["y"], cols["z"]],
                                  np.r_[fits[0].vertices[::3], fits[1].vertices[::3]])
    assert [f.name for f in msg.fields] == ["x", "y", "z", "person"]
    with pytest.raises(ValueError, match="stride must be >= 1"):
        fits_to_body_points_cloud(fits, 3.0, "cam", factory, stride=0)


def test_empty_fits_give_empty_clouds():
    assert fits_to_joints_cloud([], 1.0, "c", RosbagsFactory()).width == 0
    assert fits_to_body_points_cloud([], 1.0, "c", RosbagsFactory()).width == 0
    assert fits_to_pose_array([], 1.0, "c", RosbagsFactory()).poses == []


def _rotate(q_xyzw, v):
    x, y, z, w = q_xyzw
    u = np.array([x, y, z])
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


def _rodrigues(r, v):
    angle = np.linalg.norm(r)
    if angle == 0:
        return v
    k = r / angle
    return v * np.cos(angle) + np.cross(k, v) * np.sin(angle) + k * (k @ v) * (1 - np.cos(angle))


@pytest.mark.parametrize("rotvec", [(0, 0, 0), (1e-9, 0, 0), (0.3, -0.2, 0.9), (0, np.pi, 0), (2, 2, 1)])
def test_rotvec_to_quaternion(rotvec):
    q = rotvec_to_quaternion(np.array(rotvec, float))
    assert np.linalg.norm(q) == pytest.approx(1.0) and q[3] >= 0
    v = np.array([0.3, -1.0, 2.0])
    np.testing.assert_allclose(_rotate(q, v), _rodrigues(np.array(rotvec, float), v), atol=1e-12)
    if not any(rotvec):
        assert q.tolist() == [0.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize("factory", FACTORIES)
def test_pose_array(factory):
    fits = [make_fit(1, root=(0.0, np.pi / 2, 0.0)), make_fit(2)]
    msg = fits_to_pose_array(fits, 6.0, "cam", factory)
    assert msg.header.frame_id == "cam" and len(msg.poses) == 2
    p = msg.poses[0]
    hips = fits[0].keypoints3d[[KP["left_hip"], KP["right_hip"]]].astype(np.float64).mean(axis=0)
    np.testing.assert_allclose([p.position.x, p.position.y, p.position.z], hips, atol=1e-6)
    # REP-103 axes for a person (x forward, y left, z up), i.e. the body's canonical z, x and y axes
    for pose, fit in zip(msg.poses, fits, strict=True):
        o = pose.orientation
        axes = Rotation.from_quat([o.x, o.y, o.z, o.w]).as_matrix()
        root = Rotation.from_rotvec(fit.params.root_orient).as_matrix()
        np.testing.assert_allclose(axes, root[:, [2, 0, 1]], atol=1e-12)
    o = msg.poses[0].orientation
    forward = Rotation.from_quat([o.x, o.y, o.z, o.w]).apply([1.0, 0.0, 0.0])
    np.testing.assert_allclose(forward, [1.0, 0.0, 0.0], atol=1e-12), "turned 90 deg: facing camera x"


def test_ids_must_fit_int32():
    with pytest.raises(ValueError, match="must fit int32"):
        fits_to_joints_cloud([make_fit(2**31)], 1.0, "c", RosbagsFactory())


@needs_rclpy
def test_outputs_same_from_both_factories():
    fits = [make_fit(1, root=(0.1, 0.2, 0.3)), make_fit(5)]
    for fn in (fits_to_joints_cloud, fits_to_body_points_cloud, fits_to_pose_array):
        assert to_plain(fn(fits, 1.0, "c", RclpyFactory())) == to_plain(fn(fits, 1.0, "c", RosbagsFactory()))


# ---------------------------------------------------------------------------------------------- diagnostics
@pytest.mark.parametrize("factory", FACTORIES)
def test_diagnostics_array(factory):
    values = {"people": 2, "latency_s": 0.0123456789, "state": "running", "dropped": True}
    msg = diagnostics_array(7.0, "smplify3d: fitting", "WARN", "slow", values, factory, hardware_id="gpu0")
    assert msg.header.stamp.sec == 7 and len(msg.status) == 1
    st = msg.status[0]
    assert to_plain(st)["level"] == 1
    assert (st.name, st.message, st.hardware_id) == ("smplify3d: fitting", "slow", "gpu0")
    assert [(kv.key, kv.value) for kv in st.values] == [
        ("people", "2"), ("latency_s", "0.0123457"), ("state", "running"), ("dropped", "true")]
    assert to_plain(diagnostics_array(0.0, "n", 2, "", {}, factory).status[0])["level"] == 2


@needs_rclpy
def test_diagnostics_same_from_both_factories():
    args = (1.0, "n", "ERROR", "m", {"a": 1.5})
    a, b = diagnostics_array(*args, RclpyFactory()), diagnostics_array(*args, RosbagsFactory())
    assert to_plain(a) == to_plain(b)


@pytest.mark.parametrize("level,match", [("BAD", "unknown diagnostic level 'BAD'"), (4, "0 \\(OK\\) to 3"),
                                         (-1, "0 \\(OK\\) to 3")])
def test_diagnostics_bad_level(level, match):
    with pytest.raises(ValueError, match=match):
        diagnostics_array(0.0, "n", level, "", {}, RosbagsFactory())


def test_format_value():
    assert format_value(float("nan")) == "nan" and format_value(3) == "3" and format_value(False) == "false"
    assert format_value(1234567.0) == "1.23457e+06"


def test_body_points_on_a_grid():
    fits = [make_fit(1, 30)]
    grid = 2.0**-8
    cols = read_fields(fits_to_body_points_cloud(fits, 3.0, "cam", RosbagsFactory(), grid_m=grid), ["x", "y", "z"])
    xyz = np.c_[cols["x"], cols["y"], cols["z"]].astype(np.float64)
    assert np.abs(xyz - fits[0].vertices).max() <= grid / 2 + 1e-6
    assert np.array_equal(xyz / grid, np.round(xyz / grid))
