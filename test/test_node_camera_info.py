"""The camera info joins each frame as the latest one received (`sync.latest_camera_info`, the default): a
frame whose own camera info comes late or never is fitted with the last one. Matched by stamp (false), such
a frame waits for its camera info and is lost without it."""

from __future__ import annotations

import time

import bag_fixture
import node_support
import pytest

pytest.importorskip("rclpy")

FRAMES = 6


@pytest.mark.parametrize("latest", [True, False], ids=["latest", "matched"])
def test_frames_whose_camera_info_never_comes(latest):
    bag = node_support.fixture_bag("mcap")
    params = {"sync.latest_camera_info": latest, "worker_queue_size": 100, "diagnostics_period_s": 0.2}
    with node_support.running_node(params) as (node, recorder):
        stamp = bag_fixture.T0 + 700.0
        for k in range(FRAMES):  # only the first frame brings a camera info
            stamp += 0.1
            msgs = node_support.bad_frame("no_people", recorder.factory, bag.camera, bag.frames[0], stamp)
            recorder.publish_frame({name: m for name, m in msgs.items() if k == 0 or name != "camera_info"})
            time.sleep(0.1)
        expected = FRAMES if latest else 1
        assert node_support.wait_for(lambda: recorder.count("/smplify3d/bodies") >= expected, 10.0)
        time.sleep(0.5)  # nothing more comes
        assert recorder.count("/smplify3d/bodies") == expected
        # all inputs silent by then; a silent camera info stops frames only when they wait for it
        reason = node.no_frame_reason(time.monotonic() + 5.0)
        assert ("camera_info silent" in reason) == (not latest), reason
