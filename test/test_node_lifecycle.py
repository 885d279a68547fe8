"""The node's life: parameters from a profile overridden by ROS parameters, start, spin, shut down cleanly."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path

import node_support
import pytest

rclpy = pytest.importorskip("rclpy")

REPO = Path(__file__).resolve().parent.parent


def test_parameters_are_declared_with_descriptions_and_profile_values(ros):
    from smplify3d_ros.node import create_node

    node = create_node({}, fitter=node_support.fitter())
    try:
        assert node.get_parameter("params_file").value == "jackal_vlp16"
        assert node.get_parameter("sync.slop_s").value == pytest.approx(0.06)
        assert node.get_parameter("topics.points").value == "/velodyne_points"
        assert list(node.get_parameter("extrinsic.xyz").value) == pytest.approx([0.10, 0.0, -0.15])
        assert node.get_parameter("fitting.profile").value == "robot"
        assert node.get_parameter("fitting.body.model").value == "anny"
        assert node.get_parameter("fitting.device").value == "cpu"
        descriptor = node.describe_parameter("sync.slop_s")
        assert "stamp difference" in descriptor.description and descriptor.read_only
        assert "optimizer profile" in node.describe_parameter("fitting.profile").description
        names = {name for name, _ in node.get_topic_names_and_types()}
        assert {"/smplify3d/markers", "/smplify3d/joints", "/smplify3d/body_points", "/smplify3d/people",
                "/smplify3d/bodies", "/diagnostics"} <= names
    finally:
        node.destroy_node()


def test_ros_parameters_override_the_profile(ros):
    from smplify3d_ros.node import create_node

    node = create_node({"params_file": "ouster64", "sync.slop_s": 0.02, "publish.body_points": False,
                        "topics.compressed_image": "/camera/color/image_raw/compressed", "fitting.profile": "thesis"},
                       fitter=node_support.fitter())
    try:
        cfg, node_cfg = node.config, node.node_config
        assert node_cfg.topics.points == "/ouster/points", "the profile's value"
        assert cfg.lidar.vertical_resolution_deg == pytest.approx(0.71)
        assert node_cfg.sync.slop_s == pytest.approx(0.02), "the ROS parameter's value"
        assert cfg.fitting.profile == "thesis"
        # the node's own publishers (the graph may still list other tests' nodes in this domain)
        published = {pub.topic_name for pub in node.publishers}
        assert "/smplify3d/body_points" not in published and "/smplify3d/bodies" in published
        subscribed = {sub.topic_name for sub in node.subscriptions}
        assert "/camera/color/image_raw/compressed" in subscribed and "/ouster/points" in subscribed
    finally:
        node.destroy_node()


@pytest.mark.parametrize("parameters, message", [
    ({"people.max_people": 0}, "max_people must be"),
    ({"sync.slop_s": "fast"}, "sync.slop_s"),
    ({"fitting.profile": "nope"}, "profile 'nope'"),
    ({"params_file": "no_such_profile"}, "unknown params profile"),
])
def test_bad_parameters_are_configuration_errors(ros, parameters, message):
    from smplify3d_ros.config import ConfigError
    from smplify3d_ros.node import create_node

    with pytest.raises(ConfigError, match=message.replace("(", r"\(")):
        create_node(parameters, fitter=node_support.fitter()).destroy_node()


@pytest.mark.parametrize("lazy", [True, False])
def test_outputs_are_built_only_while_subscribed_when_lazy(ros, lazy):
    from rclpy.node import Node
    from std_msgs.msg import String

    from smplify3d_ros.node import create_node

    node = create_node({"publish.lazy": lazy}, fitter=node_support.fitter())
    listener = Node("smplify3d_test_listener")
    try:
        everything = {"markers", "joints", "body_points", "people", "bodies", "clearing_points"}
        assert set(node.processor.skip_outputs()) == (everything if lazy else set())
        listener.create_subscription(String, "/smplify3d/bodies", lambda msg: None, 10)
        if lazy:
            assert node_support.wait_for(lambda: "bodies" not in node.processor.skip_outputs(), 10.0)
            assert set(node.processor.skip_outputs()) == everything - {"bodies"}
        else:
            assert list(node.processor.skip_outputs()) == []
    finally:
        listener.destroy_node()
        node.destroy_node()


def test_spin_publishes_diagnostics_then_destroys_cleanly():
    with node_support.running_node({"diagnostics_period_s": 0.1}) as (node, recorder):
        assert node_support.wait_for(lambda: recorder.count("/diagnostics") >= 2, 10.0)
        values = recorder.last_diagnostics()
        assert values["frames_in"] == "0"
        assert values["queue.dropped_stale"] == "0" and "rate_hz.points" in values
        status = recorder.messages("/diagnostics")[-1].status[0]
        assert status.name == "smplify3d: fitting"
        # no sensor ever publishes here: past diagnostics.stale_after_s (1 s) the inputs are WARN and the
        # fitting status ERROR, diagnostic_updater style (one status per task)
        assert node_support.wait_for(lambda: node_support.last_statuses(recorder)["smplify3d: fitting"][0] == 2, 10.0)
        statuses = node_support.last_statuses(recorder)
        assert statuses["smplify3d: fitting"][1].startswith("no frame can be built: image silent for")
        for name in ("image", "camera_info", "points", "keypoints"):
            level, message, values = statuses[f"smplify3d: input {name}"]
            assert level == 1 and message.startswith("no message yet for"), (name, message)
            assert values["received"] == "0" and values["topic"].startswith("/")
        worker = node._worker
    assert not worker.is_alive(), "the fitting worker stopped with the node"


def _start(args: list[str]) -> subprocess.Popen:
    node_support.isolate_ros_graph()
    env = node_support.child_env()  # the graph's settings included
    env["PYTHONUNBUFFERED"] = "1"
    return subprocess.Popen([sys.executable, "-m", "smplify3d_ros.node", "--ros-args", *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _read_until(proc: subprocess.Popen, text: str, timeout: float) -> str:
    import selectors

    out = ""
    sel = selectors.DefaultSelector()
    sel.register(proc.stdout, selectors.EVENT_READ)
    end = time.monotonic() + timeout
    while time.monotonic() < end and text not in out:
        if sel.select(timeout=0.5):
            line = proc.stdout.readline()
            if not line:
                break
            out += line
    return out


def test_ctrl_c_while_fitting_exits_cleanly_without_traceback(ros):
    import threading

    from rclpy.executors import SingleThreadedExecutor

    proc = _start(["-p", "diagnostics_period_s:=0.2"])
    recorder = node_support.Recorder({"image": "/camera/color/image_raw", "camera_info": "/camera/color/camera_info",
                                      "points": "/velodyne_points", "keypoints": "/keypoints"})
    executor = SingleThreadedExecutor()
    executor.add_node(recorder.node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        out = _read_until(proc, "ready:", timeout=120)
        assert "ready:" in out, out
        assert recorder.wait_connected(timeout=30)
        bag = node_support.fixture_bag("mcap")
        recorder.publish_frame(node_support.frame_at(recorder.factory, bag.camera, bag.frames[0], 1_700_000_000.0))
        assert node_support.wait_for(lambda: int(recorder.last_diagnostics().get("received.points", "0")) >= 1, 30)
        proc.send_signal(signal.SIGINT)  # the worker is fitting the frame now
        rest, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
        executor.shutdown()
        recorder.node.destroy_node()
    out += rest
    assert proc.returncode == 0, out
    assert "Traceback" not in out and "Exception" not in out, out
    assert "Warp" not in out and "CUDA driver" not in out, "the body model loads quietly (ROS log only)"


def test_configuration_error_exits_2_with_the_key():
    proc = _start(["-p", "people.max_people:=0"])
    try:
        out, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 2, out
    assert "max_people must be" in out and "Traceback" not in out
