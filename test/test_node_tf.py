"""The live node's TF: lookups at the image's stamp with `extrinsic.tf_timeout_s` (tf2_ros faked: it is not
installable here), a frame TF cannot place at its stamp dropped and counted, and the pip-only path without
tf2_ros or tf2_msgs: the extrinsic parameters, said so in the log."""

from __future__ import annotations

import bag_fixture
import node_support
import pytest

from msg_adapters import stamp_to_ns

rclpy = pytest.importorskip("rclpy")


def _transform_stamped(T, parent: str, child: str):
    from geometry_msgs.msg import TransformStamped

    from smplify3d_ros.geometry import matrix_to_quaternion

    msg = TransformStamped()
    msg.header.frame_id, msg.child_frame_id = parent, child
    q, t = matrix_to_quaternion(T[:3, :3]), T[:3, 3]
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = map(float, t)
    r = msg.transform.rotation
    r.x, r.y, r.z, r.w = map(float, q)
    return msg


def _publish_nobody(recorder, stamp: float) -> None:
    bag = node_support.fixture_bag("mcap")
    recorder.publish_frame(node_support.bad_frame("no_people", recorder.factory, bag.camera, bag.frames[0], stamp))


def _count(node, key: str) -> int:
    return int(node._processor_values.get(key, 0))


def test_tf_is_looked_up_at_the_image_stamp_and_a_miss_is_a_counted_drop(monkeypatch):
    from rclpy.impl.rcutils_logger import RcutilsLogger

    infos: list[str] = []
    real_info = RcutilsLogger.info
    monkeypatch.setattr(RcutilsLogger, "info", lambda self, msg, **kw: (infos.append(msg), real_info(self, msg, **kw)))
    with node_support.fake_modules("tf2_ros"), node_support.running_node({"output_frame": "odom"}) as (node, recorder):
        import tf2_ros

        buffer = node._tf_buffer
        assert isinstance(buffer, tf2_ros.Buffer) and tf2_ros.FAKE
        ext = node.node_config.extrinsic
        buffer.transforms[(ext.camera_frame, bag_fixture.LIDAR_FRAME)] = _transform_stamped(
            ext.T_cam_lidar(), ext.camera_frame, bag_fixture.LIDAR_FRAME)
        buffer.failures["odom"] = tf2_ros.ExtrapolationException("Lookup would require extrapolation into the future")
        stamp = bag_fixture.T0 + 321.25
        _publish_nobody(recorder, stamp)
        assert node_support.wait_for(lambda: _count(node, "drop.tf_timeout") >= 1, 30.0), node._processor_values
        calls = {call[1]: call for call in buffer.calls}
        expected_ns = stamp_to_ns(stamp)  # the conversion the message factory applied
        for target in (ext.camera_frame, "odom"):
            _, _, source, time, timeout = calls[target]
            assert time.nanoseconds == expected_ns, "at the image's stamp, not the latest transform"
            assert timeout.nanoseconds == round(ext.tf_timeout_s * 1e9)
        # odometry catches up: the next frame is placed
        buffer.failures.clear()
        buffer.transforms[("odom", ext.camera_frame)] = _transform_stamped(ext.T_lidar_cam(), "odom", ext.camera_frame)
        _publish_nobody(recorder, stamp + 1.0)
        assert node_support.wait_for(lambda: _count(node, "frames_published") >= 1, 30.0)
        assert recorder.messages("/smplify3d/people")[-1].header.frame_id == "odom"
    assert any(line.startswith("tf2_msgs is not installed: the extrinsic parameters are not published")
               for line in infos)


def test_without_tf2_ros_the_extrinsic_parameters_are_used(monkeypatch):
    import sys

    from rclpy.impl.rcutils_logger import RcutilsLogger

    monkeypatch.setitem(sys.modules, "tf2_ros", None)  # as on a pip-only install
    infos: list[str] = []
    real_info = RcutilsLogger.info
    monkeypatch.setattr(RcutilsLogger, "info", lambda self, msg, **kw: (infos.append(msg), real_info(self, msg, **kw)))
    with node_support.running_node({}) as (node, recorder):
        assert node._tf_buffer is None and node.processor.transforms.lookup is None
        _publish_nobody(recorder, bag_fixture.T0 + 400.0)
        assert node_support.wait_for(lambda: _count(node, "frames_published") >= 1, 30.0)
    assert "tf2_ros is not installed: using the extrinsic parameters" in infos
