"""The live node's ROS4HRI outputs: per-body joint_states / position / velocity under /humans/bodies (REP-155
names), said-so in the log when hri_msgs or tf2_msgs is missing, and per-body publishers removed once a
body has been gone for `publish.hri_forget_after_s`."""

from __future__ import annotations

import time

import bag_fixture
import node_support
import pytest

rclpy = pytest.importorskip("rclpy")


def test_per_body_topics_and_their_lifetime(monkeypatch):
    from rclpy.impl.rcutils_logger import RcutilsLogger

    infos: list[str] = []
    real_info = RcutilsLogger.info
    monkeypatch.setattr(RcutilsLogger, "info", lambda self, msg, **kw: (infos.append(msg), real_info(self, msg, **kw)))
    bag = node_support.fixture_bag("mcap")
    frame = bag.frames[0]
    ids = [f"b{p.person_id}" for p in frame.people]
    got: dict[str, list] = {}
    with node_support.running_node({"publish.hri_forget_after_s": 1.0}) as (node, recorder):
        f = recorder.factory
        for bid in ids:
            for leaf, t in (("joint_states", "sensor_msgs/msg/JointState"),
                            ("position", "geometry_msgs/msg/PointStamped"),
                            ("velocity", "geometry_msgs/msg/TwistStamped")):
                topic = f"/humans/bodies/{bid}/{leaf}"
                recorder.node.create_subscription(f.message_class(t), topic,
                                                  lambda m, topic=topic: got.setdefault(topic, []).append(m), 10)
        t = bag_fixture.T0 + 700.0
        for k in range(2):  # two frames of the same people, the second after the first is out
            recorder.publish_frame(node_support.frame_at(f, bag.camera, frame, t + 0.1 * k))
            assert node_support.wait_for(lambda k=k: recorder.count("/smplify3d/bodies") >= k + 1, 180.0)
        assert node_support.wait_for(lambda: all(len(got.get(f"/humans/bodies/{b}/velocity", [])) >= 1 for b in ids),
                                     10.0), sorted(got)
        for bid in ids:
            js = got[f"/humans/bodies/{bid}/joint_states"][-1]
            assert len(js.name) == 3 * 19 and js.name[0] == f"left_hip_yaw_{bid}"
            assert got[f"/humans/bodies/{bid}/position"][-1].header.frame_id == bag_fixture.CAMERA_FRAME
        # the people leave: once they have been gone hri_forget_after_s (1 s), the next frame removes their
        # publishers
        recorder.publish_frame(node_support.bad_frame("no_people", f, bag.camera, frame, t + 1.0))
        assert node_support.wait_for(lambda: recorder.count("/smplify3d/bodies") >= 3, 60.0)
        assert node.count_publishers(f"/humans/bodies/{ids[0]}/position") == 1, "not yet: gone for < 1 s"
        time.sleep(1.2)
        recorder.publish_frame(node_support.bad_frame("no_people", f, bag.camera, frame, t + 2.0))
        assert node_support.wait_for(lambda: recorder.count("/smplify3d/bodies") >= 4, 60.0)
        assert node_support.wait_for(lambda: node.count_publishers(f"/humans/bodies/{ids[0]}/position") == 0, 10.0)
        assert not any(topic.startswith(f"/humans/bodies/{ids[0]}/") for topic in node._topic_pubs.topics())
    assert any(line.startswith("hri_msgs (ROS4HRI) is not installed: ") for line in infos)
    assert "tf2_msgs is not installed: no body_<id> frames on /tf" in infos


def test_skeleton2d_keypoint_input_needs_hri_msgs():
    pytest.importorskip("rclpy")
    try:
        import hri_msgs  # noqa: F401
    except ImportError:
        pass
    else:
        pytest.skip("hri_msgs is installed")
    from smplify3d_ros.config import ConfigError
    from smplify3d_ros.node import create_node

    node_support.isolate_ros_graph()
    rclpy.init()
    try:
        with pytest.raises(ConfigError, match="keypoint_input skeleton2d needs hri_msgs"):
            create_node({"keypoint_input": "skeleton2d"}, fitter=node_support.fitter())
    finally:
        rclpy.try_shutdown()
