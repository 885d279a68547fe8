"""The per-frame step the node and replay share (`MessageProcessor`): bad input is a counted drop, never
an exception.

The fitting itself is replaced by a stub here (its own tests cover it); these tests are about the wiring:
conversion, people selection, ids, init bodies, transforms, outputs, counters and diagnostics.
"""

from __future__ import annotations

import json

import bag_fixture
import node_support
import numpy as np
import pytest

from msg_adapters import RosbagsFactory
from smplify3d_ros.config import load_config
from smplify3d_ros.runtime.config import load_node_config
from smplify3d_ros.runtime.messages import FrameMessages, to_frame
from smplify3d_ros.runtime.processor import MessageProcessor
from smplify3d_ros.runtime.stats import DiagnosticsReporter
from smplify3d_ros.runtime.transforms import Transforms, transform_fit
from smplify3d_ros.types import BodyFit, BodyParams, FitQuality

FACTORY = RosbagsFactory()


StubFitter = node_support.StubFitter


@pytest.fixture()
def frame():
    # People posed by the real body model, built once; the pipeline under test uses the stub fitter.
    return _frames()[0]


def _frames():
    if not hasattr(_frames, "cache"):
        _frames.cache = bag_fixture.make_frames(node_support.fitter().model,
                                                node_support.node_config().extrinsic.T_cam_lidar(), 2, 2)
    return _frames.cache


def pipeline(overrides=None, tracking: bool = False) -> MessageProcessor:
    """A processor with the stub fitter; without tracking unless asked (these tests are about the wiring:
    a tracker's warm starts would arrive as initial estimates)."""
    overrides = {**(overrides or {}), "tracking": {"enabled": tracking}}
    return MessageProcessor(load_config(overrides=overrides), load_node_config(overrides=overrides), FACTORY,
                            fitter=StubFitter())


def messages(msgs: dict) -> FrameMessages:
    return FrameMessages(msgs["camera_info"], msgs["points"], msgs["keypoints"], msgs.get("image"))


CAMERA = bag_fixture.fixture_camera()
T0 = bag_fixture.T0


def test_good_frame_fits_every_person_and_builds_all_outputs(frame):
    p = pipeline()
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert result.ok, result.message
    assert [f.person_id for f in result.fits] == [0, 1]
    assert {"markers", "joints", "body_points", "people", "bodies", "clearing_points"} <= set(result.outputs)
    people = p.fitter.calls[0]
    assert all(len(person.points) > 100 for person in people), "the LiDAR person extraction ran on the scan"
    doc = json.loads(result.outputs["bodies"].data)
    assert doc["stamp"] == {"sec": int(T0), "nanosec": 0}
    assert doc["frame_id"] == bag_fixture.CAMERA_FRAME
    assert result.outputs["markers"].markers[0].header.stamp.sec == int(T0)
    assert p.stats.frames_published == 1 and p.stats.people_fitted == 2
    assert {"convert", "extract", "fit", "outputs", "total"} <= set(result.latency)


def test_outputs_nobody_subscribes_to_are_not_built(frame):
    p = pipeline()
    p.skip_outputs = lambda: ["markers", "clearing_points"]  # the node's publish.lazy
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert result.ok, result.message
    assert {"joints", "body_points", "people", "bodies"} <= set(result.outputs)
    assert not {"markers", "clearing_points"} & set(result.outputs)


@pytest.mark.parametrize("kind", sorted(node_support.BAD_KINDS))
def test_bad_input_is_a_counted_drop(kind, frame):
    p = pipeline()
    first = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert first.ok
    stamp = T0 - 0.3 if kind == "time_backwards" else T0 + 0.1
    result = p.process(messages(node_support.bad_frame(kind, FACTORY, CAMERA, frame, stamp)))
    outcome, key = node_support.BAD_KINDS[kind]
    values = p.stats.values()
    if outcome == "drop":
        assert result.drop == key, result.message
        assert result.message
        assert not result.outputs
        assert p.stats.drops[key] == 1
        assert values[f"drop.{key}"] == 1
    else:
        assert result.ok and result.fits == []
        assert values[key] >= 1
        deletes = [m for m in result.outputs["markers"].markers if m.action == 2]
        assert {m.id for m in deletes} == {0, 1}, "people who vanished get DELETE markers"
    # the pipeline keeps working
    good = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0 + 0.2)))
    assert good.ok and len(good.fits) == 2


def test_duplicate_stamp_and_clock_reset(frame):
    p = pipeline()
    assert p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0))).ok
    assert p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0))).drop == "duplicate_stamp"
    back = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0 - 100.0)))
    assert back.ok, "a jump back beyond sync.time_reset_s is a clock reset, not a drop"
    assert p.stats.time_resets == 1


