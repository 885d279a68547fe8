"""Transforms at the image's stamp: the time-indexed TF graph a replay builds from /tf and /tf_static
(interpolation like tf2, no extrapolation), motion compensation through a fixed frame, the extrinsic as a
TFMessage, and the processor dropping (and counting) a frame TF cannot place at its stamp."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msg_adapters import RosbagsFactory
from smplify3d_ros.geometry import invert, transform
from smplify3d_ros.runtime.config import load_node_config
from smplify3d_ros.runtime.transforms import (
    TransformGraph,
    Transforms,
    TransformUnavailable,
    extrinsic_tf_message,
    tf_message,
)

F = RosbagsFactory()
S = 1_000_000_000
T0 = 1_700_000_000 * S


def odom_to_base(t_ns: int) -> np.ndarray:
    """The robot drives at 1 m/s along odom x while turning at 0.2 rad/s."""
    dt = (t_ns - T0) * 1e-9
    return transform(Rotation.from_euler("z", 0.2 * dt).as_matrix(), (1.0 * dt, 0.0, 0.0))


def moving_graph(extrinsic) -> TransformGraph:
    graph = TransformGraph()
    base_velodyne = transform(None, (0.0, 0.0, 0.4))
    graph.add(tf_message([("base_link", "velodyne", base_velodyne)], T0, F))
    graph.add(extrinsic_tf_message(extrinsic, T0, F))  # velodyne -> camera_color_optical_frame
    for k in range(0, 51):  # 50 Hz for 1 s
        t = T0 + k * S // 50
        graph.add(tf_message([("odom", "base_link", odom_to_base(t))], t, F), static=False)
    return graph


def test_dynamic_edges_interpolate_and_never_extrapolate():
    ext = load_node_config().extrinsic
    graph = moving_graph(ext)
    t = T0 + 333_333_333  # between two samples
    expected = odom_to_base(t) @ transform(None, (0, 0, 0.4)) @ ext.T_lidar_cam()
    np.testing.assert_allclose(graph.lookup("odom", ext.camera_frame, t), expected, atol=1e-9)
    np.testing.assert_allclose(graph.lookup(ext.camera_frame, "odom", t), invert(expected), atol=1e-9)
    np.testing.assert_allclose(graph.lookup("odom", "base_link", T0 + S // 50), odom_to_base(T0 + S // 50))
    np.testing.assert_allclose(graph.lookup("odom", "base_link", None), odom_to_base(T0 + S), atol=1e-12)
    with pytest.raises(TransformUnavailable, match="odom -> base_link has no transform at"):
        graph.lookup("odom", ext.camera_frame, T0 + 2 * S)
    assert graph.lookup("map", ext.camera_frame, t) is None, "unknown frame: None, not a drop"
    # static edges hold at any time
    np.testing.assert_allclose(graph.lookup(ext.camera_frame, "velodyne", T0 + 99 * S), ext.T_cam_lidar(), atol=1e-9)


def test_motion_compensation_moves_the_scan_to_the_image_time():
    ext = load_node_config(None, {"node": {"extrinsic": {"motion_compensation": True}}}).extrinsic
    graph = moving_graph(ext)
    t_image, t_cloud = T0 + 500_000_000, T0 + 520_000_000  # the scan 20 ms after the image
    plain = Transforms(load_node_config().extrinsic, graph.lookup)
    moving = Transforms(ext, graph.lookup)
    T_plain = plain.cam_from_lidar(ext.camera_frame, "velodyne", t_image, t_cloud)
    T_moved = moving.cam_from_lidar(ext.camera_frame, "velodyne", t_image, t_cloud)
    np.testing.assert_allclose(T_plain, ext.T_cam_lidar(), atol=1e-9)
    base_velodyne = transform(None, (0, 0, 0.4))
    expected = invert(odom_to_base(t_image) @ base_velodyne @ ext.T_lidar_cam()) @ odom_to_base(t_cloud) @ base_velodyne
    np.testing.assert_allclose(T_moved, expected, atol=1e-9)
    # a point 5 m ahead, seen 20 ms later by a robot driving at 1 m/s: 2 cm nearer then, so 2 cm farther
    # from where the camera was at the image's time, along the camera's forward (z) axis
    p = np.array([5.0, 0.0, 0.0, 1.0])
    shift = (T_moved @ p - T_plain @ p)[:3]
    assert shift[2] == pytest.approx(0.02, abs=2e-3) and np.linalg.norm(shift) < 0.03


def test_lookups_are_made_at_the_image_stamp():
    calls = []

    def lookup(target, source, stamp_ns, source_stamp_ns=None, fixed_frame=None):
        calls.append((target, source, stamp_ns, source_stamp_ns, fixed_frame))
        return np.eye(4)

    ext = load_node_config().extrinsic
    transforms = Transforms(ext, lookup)
    transforms.cam_from_lidar(ext.camera_frame, "velodyne", T0 + 7, T0 + 20_000_007)
    transforms.out_from_cam("odom", ext.camera_frame, "velodyne", T0 + 7)
    assert calls == [(ext.camera_frame, "velodyne", T0 + 7, None, None), ("odom", ext.camera_frame, T0 + 7, None, None)]


def test_the_extrinsic_tf_message_says_what_the_parameters_say():
    ext = load_node_config().extrinsic
    msg = extrinsic_tf_message(ext, T0, F)
    t = msg.transforms[0]
    assert (t.header.frame_id, t.child_frame_id) == (ext.lidar_frame, ext.camera_frame)
    graph = TransformGraph()
    graph.add(msg)
    np.testing.assert_allclose(graph.lookup(ext.camera_frame, ext.lidar_frame, T0), ext.T_cam_lidar(), atol=1e-9)


def test_a_frame_tf_cannot_place_at_its_stamp_is_a_counted_drop():
    import node_support

    from smplify3d_ros.runtime.messages import FrameMessages
    from smplify3d_ros.runtime.processor import MessageProcessor

    node_cfg = load_node_config(None, {"node": {"output_frame": "odom"}})
    graph = moving_graph(node_cfg.extrinsic)
    bag = node_support.fixture_bag("mcap")
    processor = MessageProcessor(node_support.config(), node_cfg, F, fitter=node_support.fitter(),
                                 transforms=Transforms(node_cfg.extrinsic, graph.lookup))
    msgs = node_support.bad_frame("no_people", F, bag.camera, bag.frames[0], (T0 + 5 * S) * 1e-9)  # after the /tf
    result = processor.process(FrameMessages(msgs["camera_info"], msgs["points"], msgs["keypoints"], msgs["image"]))
    assert result.drop == "tf_timeout" and "no transform at" in result.message
    assert processor.stats.drops["tf_timeout"] == 1
    msgs = node_support.bad_frame("no_people", F, bag.camera, bag.frames[0], (T0 + S // 2) * 1e-9)
    result = processor.process(FrameMessages(msgs["camera_info"], msgs["points"], msgs["keypoints"], msgs["image"]))
    assert result.ok and result.frame_id == "odom"
