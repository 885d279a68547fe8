"""`smplify3d bench-live`: the node in this process, the bag published by a player process through rclpy."""

from __future__ import annotations

import pytest


def test_the_node_is_timed_live_on_a_bag_played_by_a_process_of_its_own():
    pytest.importorskip("rclpy")
    from node_support import isolate_ros_graph, live_bag

    # a domain apart: the player process and the node met nothing else there (in the worker's own domain,
    # after the worker's other ROS tests, the node once heard none of what the player published)
    isolate_ros_graph(apart=True)
    from smplify3d_ros.eval.live import run_live

    result = run_live(live_bag(), None, {}, speed=1.0, settle_s=2.0)
    assert result.frames_played >= 2 and result.duration_s > 0
    assert result.bodies, "no ~/bodies came back"
    assert all(received >= stamp for stamp, received, _ in result.bodies)
    # the node's own view: how late the frames arrived, and how long each stage took
    for key in ("latency_ms.arrival.p50", "latency_ms.fit.p50", "sync.matched"):
        assert key in result.diagnostics, sorted(result.diagnostics)
    assert "output rate" in result.text()
    # what a robot got, against the bag's ground truth: every published frame of the bag is scored
    accuracy = result.accuracy
    assert accuracy is not None and accuracy.frames == len(result.bodies) and accuracy.people >= accuracy.frames
    assert 0.0 < accuracy.mpjpe_mm < 300.0, accuracy
    assert "ground truth, frames published: MPJPE" in result.text()


def test_the_node_subscribes_to_the_image_topic_the_bag_has():
    """A bag that holds only compressed images (bags/people_ids) is subscribed as compressed, as the replay
    reads it; a raw-image bag keeps the raw topic; an explicit parameter still wins over the bag."""
    pytest.importorskip("rclpy")
    from node_support import REPO

    from smplify3d_ros.eval.live import bag_topic_parameters

    compressed = bag_topic_parameters(REPO / "bags" / "people_ids", None, {})
    assert compressed["topics.compressed_image"] == "/camera/color/image_raw/compressed"
    assert compressed["topics.image"] == ""
    assert compressed["topics.points"] == "/velodyne_points" and compressed["topics.keypoints"] == "/keypoints"
    raw = bag_topic_parameters(REPO / "bags" / "walk", None, {})
    assert raw["topics.image"] == "/camera/color/image_raw" and raw["topics.compressed_image"] == ""
    chosen = bag_topic_parameters(REPO / "bags" / "walk", None,
                                  {"topics.compressed_image": "/camera/color/image_raw/compressed"})
    assert chosen["topics.compressed_image"] == "/camera/color/image_raw/compressed" and chosen["topics.image"] == ""


def test_a_bag_without_the_inputs_is_one_line_not_a_traceback(tmp_path, capsys):
    pytest.importorskip("rclpy")
    import argparse

    from smplify3d_ros.eval.live import add_arguments, run

    (tmp_path / "not_a_bag").mkdir()
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    assert run(parser.parse_args([str(tmp_path / "not_a_bag")])) in (1, 2)
    err = capsys.readouterr().err.strip()
    assert err.startswith("smplify3d bench-live:") and "\n" not in err and "Traceback" not in err
