"""/diagnostics of the live node, with either synchronizer: an input going silent is WARN within 2 s (its
own status) and makes the fitting status ERROR (no frame can be built); it recovers when the input does."""

from __future__ import annotations

import time

import bag_fixture
import node_support
import pytest

pytest.importorskip("rclpy")

OK, WARN, ERROR = 0, 1, 2
FITTING, POINTS = "smplify3d: fitting", "smplify3d: input points"


def _publish(recorder, camera, frame, stamp: float, skip: tuple[str, ...] = ()) -> None:
    msgs = node_support.bad_frame("no_people", recorder.factory, camera, frame, stamp)  # nobody: a light worker
    recorder.publish_frame({name: msg for name, msg in msgs.items() if name not in skip})


@pytest.mark.parametrize("use_message_filters", [False, True], ids=["builtin_sync", "message_filters"])
def test_a_silent_input_is_warn_within_2_s_and_no_frame_can_be_built(use_message_filters):
    bag = node_support.fixture_bag("mcap")
    params = {"diagnostics_period_s": 0.2, "sync.use_message_filters": use_message_filters}
    with node_support.fake_modules("message_filters"), node_support.running_node(params) as (node, recorder):
        assert type(node.sync).__name__ == ("MessageFiltersSync" if use_message_filters else "ApproximateTimeSync")
        stamp = bag_fixture.T0 + 500.0
        for _ in range(10):  # 1 s of frames at 10 Hz
            stamp += 0.1
            _publish(recorder, bag.camera, bag.frames[0], stamp)
            time.sleep(0.1)
        assert node_support.wait_for(lambda: node_support.last_statuses(recorder).get(POINTS, (None,))[0] == OK, 5.0)
        assert int(node_support.last_statuses(recorder)[FITTING][2]["sync.matched"]) >= 5

        silent_since = time.monotonic()  # the scan stops; the camera and the detector go on
        warn_after = error_after = None
        while time.monotonic() - silent_since < 4.0 and (warn_after is None or error_after is None):
            stamp += 0.1
            _publish(recorder, bag.camera, bag.frames[0], stamp, skip=("points",))
            time.sleep(0.1)
            status = node_support.last_statuses(recorder)
            if warn_after is None and status[POINTS][0] == WARN:
                warn_after = time.monotonic() - silent_since
                assert "no message for" in status[POINTS][1]
            if error_after is None and status[FITTING][0] == ERROR:
                error_after = time.monotonic() - silent_since
                assert "no frame can be built: points silent for" in status[FITTING][1]
        assert warn_after is not None and error_after is not None, node_support.last_statuses(recorder)
        print(f"input status WARN after {warn_after:.2f} s, fitting ERROR after {error_after:.2f} s of silence")
        assert warn_after < 2.0 and error_after < 2.0
        assert node_support.last_statuses(recorder)["smplify3d: input image"][0] == OK

        for _ in range(5):  # the scan is back
            stamp += 0.1
            _publish(recorder, bag.camera, bag.frames[0], stamp)
            time.sleep(0.1)
        assert node_support.wait_for(lambda: node_support.last_statuses(recorder)[POINTS][0] == OK, 5.0)
        assert node_support.wait_for(lambda: node_support.last_statuses(recorder)[FITTING][0] != ERROR, 5.0)