def test_people_selection_ids_and_limits(frame):
    p = pipeline({"people": {"max_people": 1}})
    kp = np.concatenate([frame.keypoints, frame.keypoints[:1], frame.keypoints[:1]])
    kp[2, :, 2] = 0.0  # no confident keypoint
    kp[3, 12:, 2] = 0.0  # only 12 confident keypoints: still enough
    msgs = node_support.frame_at(FACTORY, CAMERA, frame, T0)
    from msg_adapters import write_keypoints

    msgs["keypoints"] = write_keypoints(kp, np.array([-1, -1, 5, -1]), T0, bag_fixture.CAMERA_FRAME, FACTORY)
    result = p.process(messages(msgs))
    assert result.ok
    assert p.stats.people_dropped["few_keypoints"] == 1
    assert p.stats.people_dropped["max_people"] == 2
    assert len(result.fits) == 1
    # the largest keypoint box is kept (the nearer person, id assigned by the node)
    assert result.fits[0].person_id >= 0


def test_anonymous_people_get_free_ids_left_to_right(frame):
    p = pipeline()
    f = to_frame(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)), "coco17", p.transforms, "camera")
    import dataclasses

    f = dataclasses.replace(f, person_ids=np.array([-1, 0]))
    selected, _ = p.frames.select_people(f)
    assert selected.person_ids.tolist() == [1, 0]


def test_init_bodies_matched_by_stamp_and_id(frame):
    p = pipeline()
    body = {"id": 1, "model": "stub", "shape": [0.3], "root_orient": [0, 0, 0], "transl": [1.0, 2.0, 3.0],
            "pose": {"knee": [0.1, 0, 0]}}
    doc = {"schema": "smplify3d_ros/bodies", "version": 1, "stamp": {"sec": int(T0), "nanosec": 0},
           "frame_id": bag_fixture.CAMERA_FRAME, "bodies": [body]}
    assert p.add_init_bodies(json.dumps(doc))
    assert not p.add_init_bodies("{not json")
    assert p.stats.init_bodies_dropped["bad_document"] == 1
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    people = p.fitter.calls[-1]
    assert people[0].init is None and people[1].init is not None
    assert people[1].init.transl.tolist() == [1.0, 2.0, 3.0]
    assert result.fits[1].params.transl.tolist() == [1.0, 2.0, 3.0]
    assert p.stats.init_bodies_used == 1
    # a document for another stamp is not used
    later = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0 + 1.0)))
    assert later.ok and all(person.init is None for person in p.fitter.calls[-1])


def test_output_frame_lidar_moves_geometry(frame):
    p = pipeline({"node": {"output_frame": bag_fixture.LIDAR_FRAME}})
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert result.ok and result.frame_id == bag_fixture.LIDAR_FRAME
    cam = pipeline().process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    T = np.linalg.inv(node_support.node_config().extrinsic.T_cam_lidar())
    expected = cam.fits[0].vertices @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(result.fits[0].vertices, expected, atol=1e-5)
    assert result.outputs["joints"].header.frame_id == bag_fixture.LIDAR_FRAME


def test_output_frame_without_transform_is_a_drop(frame):
    p = pipeline({"node": {"output_frame": "map"}})
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert result.drop == "no_transform"


def test_transform_fit_is_rigid():
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    T[:3, 3] = [1.0, -2.0, 0.5]
    params = BodyParams("stub", np.zeros(1), np.zeros((1, 3)), np.array([0.1, 0.2, 0.3]), np.array([0.0, 1.0, 4.0]))
    fit = BodyFit(0, params, ["a"], np.random.default_rng(0).normal(size=(5, 3)).astype(np.float32),
                  np.zeros((17, 3), np.float32), np.zeros((1, 3), np.float32), FitQuality(0, 0, 0, [], True, 0))
    moved = transform_fit(fit, T)
    np.testing.assert_allclose(moved.vertices, fit.vertices @ T[:3, :3].T + T[:3, 3], atol=1e-5)
    np.testing.assert_allclose(moved.params.transl, T[:3, :3] @ params.transl + T[:3, 3], atol=1e-9)
    R = Rotation.from_rotvec(moved.params.root_orient).as_matrix()
    np.testing.assert_allclose(R, T[:3, :3] @ Rotation.from_rotvec(params.root_orient).as_matrix(), atol=1e-9)


def test_transforms_prefers_lookup_then_parameters():
    ext = node_support.node_config().extrinsic
    T = np.eye(4)
    T[0, 3] = 5.0
    found = Transforms(ext, lambda target, source, stamp: T if (target, source) == ("cam", "lidar") else None)
    np.testing.assert_array_equal(found.cam_from_lidar("cam", "lidar", None), T)
    np.testing.assert_allclose(found.cam_from_lidar("cam", "other", None), ext.T_cam_lidar())
    np.testing.assert_array_equal(Transforms(ext).cam_from_lidar("x", "x", None), np.eye(4))


