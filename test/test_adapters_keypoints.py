"""Keypoint encoding: formats, person grouping, malformed points, both runtimes."""

from __future__ import annotations

import numpy as np
import pytest

from msg_adapters.factory import RclpyFactory, RosbagsFactory, rclpy_available, to_plain
from msg_adapters.keypoints import (
    KEYPOINT_FORMATS,
    KeypointError,
    KeypointFormat,
    get_keypoint_format,
    read_keypoints,
    write_keypoints,
)
from msg_adapters.pointcloud2 import make_pointcloud2
from smplify3d_ros.keypoints import COCO17_NAMES, KP

needs_rclpy = pytest.mark.skipif(not rclpy_available(), reason="rclpy not installed")
FACTORIES = [pytest.param(RosbagsFactory(), id="rosbags"),
             pytest.param(RclpyFactory(), id="rclpy", marks=needs_rclpy)]


def cloud(points, factory=None, fields=("u", "v", "score", "person", "joint"), dtypes=None):
    """Keypoint cloud from rows (u, v, score, person, joint), in the given order."""
    dtypes = dtypes or {"u": np.float32, "v": np.float32, "score": np.float32, "person": np.int32,
                        "joint": np.uint16}
    rows = np.array(points, dtype=np.float64).reshape(-1, 5)
    index = {"u": 0, "v": 1, "score": 2, "person": 3, "joint": 4}
    cols = {name: rows[:, index[name]].astype(dtypes[name]) for name in fields}
    return make_pointcloud2(4.0, "cam", cols, factory or RosbagsFactory())


def person_rows(pid, joints, base=100.0, score=0.9):
    return [(base + j, 2 * base + j, score, pid, j) for j in joints]


def test_format_tables():
    sizes = {"coco17": 17, "body25": 25, "halpe26": 26, "openpose18": 18, "rep155": 18}
    assert {n: f.num_joints for n, f in KEYPOINT_FORMATS.items()} == sizes
    for fmt in KEYPOINT_FORMATS.values():
        assert (fmt.from_coco >= 0).all(), f"{fmt.name} lacks a COCO joint"
        np.testing.assert_array_equal(fmt.to_coco[fmt.from_coco], np.arange(17))
    body25 = KEYPOINT_FORMATS["body25"]
    assert body25.joints[1] == ("Neck", None) and body25.to_coco[8] == -1  # MidHip
    assert body25.to_coco[9] == KP["right_hip"] and body25.to_coco[12] == KP["left_hip"]
    assert KEYPOINT_FORMATS["halpe26"].to_coco[:17].tolist() == list(range(17))
    # OpenPose COCO-18 and REP-155 differ only in the eye/ear order.
    op, rep = KEYPOINT_FORMATS["openpose18"], KEYPOINT_FORMATS["rep155"]
    assert op.to_coco[14] == KP["right_eye"] and rep.to_coco[14] == KP["left_eye"]
    assert op.to_coco[:14].tolist() == rep.to_coco[:14].tolist()
    assert op.to_coco[16] == KP["right_ear"] and rep.to_coco[17] == KP["right_ear"]


def test_unknown_format_lists_known_ones():
    with pytest.raises(KeypointError, match="unknown keypoint format 'mpii'; known: coco17, body25"):
        get_keypoint_format("mpii")
    assert get_keypoint_format("BODY25").name == "body25"


def test_format_table_is_validated():
    with pytest.raises(KeypointError, match="unknown COCO name 'neck'"):
        KeypointFormat("bad", (("Neck", "neck"),))
    with pytest.raises(KeypointError, match="'nose' is mapped twice"):
        KeypointFormat("bad", (("a", "nose"), ("b", "nose")))


@pytest.mark.parametrize("factory", FACTORIES)
@pytest.mark.parametrize("fmt", list(KEYPOINT_FORMATS))
def test_write_read_roundtrip(factory, fmt):
    rng = np.random.default_rng(1)
    kp = np.c_[rng.uniform(0, 640, (3 * 17, 2)), rng.uniform(0, 1, (3 * 17, 1))].reshape(3, 17, 3)
    kp[1, 4] = 0.0  # a missing joint
    ids = np.array([7, -1, -1])
    msg = write_keypoints(kp, ids, 2.5, "cam", factory, keypoint_format=fmt)
    assert msg.width == 3 * 17 and msg.header.frame_id == "cam"
    assert [f.name for f in msg.fields] == ["u", "v", "score", "person", "joint"]
    out = read_keypoints(msg, fmt)
    np.testing.assert_allclose(out.keypoints, kp, atol=1e-4)  # float32 on the wire
    assert out.person_ids.tolist() == [7, -1, -1] and out.person_ids.dtype == np.int64
    assert (out.dropped_joints, out.duplicate_joints, out.nan_points) == (0, 0, 0)
    assert out.stamp_ns == 2_500_000_000 and out.frame_id == "cam"


