"""One frame path: the live node, the replay, `fit_frame` and the bench run the same frame logic.

The live test publishes a bundled recording (bags/walk_sqlite3, else the test fixture) through rclpy at its
recorded timing into a running node whose queue is longer than the bag (people are tracked across frames,
so the node must see every frame the replay sees); every frame it publishes must be what
`smplify3d replay` computes for that frame, byte for byte (ids and velocities included), with either
synchronizer."""

from __future__ import annotations

import importlib.util
import json
import sys
import time
from pathlib import Path

import node_support
import pytest

from msg_adapters import read_fields

FAKES = Path(__file__).resolve().parent / "fakes"
SYNCHRONIZERS = ["builtin", "message_filters"]


@pytest.fixture()
def synchronizer(request, monkeypatch):
    """`builtin`, or `message_filters`: the real package when installed, else the test stand-in."""
    if request.param == "message_filters" and importlib.util.find_spec("message_filters") is None:
        monkeypatch.syspath_prepend(str(FAKES))
        monkeypatch.delitem(sys.modules, "message_filters", raising=False)
    return request.param


def bodies_documents(path) -> dict[int, dict]:
    """stamp ns -> the `/smplify3d/bodies` document of a replay's output bag."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    out = {}
    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic == "/smplify3d/bodies"]
        for conn, _, raw in reader.messages(connections=conns):
            doc = json.loads(store.deserialize_cdr(raw, conn.msgtype).data)
            out[doc["stamp"]["sec"] * 1_000_000_000 + doc["stamp"]["nanosec"]] = doc
    return out


@pytest.mark.parametrize("synchronizer", SYNCHRONIZERS, indirect=True)
def test_node_and_replay_publish_identical_bodies(synchronizer, tmp_path):
    pytest.importorskip("rclpy")
    from smplify3d_ros.replay import replay_bag
    from smplify3d_ros.runtime.config import load_node_config

    use_mf = synchronizer == "message_filters"
    path = node_support.live_bag()
    node_config = load_node_config(overrides={"node": {"sync": {"use_message_filters": use_mf}}})
    out = tmp_path / "replayed.mcap"
    summary = replay_bag(path, out, progress=False, config=node_support.config(), node_config=node_config,
                         fitter=node_support.fitter())
    replayed = bodies_documents(out)
    assert summary.frames_published == summary.frames_synced == len(replayed) >= 2

    parameters = {"sync.use_message_filters": use_mf, "worker_queue_size": 100, "diagnostics_period_s": 0.25}
    with node_support.running_node(parameters) as (node, recorder):
        assert type(node.sync).__name__ == ("MessageFiltersSync" if use_mf else "ApproximateTimeSync")
        sent = node_support.publish_bag_at_recorded_timing(path, recorder)
        last = sent["image"][-1]

        def published() -> list[dict]:
            return [json.loads(m.data) for m in recorder.messages("/smplify3d/bodies")]

        assert node_support.wait_for(lambda: any(_stamp(d) == last for d in published()), 300.0), \
            recorder.last_diagnostics()
        n = len(published())
        assert node_support.wait_for(lambda: min(recorder.count(t) for t in (
            "/smplify3d/markers", "/smplify3d/joints", "/smplify3d/people")) >= n, 30.0)
        time.sleep(0.6)  # one more diagnostics period
        diagnostics, live = recorder.last_diagnostics(), published()
        markers, joints, people = (recorder.messages(f"/smplify3d/{t}") for t in ("markers", "joints", "people"))

    n_frames = len(sent["image"])
    assert n_frames == summary.frames_synced == len(live)
    for doc in live:  # the replay's document of the same frame, to the byte
        assert doc == replayed[_stamp(doc)], f"frame {_stamp(doc)}: the node's bodies differ from the replay's"
    assert all(body["model"] == "anny" for doc in live for body in doc["bodies"])
    _check_other_outputs(live, markers, joints, people)
    # diagnostics: every frame synchronized and fitted; the same sync.* keys with either synchronizer
    assert {k for k in diagnostics if k.startswith("sync.")} == set(summary.sync)
    assert int(diagnostics["sync.matched"]) == summary.sync["sync.matched"] == n_frames
    assert int(diagnostics["frames_published"]) == len(live)
    assert int(diagnostics["frames_published"]) + int(diagnostics["queue.dropped_stale"]) == n_frames
    assert diagnostics["worker_errors"] == "0" and "drop.internal_error" not in diagnostics


def _stamp(doc: dict) -> int:
    return doc["stamp"]["sec"] * 1_000_000_000 + doc["stamp"]["nanosec"]


def _check_other_outputs(bodies: list[dict], markers: list, joints: list, people: list) -> None:
    """Markers (a mesh, a skeleton and a label per person, the image's stamp), joints (17 per person with
    the person ids) and people (one pose per body) of each published frame."""
    for array, cloud, poses, doc in zip(markers, joints, people, bodies, strict=True):
        ids = {b["id"] for b in doc["bodies"]}
        meshes = {m.id: m for m in array.markers if m.ns == "mesh" and m.action == 0}
        assert set(meshes) == ids
        assert all(m.type == 11 and len(m.points) % 3 == 0 and len(m.points) > 1000 for m in meshes.values())
        assert {m.ns for m in array.markers if m.action == 0} == {"mesh", "skeleton", "label"}
        header = array.markers[0].header
        assert (header.stamp.sec, header.stamp.nanosec) == (doc["stamp"]["sec"], doc["stamp"]["nanosec"])
        fields = read_fields(cloud, ["person", "joint"])
        assert sorted(set(fields["person"].tolist())) == sorted(ids)
        assert len(fields["joint"]) == 17 * len(doc["bodies"])
        assert len(poses.poses) == len(doc["bodies"])


def test_fit_frame_runs_the_frame_path_of_the_drivers():
    """`fit_frame(Frame)` selects people as the drivers do and gives the processor's fits for a frame."""
    import bag_fixture
    import numpy as np

    from msg_adapters import RosbagsFactory
    from smplify3d_ros.frame_fitter import fit_frame
    from smplify3d_ros.runtime.messages import FrameMessages, to_frame
    from smplify3d_ros.runtime.processor import MessageProcessor

    factory = RosbagsFactory()
    camera = bag_fixture.fixture_camera()
    frame_data = bag_fixture.make_frames(node_support.fitter().model,
                                         node_support.node_config().extrinsic.T_cam_lidar(), 1, 2)[0]
    raw = node_support.frame_at(factory, camera, frame_data, bag_fixture.T0)
    msgs = FrameMessages(raw["camera_info"], raw["points"], raw["keypoints"], raw.get("image"))
    processor = MessageProcessor(node_support.config(), node_support.node_config(), factory,
                                 fitter=node_support.fitter())
    result = processor.process(msgs)
    assert result.ok and len(result.fits) == 2
    frame = to_frame(msgs, "coco17", processor.transforms, "camera")
    fits = fit_frame(frame, node_support.config())
    assert [f.person_id for f in fits] == [f.person_id for f in result.fits]
    for a, b in zip(fits, result.fits, strict=True):
        np.testing.assert_array_equal(a.vertices, b.vertices)
    frame.keypoints[1, :, 2] = 0.0  # the second person loses every keypoint: not fitted, as in the drivers
    assert [f.person_id for f in fit_frame(frame, node_support.config())] == [result.fits[0].person_id]
