"""`smplify3d bench-live`: the node in the command's process, the bag published by a player process through rclpy."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


@pytest.mark.parametrize("player", [[], ["--in-process-player"]], ids=["player_process", "in_process_player"])
def test_the_node_is_timed_live_on_a_bag_played_by_a_process_of_its_own(tmp_path, player):
    """`smplify3d bench-live` as a user runs it, in a process of its own; the bag played by a process of its
    own or in the node's process, each once both sides of the match are made."""
    pytest.importorskip("rclpy")
    from node_support import REPO, child_env, isolate_ros_graph, live_bag

    isolate_ros_graph()
    out = tmp_path / "live.json"
    proc = subprocess.run([sys.executable, "-c", "import sys; from smplify3d_ros.cli import main; sys.exit(main())",
                           "bench-live", str(live_bag()), "--settle", "2", "--json", str(out), *player],
                          cwd=REPO, env=child_env(), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr, proc.stderr
    result = json.loads(out.read_text())
    assert result["frames_played"] >= 2 and result["duration_s"] > 0
    assert result["bodies_received"] >= 1, "no ~/bodies came back"
    assert result["latency_ms_median"] >= 0.0  # received after its image's stamp
    # the node's own view: how late the frames arrived, and how long each stage took
    for key in ("latency_ms.arrival.p50", "latency_ms.fit.p50", "sync.matched"):
        assert key in result["diagnostics"], sorted(result["diagnostics"])
    assert "output rate" in proc.stdout
    # what a robot got, against the bag's ground truth: every published frame of the bag is scored
    accuracy = result["accuracy"]
    assert accuracy is not None and accuracy["frames"] == result["bodies_received"]
    assert accuracy["people"] >= accuracy["frames"] and 0.0 < accuracy["mpjpe_mm"] < 300.0, accuracy
    assert "ground truth, frames published: MPJPE" in proc.stdout


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