@needs_rclpy
def test_write_same_message_from_both_factories():
    kp = np.ones((1, 17, 3)) * 0.5
    assert to_plain(write_keypoints(kp, [3], 1.0, "c", RclpyFactory(), "body25")) == to_plain(
        write_keypoints(kp, [3], 1.0, "c", RosbagsFactory(), "body25"))


def test_body25_message_maps_to_coco():
    rows = [(100.0 + j, 200.0 + j, 0.5, 4, j) for j in range(25)]
    out = read_keypoints(cloud(rows), "body25")
    kp = out.keypoints[0]
    assert kp[KP["nose"], 0] == 100.0
    assert kp[KP["right_shoulder"], 0] == 102.0 and kp[KP["left_shoulder"], 0] == 105.0
    assert kp[KP["right_hip"], 0] == 109.0 and kp[KP["left_ankle"], 0] == 114.0
    assert kp[KP["right_eye"], 0] == 115.0 and kp[KP["left_ear"], 0] == 118.0
    assert (kp[:, 2] == 0.5).all() and out.dropped_joints == 0  # neck, mid-hip, feet: ignored, not dropped


def test_rep155_eyes():
    rows = [(10.0 * j, 0.0, 1.0, 0, j) for j in (14, 15, 16, 17)]
    rep = read_keypoints(cloud(rows), "rep155").keypoints[0]
    op = read_keypoints(cloud(rows), "openpose18").keypoints[0]
    assert rep[KP["left_eye"], 0] == 140.0 and op[KP["right_eye"], 0] == 140.0
    assert rep[KP["right_ear"], 0] == 170.0 and op[KP["left_ear"], 0] == 170.0


def test_people_with_ids_are_grouped_wherever_their_points_are():
    rows = person_rows(5, [0, 1, 2], base=100) + person_rows(7, [0, 1], base=300) + person_rows(5, [3], 100)
    out = read_keypoints(cloud(rows))
    assert out.person_ids.tolist() == [5, 7]
    assert out.keypoints[0, 3].tolist() == pytest.approx([103.0, 203.0, 0.9])
    assert (out.keypoints[1, 2:, 2] == 0).all() and out.keypoints[1, 1, 0] == 301.0


def test_anonymous_people_split_on_repeated_joint():
    rows = person_rows(-1, range(17), base=100) + person_rows(-1, range(17), base=400)
    out = read_keypoints(cloud(rows))
    assert out.person_ids.tolist() == [-1, -1]
    assert out.keypoints[0, :, 0].tolist() == [100.0 + j for j in range(17)]
    assert out.keypoints[1, :, 0].tolist() == [400.0 + j for j in range(17)]
    # Partial people: a run 0..5 then 3..8 is two people, the second starting at the repeated joint 3.
    out = read_keypoints(cloud(person_rows(-1, range(6), 100) + person_rows(-1, range(3, 9), 400)))
    assert len(out) == 2 and out.keypoints[1, 3, 0] == 403.0 and out.keypoints[0, 6, 2] == 0.0


def test_anonymous_run_ends_at_a_point_with_an_id():
    rows = person_rows(-1, [0, 1, 2], 100) + person_rows(9, range(17), 300) + person_rows(-1, [3, 4], 500)
    out = read_keypoints(cloud(rows))
    assert out.person_ids.tolist() == [-1, 9, -1]
    assert out.keypoints[2, 3, 0] == 503.0 and out.keypoints[0, 3, 2] == 0.0


def test_negative_ids_below_minus_one_read_as_anonymous():
    out = read_keypoints(cloud(person_rows(-3, [0, 1])))
    assert out.person_ids.tolist() == [-1]


def test_bad_points_are_dropped_or_zeroed_and_counted():
    rows = [
        (10.0, 20.0, 1.5, 1, KP["nose"]),  # score clipped to 1
        (np.nan, 20.0, 0.8, 1, KP["left_eye"]),  # NaN -> missing
        (11.0, np.inf, 0.8, 1, KP["right_eye"]),  # inf -> missing
        (12.0, 22.0, -0.3, 1, KP["left_ear"]),  # score clipped to 0
        (13.0, 23.0, np.nan, 1, KP["right_ear"]),  # NaN score -> 0
        (14.0, 24.0, 0.7, 1, 17),  # outside COCO-17: dropped
        (15.0, 25.0, 0.7, 1, 60000),  # outside: dropped
    ]
    out = read_keypoints(cloud(rows))
    kp = out.keypoints[0]
    assert kp[KP["nose"]].tolist() == [10.0, 20.0, 1.0]
    assert kp[KP["left_eye"]].tolist() == [0.0, 0.0, 0.0] and kp[KP["right_eye"]].tolist() == [0.0, 0.0, 0.0]
    assert kp[KP["left_ear"], 2] == 0.0 and kp[KP["right_ear"], 2] == 0.0 and kp[KP["right_ear"], 0] == 13.0
    assert (out.dropped_joints, out.nan_points, out.duplicate_joints) == (2, 2, 0)
    assert np.isfinite(out.keypoints).all()


