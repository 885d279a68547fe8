"""One frame path: the live node, the replay, `fit_frame` and the bench run the same frame logic, and the
node and the replay give identical `~/bodies` on a bundled bag with either synchronizer."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import node_support
import pytest
from test_node_replay import publish_bag_at_recorded_timing

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
    assert summary.frames_published == len(replayed) >= 2

    # a queue longer than the bag: the node fits every frame, as the replay does
    parameters = {"sync.use_message_filters": use_mf, "worker_queue_size": 100, "diagnostics_period_s": 0.25}
    with node_support.running_node(parameters) as (node, recorder):
        assert type(node.sync).__name__ == ("MessageFiltersSync" if use_mf else "ApproximateTimeSync")
        sent = publish_bag_at_recorded_timing(path, recorder)
        assert node_support.wait_for(lambda: recorder.count("/smplify3d/bodies") >= len(replayed), 300.0), \
            recorder.last_diagnostics()
        node_support.wait_for(lambda: "sync.matched" in recorder.last_diagnostics(), 5.0)
        diagnostics = recorder.last_diagnostics()
        live = [json.loads(m.data) for m in recorder.messages("/smplify3d/bodies")]

    assert len(sent["image"]) == summary.frames_synced
    for doc in live:
        stamp = doc["stamp"]["sec"] * 1_000_000_000 + doc["stamp"]["nanosec"]
        assert doc == replayed[stamp], f"frame {stamp}: the node's bodies differ from the replay's"
    assert {d["stamp"]["sec"] * 1_000_000_000 + d["stamp"]["nanosec"] for d in live} == set(replayed)
    sync_keys = {k for k in diagnostics if k.startswith("sync.")}
    assert sync_keys == set(summary.sync), "the same sync.* diagnostics with either synchronizer"
    assert int(diagnostics["sync.matched"]) == summary.sync["sync.matched"] == summary.frames_synced


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
