"""Replay with a recorded /tf: `output_frame: odom` puts each frame's bodies where odometry had the camera at
the image's stamp (interpolated between /tf samples), and a frame outside the recorded /tf is a counted drop."""

from __future__ import annotations

import dataclasses

import node_support
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msg_adapters import RosbagsFactory
from smplify3d_ros.geometry import transform
from smplify3d_ros.runtime.config import load_node_config
from smplify3d_ros.runtime.transforms import tf_message

pytest.importorskip("rosbags")

S = 1_000_000_000


def odom_to_velodyne(t_ns: int, t0_ns: int) -> np.ndarray:
    dt = (t_ns - t0_ns) * 1e-9
    return transform(Rotation.from_euler("z", 0.3 * dt).as_matrix(), (0.8 * dt, 0.1 * dt, 0.0))


def bag_with_tf(tmp_path, tf_until_s: float):
    """The two-frame fixture bag plus /tf odom -> velodyne at 50 Hz from its start for `tf_until_s`."""
    from rosbags.rosbag2 import Reader, Writer

    source = node_support.fixture_bag("mcap").path
    path = tmp_path / "with_tf"
    factory = RosbagsFactory()
    store = factory.typestore
    with Reader(source) as reader, Writer(path, version=9) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store) for c in reader.connections}
        tf = writer.add_connection("/tf", "tf2_msgs/msg/TFMessage", typestore=store)
        t0 = reader.start_time
        for k in range(int(tf_until_s * 50) + 1):
            t = t0 + k * S // 50
            msg = tf_message([("odom", "velodyne", odom_to_velodyne(t, t0))], t, factory)
            writer.write(tf, t, store.serialize_cdr(msg, "tf2_msgs/msg/TFMessage"))
        for conn, t, raw in reader.messages():
            writer.write(conns[conn.id], t, raw)
    return path, t0


class SpreadStubFitter(node_support.StubFitter):
    """The stub's fits with 17 distinct keypoints (a skeleton-sized spread around the stub's point), so
    that a rotation of the output frame shows in every axis; the transforms are under test, not the fits."""

    def fit(self, people, K, origin, options=None):
        spread = np.stack([np.linspace(-0.3, 0.3, 17), np.linspace(-0.9, 0.8, 17), np.cos(np.arange(17))], axis=1)
        return [dataclasses.replace(f, keypoints3d=(f.keypoints3d + 0.2 * spread).astype(np.float32))
                for f in super().fit(people, K, origin, options)]


def test_output_frame_odom_replays_with_the_recorded_tf(tmp_path):
    path, t0 = bag_with_tf(tmp_path, tf_until_s=2.0)
    in_odom = node_support.stub_replay(path, tmp_path / "out.mcap", fitter=SpreadStubFitter(),
                                       node_config=load_node_config(None, {"node": {"output_frame": "odom"}}))
    in_camera = node_support.stub_replay(node_support.fixture_bag("mcap").path, fitter=SpreadStubFitter())
    assert in_odom.drops == {} and in_odom.frames_published == in_camera.frames_published == 2
    T_velodyne_cam = node_support.node_config().extrinsic.T_lidar_cam()
    for odom, cam in zip(in_odom.frames, in_camera.frames, strict=True):
        assert odom.stamp_ns == cam.stamp_ns and odom.person_ids == cam.person_ids
        T = odom_to_velodyne(odom.stamp_ns, t0) @ T_velodyne_cam  # camera -> odom at the image's stamp
        expected = cam.keypoints3d @ T[:3, :3].T + T[:3, 3]
        np.testing.assert_allclose(odom.keypoints3d, expected, atol=2e-3)


def test_a_frame_after_the_recorded_tf_is_a_counted_drop(tmp_path):
    path, t0 = bag_with_tf(tmp_path, tf_until_s=0.55)  # the bag starts 0.5 s before its first frame
    summary = node_support.stub_replay(path, node_config=load_node_config(None, {"node": {"output_frame": "odom"}}))
    assert summary.frames_published == 1 and summary.drops == {"tf_timeout": 1}