def test_diagnostics_levels(frame):
    p = pipeline()
    reporter = DiagnosticsReporter("test")
    p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    ok = reporter.message(T0, p.stats.values(), FACTORY).status[0]
    assert ok.level == 0
    p.process(messages(node_support.bad_frame("empty_cloud", FACTORY, CAMERA, frame, T0 + 0.1)))
    warn = reporter.message(T0, p.stats.values(), FACTORY).status[0]
    assert warn.level == 1 and "1 frame(s) dropped" in warn.message
    values = {kv.key: kv.value for kv in warn.values}
    assert values["drop.empty_cloud"] == "1" and "latency_ms.fit.mean" in values
    assert reporter.message(T0, p.stats.values(), FACTORY).status[0].level == 0, "per period"


def test_fit_exception_is_a_counted_error(frame):
    p = pipeline()

    def boom(*args):
        raise RuntimeError("kaboom")

    p.fitter.fit = boom
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert result.drop == "fit_error" and "kaboom" in result.message
    assert DiagnosticsReporter("test").message(T0, p.stats.values(), FACTORY).status[0].level == 2


def test_unexpected_exception_is_an_internal_error_drop(frame):
    p = pipeline()

    def broken(*args):
        raise KeyError("surprise")

    p.outputs.build = broken
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert result.drop == "internal_error" and "surprise" in result.message and result.outputs == {}
    status = DiagnosticsReporter("test").message(T0, p.stats.values(), FACTORY).status[0]
    assert status.level == 2


def test_rate_limited_logging_works_with_the_rclpy_logger(frame):
    """rclpy's logger refuses two severities from one call site: each severity logs from its own line."""
    rclpy_logging = pytest.importorskip("rclpy.logging")
    p = MessageProcessor(node_support.config(), node_support.node_config(), FACTORY, fitter=StubFitter(),
                         log=rclpy_logging.get_logger("smplify3d_pipeline_test"))
    p.process(messages(node_support.bad_frame("out_of_image", FACTORY, CAMERA, frame, T0)))  # info
    p.process(messages(node_support.bad_frame("empty_cloud", FACTORY, CAMERA, frame, T0 + 0.1)))  # warning
    p.fitter.fit = lambda *a: (_ for _ in ()).throw(RuntimeError("x"))
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0 + 0.2)))  # error
    assert result.drop == "fit_error"
    assert p.stats.drops["internal_error"] == 0


def _init_doc(body: dict, stamp: float = T0) -> str:
    return json.dumps({"schema": "smplify3d_ros/bodies", "version": 1, "stamp": {"sec": int(stamp), "nanosec": 0},
                       "frame_id": bag_fixture.CAMERA_FRAME, "bodies": [body]})


@pytest.mark.parametrize("n_shape", [0, 100])
def test_init_bodies_with_another_shape_size_than_the_model_are_bad_documents(n_shape, frame):
    """Such a document used to be accepted and the frame then lost as a fit_error."""
    p = pipeline()
    body = {"id": 1, "model": "stub", "shape": [0.1] * n_shape, "root_orient": [0, 0, 0],
            "transl": [1.0, 2.0, 3.0], "pose": {"knee": [0.1, 0, 0]}}
    assert not p.add_init_bodies(_init_doc(body))
    assert p.stats.init_bodies_dropped["bad_document"] == 1
    result = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert result.ok and all(person.init is None for person in p.fitter.calls[-1])


class NonFiniteFitter(StubFitter):
    """Person 1's fit diverged: NaN translation and vertices (person 0 is fine)."""

    def fit(self, people, K, origin, options=None):
        fits = super().fit(people, K, origin, options)
        for fit in fits:
            if fit.person_id == 1:
                fit.params.transl = np.array([np.nan, 0.0, 1e308 * 10])
                fit.vertices = np.full_like(fit.vertices, np.nan)
                fit.flags.add("diverged")
        return fits


def _numbers(msg) -> list[float]:
    """Every float of a message, recursively (rosbags messages: dataclasses and numpy arrays)."""
    import dataclasses

    if isinstance(msg, np.ndarray):
        return msg.astype(np.float64).ravel().tolist() if msg.dtype.kind == "f" else []
    if isinstance(msg, float):
        return [msg]
    if isinstance(msg, (list, tuple)):
        return [x for item in msg for x in _numbers(item)]
    if dataclasses.is_dataclass(msg):
        return [x for f in dataclasses.fields(msg) for x in _numbers(getattr(msg, f.name))]
    return []