def test_duplicate_joint_keeps_highest_score():
    rows = [(1.0, 1.0, 0.3, 2, 0), (2.0, 2.0, 0.9, 2, 0), (3.0, 3.0, 0.5, 2, 0)]
    out = read_keypoints(cloud(rows))
    assert out.keypoints[0, 0].tolist() == pytest.approx([2.0, 2.0, 0.9])
    assert out.duplicate_joints == 2


@pytest.mark.parametrize("factory", FACTORIES)
def test_empty_cloud_is_no_person(factory):
    out = read_keypoints(write_keypoints(np.zeros((0, 17, 3)), [], 1.0, "cam", factory))
    assert out.keypoints.shape == (0, 17, 3) and out.person_ids.shape == (0,) and len(out) == 0
    assert len(read_keypoints(factory.make("sensor_msgs/msg/PointCloud2"))) == 0


def test_optional_fields_and_other_integer_types():
    rows = person_rows(-1, [0, 5]) + person_rows(-1, [0])
    out = read_keypoints(cloud(rows, fields=("u", "v", "joint")))  # no score, no person
    assert out.person_ids.tolist() == [-1, -1] and out.keypoints[0, 5].tolist() == [105.0, 205.0, 1.0]
    dtypes = {"u": np.float64, "v": np.float64, "score": np.float32, "person": np.int16, "joint": np.int32}
    out = read_keypoints(cloud(person_rows(3, [1, 2]), dtypes=dtypes))
    assert out.person_ids.tolist() == [3] and out.keypoints[0, 2, 0] == 102.0


@pytest.mark.parametrize("fields,dtypes,match", [
    (("v", "score", "person", "joint"), None, "no field 'u'"),
    (("u", "v", "score", "person"), None, "no field 'joint'"),
    (("u", "v", "score", "person", "joint"),
     {"u": np.float32, "v": np.float32, "score": np.float32, "person": np.int32, "joint": np.float32},
     "'joint' must have an integer datatype"),
    (("u", "v", "score", "person", "joint"),
     {"u": np.float32, "v": np.float32, "score": np.float32, "person": np.float32, "joint": np.uint16},
     "'person' must have an integer datatype"),
])
def test_malformed_keypoint_clouds(fields, dtypes, match):
    with pytest.raises(KeypointError, match=match):
        read_keypoints(cloud(person_rows(1, [0, 1]), fields=fields, dtypes=dtypes))


def test_corrupt_layout_is_a_keypoint_error():
    msg = cloud(person_rows(1, [0, 1]))
    msg.data = msg.data[:-3]
    with pytest.raises(KeypointError, match="keypoint cloud: data has"):
        read_keypoints(msg)
    assert issubclass(KeypointError, ValueError)


@pytest.mark.parametrize("kp,ids,match", [
    (np.zeros((2, 16, 3)), [1, 2], r"must be \(P, 17, 3\)"),
    (np.zeros((2, 17, 3)), [1], "2 keypoint sets but 1 person ids"),
    (np.zeros((1, 17, 3)), [-2], "person ids must be integers in"),
    (np.zeros((1, 17, 3)), [2**31], "person ids must be integers in"),
    (np.zeros((1, 17, 3)), [1.5], "person ids must be integers in"),
])
def test_write_keypoints_validates(kp, ids, match):
    with pytest.raises(KeypointError, match=match):
        write_keypoints(kp, ids, 0.0, "c", RosbagsFactory())


def test_write_body25_omits_joints_without_coco_counterpart():
    msg = write_keypoints(np.ones((1, 17, 3)), [0], 0.0, "c", RosbagsFactory(), "body25")
    joints = np.frombuffer(bytes(msg.data), np.uint8).reshape(msg.width, msg.point_step)[:, 16:18]
    joints = joints.copy().view("<u2").ravel().tolist()
    assert 1 not in joints and 8 not in joints and len(joints) == 17 and max(joints) == 18
    assert len(COCO17_NAMES) == 17
