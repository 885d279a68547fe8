"""`smplify3d bench-live`: the node in this process, the bag published by a player process through rclpy."""

from __future__ import annotations

import pytest


def test_the_node_is_timed_live_on_a_bag_played_by_a_process_of_its_own():
    pytest.importorskip("rclpy")
    from node_support import isolate_ros_graph, live_bag

    isolate_ros_graph()
    from smplify3d_ros.eval.live import run_live

    result = run_live(live_bag(), None, {}, speed=1.0, settle_s=2.0)
    assert result.frames_played >= 2 and result.duration_s > 0
    assert result.bodies, "no ~/bodies came back"
    assert all(received >= stamp for stamp, received, _ in result.bodies)
    # the node's own view: how late the frames arrived, and how long each stage took
    for key in ("latency_ms.arrival.p50", "latency_ms.fit.p50", "sync.matched"):
        assert key in result.diagnostics, sorted(result.diagnostics)
    assert "output rate" in result.text()
