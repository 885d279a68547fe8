"""The ROS4HRI outputs of a frame (runtime/outputs.py): per-body topics under /humans/bodies for tracked
people only, velocity from consecutive fits of one id (restarted on gaps, a tracker's own kept), body
frames on /tf when asked, the clearing fan; and a replay's bag holding them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msg_adapters import RosbagsFactory
from msg_adapters.outputs import clearing_points
from smplify3d_ros.runtime.config import load_node_config
from smplify3d_ros.runtime.outputs import HriSettings, OutputBuilder, VelocityEstimator, output_topic, output_type
from smplify3d_ros.types import BodyFit, BodyParams, CameraModel, FitQuality

F = RosbagsFactory()
S = 1_000_000_000
T0 = 1_700_000_000 * S


def fit_at(pid: int, x: float, velocity=None) -> BodyFit:
    kp = np.zeros((17, 3), np.float32)
    kp[:, 0] = x
    params = BodyParams("anny", np.full(3, 0.5), np.zeros((2, 3)), np.array([0.0, 0.3, 0.0]), np.array([x, 0, 4.0]))
    return BodyFit(pid, params, ["neck", "head"], np.zeros((10, 3), np.float32), kp, np.zeros((2, 3), np.float32),
                   FitQuality(1.0, 0.01, 10, [], True, 0.5), velocity=velocity)


def builder(**publish) -> OutputBuilder:
    pub = dataclasses.replace(load_node_config().publish, markers=False, **publish)
    return OutputBuilder(pub, np.zeros((0, 3), np.int64), F, HriSettings("/humans/bodies"))


def test_velocity_from_consecutive_fits_restarts_on_gaps_and_keeps_a_trackers():
    v = VelocityEstimator(max_gap_s=0.5)
    assert v.update([fit_at(3, 0.0)], T0, "odom")[0].velocity is None, "first sight: unknown"
    np.testing.assert_allclose(v.update([fit_at(3, 0.12)], T0 + S // 10, "odom")[0].velocity, [1.2, 0, 0])
    assert v.update([fit_at(3, 0.5)], T0 + S, "odom")[0].velocity is None, "0.9 s gap: restarted"
    assert v.update([fit_at(3, 0.6)], T0 + S + S // 10, "camera")[0].velocity is None, "frame changed"
    tracker = np.array([0.0, 0.5, 0.0])
    np.testing.assert_array_equal(v.update([fit_at(3, 0.7, tracker)], T0 + S + S // 5, "camera")[0].velocity,
                                  tracker)
    assert v.update([fit_at(-1, 0.0)], T0 + 2 * S, "camera")[0].velocity is None, "no id: no history"
    assert set(v._last) == set(), "bodies gone longer than a gap are forgotten"


def test_per_body_topics_for_tracked_people_and_the_tracked_list():
    b = builder()
    b.hri.tf_frames = True
    b.build([fit_at(4, 0.0), fit_at(-1, 1.0)], T0, "odom")
    out = b.build([fit_at(4, 0.05), fit_at(-1, 1.0)], T0 + S // 10, "odom")
    per_body = sorted(k for k in out if k.startswith("/humans/bodies/b"))
    assert per_body == ["/humans/bodies/b4/joint_states", "/humans/bodies/b4/position", "/humans/bodies/b4/velocity"]
    assert list(out["/humans/bodies/tracked"].ids) == ["b4"]
    assert out["/humans/bodies/b4/velocity"].twist.linear.x == pytest.approx(0.5)
    assert out["/humans/bodies/b4/position"].header.frame_id == "odom"
    (t,) = out["/tf"].transforms
    assert (t.header.frame_id, t.child_frame_id) == ("odom", "body_b4")
    q = t.transform.rotation
    forward = Rotation.from_quat([q.x, q.y, q.z, q.w]).apply([1.0, 0.0, 0.0])
    np.testing.assert_allclose(forward, Rotation.from_rotvec([0, 0.3, 0]).apply([0, 0, 1.0]), atol=1e-9)
    for name, msg in out.items():  # every output serializes as the type its topic is recorded with
        F.typestore.serialize_cdr(msg, output_type(name))
        assert output_topic(name).startswith("/")


def test_no_hri_outputs_when_switched_off_and_no_body_frames_unless_asked():
    assert not any(k.startswith("/") for k in builder(hri=False).build([fit_at(4, 0.0)], T0, "odom"))
    assert "/tf" not in builder().build([fit_at(4, 0.0)], T0, "odom")


@pytest.mark.parametrize("view, span", [("camera", (-np.pi / 4, np.pi / 4)), ("full", (-np.pi, np.pi))])
def test_the_clearing_fan_spans_the_view_without_gaps(view, span):
    K = np.array([[320.0, 0, 320.0], [0, 320.0, 240.0], [0, 0, 1]])
    fan = clearing_points(CameraModel(K, 640, 480), range_m=6.0, resolution_m=0.05, view=view)
    assert np.allclose(np.linalg.norm(fan, axis=1), 12.0, atol=1e-5) and np.all(fan[:, 1] == 0.0)
    angles = np.arctan2(fan[:, 0], fan[:, 2])
    assert angles[0] == pytest.approx(span[0]) and abs(angles[-1]) == pytest.approx(abs(span[1]))
    assert np.max(np.linalg.norm(np.diff(fan, axis=0), axis=1)) <= 0.025 + 1e-6


def test_a_replayed_bag_holds_the_hri_topics():
    import node_support
    from rosbags.highlevel import AnyReader

    bag = node_support.fixture_bag("mcap")
    ids = [f"b{p.person_id}" for p in bag.frames[0].people]
    out = node_support.workdir() / "replayed_mcap.mcap"
    node_support.replayed("mcap")
    topics: dict[str, list] = {}
    with AnyReader([out]) as reader:  # types from the bag's own definitions, as Foxglove or ros2 bag read it
        for conn, _, raw in reader.messages():
            if conn.topic.startswith("/humans/") or conn.topic == "/smplify3d/clearing_points":
                topics.setdefault(conn.topic, []).append(reader.deserialize(raw, conn.msgtype))
    assert [list(m.ids) for m in topics["/humans/bodies/tracked"]] == [ids, ids]
    for bid in ids:
        assert len(topics[f"/humans/bodies/{bid}/skeleton2d"]) == 2
        assert len(topics[f"/humans/bodies/{bid}/joint_states"][0].name) == 3 * 19
        assert len(topics[f"/humans/bodies/{bid}/velocity"]) == 1, "from the second frame on"
        (p0, p1) = topics[f"/humans/bodies/{bid}/position"]
        v = topics[f"/humans/bodies/{bid}/velocity"][0].twist.linear
        dt = (p1.header.stamp.sec - p0.header.stamp.sec) + (p1.header.stamp.nanosec - p0.header.stamp.nanosec) * 1e-9
        # the tracker's filtered velocity: the finite difference's direction, shrunk towards rest after two
        # frames (its prior on a new track's speed)
        finite_difference = (p1.point.x - p0.point.x) / dt
        assert 0.0 < v.x / finite_difference <= 1.0
    assert len(topics["/smplify3d/clearing_points"]) == 2
