"""ROS4HRI messages: joint states in REP-103 axes, Skeleton2D out and in, the hri_msgs definitions the
package carries (registered with rosbags so that bags get them without hri_msgs installed)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msg_adapters import RclpyFactory, RosbagsFactory
from msg_adapters.factory import rclpy_available, to_plain
from msg_adapters.hri import (
    CANONICAL_FROM_REP103,
    HRI_TYPES,
    has_type,
    ids_list_msg,
    joint_angles,
    joint_state_msg,
    read_skeleton2d,
    rep103_rotation,
    skeleton2d_msg,
)
from smplify3d_ros.keypoints import KP

ROSBAGS = RosbagsFactory()


@pytest.mark.parametrize("canonical_axis, angle_index", [(0, 1), (1, 0), (2, 2)],
                         ids=["left_axis_is_pitch", "up_axis_is_yaw", "forward_axis_is_roll"])
def test_a_rotation_about_one_body_axis_is_one_joint_angle(canonical_axis, angle_index):
    rotvec = np.zeros(3)
    rotvec[canonical_axis] = 0.4
    angles = joint_angles(rotvec[None])[0]
    expected = np.zeros(3)
    expected[angle_index] = 0.4
    np.testing.assert_allclose(angles, expected, atol=1e-12)


def test_joint_angles_rebuild_the_rotation_as_a_yaw_pitch_roll_chain():
    pose = Rotation.random(19, random_state=3).as_rotvec() * 0.5
    angles = joint_angles(pose)
    C = CANONICAL_FROM_REP103
    for (yaw, pitch, roll), rotvec in zip(angles, pose, strict=True):
        chain = Rotation.from_euler("z", yaw) * Rotation.from_euler("y", pitch) * Rotation.from_euler("x", roll)
        np.testing.assert_allclose(C @ chain.as_matrix() @ C.T, Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-9)


def test_rep103_axes_of_a_body():
    R = rep103_rotation(np.zeros(3))
    np.testing.assert_array_equal(R[:, 0], [0, 0, 1])  # forward = canonical z
    np.testing.assert_array_equal(R[:, 1], [1, 0, 0])  # left = canonical x
    np.testing.assert_array_equal(R[:, 2], [0, 1, 0])  # up = canonical y
    assert np.linalg.det(R) == pytest.approx(1.0)


def test_joint_state_names_and_values():
    msg = joint_state_msg(["left_knee", "neck"], np.array([[0.5, 0, 0], [0, 0, 0]]), "b7", 3.5, ROSBAGS)
    assert list(msg.name) == ["left_knee_yaw_b7", "left_knee_pitch_b7", "left_knee_roll_b7",
                              "neck_yaw_b7", "neck_pitch_b7", "neck_roll_b7"]
    np.testing.assert_allclose(msg.position, [0, 0.5, 0, 0, 0, 0], atol=1e-12)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 500_000_000)


def test_skeleton2d_round_trip_and_neck():
    kp = np.zeros((17, 3))
    kp[:, 0], kp[:, 1], kp[:, 2] = np.arange(17) * 20.0, np.arange(17) * 10.0 + 5.0, 0.9
    kp[KP["left_ankle"]] = 0.0  # missing
    msg = skeleton2d_msg(kp, 640, 480, 1.0, "cam", ROSBAGS)
    assert len(msg.skeleton) == 18
    neck = msg.skeleton[1]
    shoulders = kp[[KP["left_shoulder"], KP["right_shoulder"]]]
    assert neck.x == pytest.approx(shoulders[:, 0].mean() / 640)
    assert neck.y == pytest.approx(shoulders[:, 1].mean() / 480)
    assert msg.skeleton[0].x == pytest.approx(0.0)
    assert msg.skeleton[2].x == pytest.approx(kp[KP["right_shoulder"], 0] / 640)
    assert msg.skeleton[13].c == 0.0, "LEFT_ANKLE missing"
    raw = ROSBAGS.typestore.serialize_cdr(msg, "hri_msgs/msg/Skeleton2D")
    back = read_skeleton2d(ROSBAGS.typestore.deserialize_cdr(raw, "hri_msgs/msg/Skeleton2D"), 640, 480)
    np.testing.assert_allclose(back, kp, atol=1e-3)


def test_read_skeleton2d_treats_non_finite_points_as_missing():
    msg = skeleton2d_msg(np.full((17, 3), 0.5) * [640, 480, 1], 640, 480, 0.0, "", ROSBAGS)
    msg.skeleton[0].x = float("nan")
    out = read_skeleton2d(msg, 640, 480)
    assert out[KP["nose"]].tolist() == [0.0, 0.0, 0.0] and out[KP["left_eye"], 2] == pytest.approx(0.5)
    msg.skeleton = msg.skeleton[:5]
    with pytest.raises(ValueError, match="5 points, expected 18"):
        read_skeleton2d(msg, 640, 480)


def test_the_carried_definitions_are_registered_and_serialize():
    store = ROSBAGS.typestore
    assert set(HRI_TYPES) <= set(store.types)
    fields = {name: [f for f, _ in store.fielddefs[name][1]] for name in HRI_TYPES}
    assert fields == {"hri_msgs/msg/NormalizedPointOfInterest2D": ["x", "y", "c"],
                      "hri_msgs/msg/Skeleton2D": ["header", "skeleton"], "hri_msgs/msg/IdsList": ["header", "ids"]}
    msg = ids_list_msg(["b1", "b4"], 2.0, "odom", ROSBAGS)
    back = store.deserialize_cdr(store.serialize_cdr(msg, "hri_msgs/msg/IdsList"), "hri_msgs/msg/IdsList")
    assert list(back.ids) == ["b1", "b4"] and back.header.frame_id == "odom"
    assert store.types["hri_msgs/msg/Skeleton2D"].LEFT_EAR == 16


@pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")
def test_has_type_says_what_the_runtime_has():
    assert has_type(ROSBAGS, "hri_msgs/msg/IdsList")
    rclpy_has = has_type(RclpyFactory(), "hri_msgs/msg/IdsList")
    try:
        import hri_msgs  # noqa: F401
    except ImportError:
        assert not rclpy_has
    else:
        assert rclpy_has
    a = joint_state_msg(["neck"], np.array([[0.1, 0.2, 0.3]]), "b1", 1.0, RclpyFactory())
    b = joint_state_msg(["neck"], np.array([[0.1, 0.2, 0.3]]), "b1", 1.0, ROSBAGS)
    assert to_plain(a) == to_plain(b)