def test_a_non_finite_fit_is_withheld_and_counted_never_published(frame):
    p = MessageProcessor(node_support.config(), node_support.node_config(), FACTORY, fitter=NonFiniteFitter())
    first = p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0)))
    assert first.ok and [f.person_id for f in first.fits] == [0], "the finite person is published"
    assert p.stats.people_dropped["non_finite"] == 1
    assert p.stats.values()["people_dropped.non_finite"] == 1
    for name, msg in first.outputs.items():
        assert np.isfinite(_numbers(msg)).all(), name
    from msg_adapters import read_fields

    for name in ("joints", "body_points"):
        xyz = read_fields(first.outputs[name], ["x", "y", "z"])
        assert all(np.isfinite(c).all() for c in xyz.values()) and len(xyz["x"]) > 0, name
    assert len(first.outputs["people"].poses) == 1
    doc = json.loads(first.outputs["bodies"].data)
    assert [b["id"] for b in doc["bodies"]] == [0] and None not in doc["bodies"][0]["transl"]


def test_init_bodies_with_an_absurd_translation_are_refused(frame):
    """transl 1e308 used to reach the fit and publish NaN poses; the parser refuses it now."""
    p = pipeline()
    body = {"id": 1, "model": "stub", "shape": [0.1], "root_orient": [0, 0, 0], "transl": [1e308, 0, 3.0],
            "pose": {"knee": [0.1, 0, 0]}}
    assert not p.add_init_bodies(_init_doc(body))
    assert p.stats.init_bodies_dropped["bad_document"] == 1


def test_ignored_keypoint_points_are_counted_in_the_diagnostics(frame):
    from msg_adapters import make_pointcloud2

    p = pipeline()
    msgs = node_support.frame_at(FACTORY, CAMERA, frame, T0)
    kp = frame.keypoints[0]
    n = len(kp)
    u, v, score = kp[:, 0].astype(np.float32), kp[:, 1].astype(np.float32), kp[:, 2].astype(np.float32)
    joint = np.arange(n, dtype=np.uint16)
    u, v, score, joint = (np.append(a, x) for a, x in ((u, 1.0), (v, 1.0), (score, 0.9), (joint, 99)))
    u[3], score[4] = np.nan, np.inf  # a NaN position, an infinite confidence
    msgs["keypoints"] = make_pointcloud2(T0, bag_fixture.CAMERA_FRAME, {
        "u": u, "v": v, "score": score, "person": np.zeros(len(u), np.int32), "joint": joint.astype(np.uint16)},
        FACTORY)
    result = p.process(messages(msgs))
    assert result.ok
    values = p.stats.values()
    assert values["keypoints_ignored.out_of_format"] == 1
    assert values["keypoints_ignored.non_finite"] == 1
    assert values["keypoints_ignored.bad_score"] == 1
    people = p.fitter.calls[-1]
    assert people[0].keypoints[4, 2] == 0.0, "an infinite score is no confidence"
    status = DiagnosticsReporter("test").message(T0, values, FACTORY).status[0]
    keys = {kv.key for kv in status.values}
    assert {"keypoints_ignored.out_of_format", "keypoints_ignored.non_finite"} <= keys


def test_tracking_keeps_ids_and_warm_starts_tracked_people(frame):
    """With tracking, anonymous people get their track's id frame after frame, their next fit starts from
    the last one (a warm start), velocity comes with every fit after the first, and a clock reset ends the
    tracks."""
    import dataclasses

    p = pipeline(tracking=True)
    anonymous = dataclasses.replace(frame, keypoints=frame.keypoints)
    ids = []
    for k in range(3):
        msgs = node_support.frame_at(FACTORY, CAMERA, anonymous, T0 + 0.1 * k)
        from msg_adapters import write_keypoints

        msgs["keypoints"] = write_keypoints(frame.keypoints, np.array([-1, -1]), T0 + 0.1 * k,
                                            bag_fixture.CAMERA_FRAME, FACTORY)
        result = p.process(messages(msgs))
        assert result.ok
        ids.append(sorted(f.person_id for f in result.fits))
    assert ids[0] == ids[1] == ids[2] and len(ids[0]) == 2
    people = p.fitter.calls[-1]
    assert all(person.init is not None for person in people), "tracked people start from their last fit"
    assert all(f.velocity is not None and "warm_start" in f.flags for f in result.fits)
    values = p.stats.values()
    assert values["tracking.fits_cold"] == 2 and values["tracking.fits_warm"] == 4
    p.process(messages(node_support.frame_at(FACTORY, CAMERA, frame, T0 - 100.0)))  # a clock reset
    assert p.stats.values()["tracking.tracks_ended"] == 2
