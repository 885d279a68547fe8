"""The live path: a recording published through rclpy at its recorded timing into a running node.

The bag is a bundled recording (bags/walk_sqlite3, else the test fixture). Fitting is slower than the
sensors on a CPU, so the node's latest-frame queue skips frames; every frame it publishes must be what
`smplify3d replay` computes for that frame: same ids, same bodies, same accuracy against the ground truth.
"""

from __future__ import annotations

import json
import time

import bag_fixture
import node_support
import numpy as np
import pytest

from msg_adapters import read_fields
from smplify3d_ros.keypoints import COCO17_NAMES

pytest.importorskip("rclpy")


def publish_bag_at_recorded_timing(path, recorder, speed: float = 1.0) -> dict[str, list[int]]:
    """Every input message of the bag, deserialized as rclpy messages straight from the bag's CDR bytes."""
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader

    topic_to_input = {topic: name for name, topic in bag_fixture.TOPICS.items() if name in recorder.publishers}
    sent: dict[str, list[int]] = {}
    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic in topic_to_input]
        start_wall, start_bag = time.monotonic(), None
        for conn, t, raw in reader.messages(connections=conns):
            name = topic_to_input[conn.topic]
            start_bag = t if start_bag is None else start_bag
            delay = (t - start_bag) * 1e-9 / speed - (time.monotonic() - start_wall)
            if delay > 0:
                time.sleep(delay)
            publisher = recorder.publishers[name]
            msg = deserialize_message(bytes(raw), publisher.msg_type)
            publisher.publish(msg)
            sent.setdefault(name, []).append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
    return sent


def test_live_node_matches_replay_on_the_same_bag():
    path = node_support.live_bag()
    reference = node_support.replayed_bag(str(path), "replayed_live")  # the replay path on the same bag
    by_stamp = {record.stamp_ns: record for record in reference.frames}
    truth = node_support.ground_truth(path)
    assert reference.frames_published == reference.frames_synced >= 2 and reference.people_fitted > 0

    with node_support.running_node({"diagnostics_period_s": 0.25}) as (node, recorder):
        sent = publish_bag_at_recorded_timing(path, recorder)
        last_stamp = sent["image"][-1]

        def last_frame_done() -> bool:
            docs = [json.loads(m.data) for m in recorder.messages("/smplify3d/bodies")]
            return any(d["stamp"]["sec"] * 1_000_000_000 + d["stamp"]["nanosec"] == last_stamp for d in docs)

        # the latest-frame queue may skip frames while fitting, never the last one
        assert node_support.wait_for(last_frame_done, 300.0), recorder.last_diagnostics()
        n_published = recorder.count("/smplify3d/bodies")
        assert node_support.wait_for(lambda: recorder.count("/smplify3d/markers") >= n_published
                                     and recorder.count("/smplify3d/joints") >= n_published
                                     and recorder.count("/smplify3d/people") >= n_published, 30.0)
        time.sleep(0.6)  # one more diagnostics period
        diagnostics = recorder.last_diagnostics()
        bodies = [json.loads(m.data) for m in recorder.messages("/smplify3d/bodies")]
        markers = recorder.messages("/smplify3d/markers")
        joints = recorder.messages("/smplify3d/joints")
        people = recorder.messages("/smplify3d/people")

    n_frames = len(sent["image"])
    assert n_frames == reference.frames_synced
    assert 2 <= len(bodies) <= n_frames
    # bodies: the replay's fit of the same frame, person for person
    errors, reference_errors = [], []
    for doc in bodies:
        stamp = doc["stamp"]["sec"] * 1_000_000_000 + doc["stamp"]["nanosec"]
        assert stamp in sent["image"], "outputs carry the input image's stamp"
        assert doc["frame_id"] == bag_fixture.CAMERA_FRAME
        record = by_stamp[stamp]
        assert [b["id"] for b in doc["bodies"]] == record.person_ids
        true = {body.person_id: body for body in truth[stamp]}
        for body, ref_kp, ref_transl in zip(doc["bodies"], record.keypoints3d, record.transl, strict=True):
            kp = np.array([body["joints3d"][name] for name in COCO17_NAMES])
            np.testing.assert_allclose(kp, ref_kp, atol=2e-3)  # the same fit as replay
            np.testing.assert_allclose(body["transl"], ref_transl, atol=2e-3)
            assert body["model"] == "anny" and "image_only" not in body["flags"]
            errors.append(node_support.mpjpe(kp, true[body["id"]].keypoints3d))
            reference_errors.append(node_support.mpjpe(ref_kp, true[body["id"]].keypoints3d))
    assert errors, "people were fitted"
    live_mpjpe_mm, replay_mpjpe_mm = 1e3 * float(np.mean(errors)), 1e3 * float(np.mean(reference_errors))
    assert live_mpjpe_mm == pytest.approx(replay_mpjpe_mm, abs=2.0)
    assert live_mpjpe_mm < 200.0

    # markers: a mesh, a skeleton and a label per person, stamped with the image
    for array, doc in zip(markers, bodies, strict=True):
        ids = {b["id"] for b in doc["bodies"]}
        meshes = {m.id: m for m in array.markers if m.ns == "mesh" and m.action == 0}
        assert set(meshes) == ids
        assert all(m.type == 11 and len(m.points) % 3 == 0 and len(m.points) > 1000 for m in meshes.values())
        assert {m.ns for m in array.markers if m.action == 0} == {"mesh", "skeleton", "label"}
        header = array.markers[0].header
        assert (header.stamp.sec, header.stamp.nanosec) == (doc["stamp"]["sec"], doc["stamp"]["nanosec"])
    # joints: 17 per person with the person ids; people: one pose per body
    for cloud, doc, poses in zip(joints, bodies, people, strict=True):
        fields = read_fields(cloud, ["person", "joint"])
        assert sorted(set(fields["person"].tolist())) == sorted(b["id"] for b in doc["bodies"])
        assert len(fields["joint"]) == 17 * len(doc["bodies"])
        assert len(poses.poses) == len(doc["bodies"])
    # diagnostics: every frame synchronized; each one fitted or dropped as stale, none lost
    assert diagnostics["sync.matched"] == str(n_frames)
    assert int(diagnostics["frames_published"]) == len(bodies)
    assert int(diagnostics["frames_published"]) + int(diagnostics["queue.dropped_stale"]) == n_frames
    assert float(diagnostics["latency_ms.fit.mean"]) > 0
    assert diagnostics["worker_errors"] == "0" and "drop.internal_error" not in diagnostics
