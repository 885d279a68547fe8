"""Helpers shared by the node and replay tests: an isolated ROS graph, the fixture bags, a running node.

Expensive things (body model, fixture bags, their replay) are built once per test process and shared.
"""

from __future__ import annotations

import atexit
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import cache, lru_cache
from pathlib import Path
from typing import Any

import bag_fixture
import numpy as np


def isolate_ros_graph() -> int:
    """Keep DDS traffic on loopback, in a domain of our own; call before rclpy.init."""
    # each pytest-xdist worker (gw0, gw1, ...) in domains apart from the others' (its own residue), and in
    # one no other process on this host uses (another test run, a `smplify3d bench-live`): reserved
    from smplify3d_ros.eval.ros_domain import random_free_domain

    worker = int(os.environ.get("PYTEST_XDIST_WORKER", "gw0")[2:] or 0)
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    domain = int(os.environ.get("SMPLIFY3D_TEST_DOMAIN", 0)) or random_free_domain(step=workers, offset=worker)
    os.environ["SMPLIFY3D_TEST_DOMAIN"] = str(domain)
    os.environ["ROS_DOMAIN_ID"] = str(domain)
    os.environ["RMW_IMPLEMENTATION"] = "rmw_fastrtps_cpp"
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)  # deprecated in Jazzy; the range above replaces it
    return domain


def child_env() -> dict[str, str]:
    """This process's environment, with the repository first on PYTHONPATH: for the processes a test starts."""
    return dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")]))


@lru_cache(maxsize=1)
def config():
    from smplify3d_ros.config import load_config

    return load_config()


@lru_cache(maxsize=1)
def node_config():
    from smplify3d_ros.runtime.config import load_node_config

    return load_node_config()


@lru_cache(maxsize=1)
def fitter():
    from smplify3d_ros.fitting.fitter import Fitter

    return Fitter(config().fitting)


@lru_cache(maxsize=1)
def workdir() -> Path:
    path = Path(tempfile.mkdtemp(prefix="smplify3d-test-"))
    atexit.register(shutil.rmtree, path, ignore_errors=True)
    return path


@cache
def fixture_bag(storage: str) -> bag_fixture.FixtureBag:
    """mcap: two people, /tf_static present; sqlite3: one person, no /tf_static. Two frames each."""
    T = node_config().extrinsic.T_cam_lidar()
    path = workdir() / f"fixture_{storage}"
    if storage == "mcap":
        return bag_fixture.write_fixture_bag(path, fitter().model, T, "mcap", n_frames=2, n_people=2, seed=3,
                                             with_tf=True)
    return bag_fixture.write_fixture_bag(path, fitter().model, T, "sqlite3", n_frames=2, n_people=1, seed=5,
                                         with_tf=False)


@cache
def replayed(storage: str):
    """ReplaySummary of a fixture bag (written to <workdir>/replayed_<storage>.mcap, with a PNG)."""
    return replayed_bag(str(fixture_bag(storage).path), f"replayed_{storage}")


@cache
def replayed_bag(path: str, name: str = "replayed"):
    """ReplaySummary of any bag with the default profile and the shared fitter (cached per path)."""
    from smplify3d_ros.replay import replay_bag

    out = workdir() / f"{name}.mcap"
    png = workdir() / f"{name}.png"
    return replay_bag(path, out, png=png, progress=False, config=config(), node_config=node_config(),
                      fitter=fitter())


REPO = Path(__file__).resolve().parent.parent


def live_bag() -> Path:
    """A bundled recording from bags/ when it is there (`smplify3d make-bags`), else the fixture bag."""
    bundled = REPO / "bags" / "walk_sqlite3"
    return bundled if (bundled / "metadata.yaml").exists() else fixture_bag("mcap").path


def ground_truth(path: Path) -> dict[int, list]:
    """{stamp ns: [TruthBody]} of a bag's /ground_truth/bodies."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from smplify3d_ros.eval.truth import GROUND_TRUTH_TOPIC, parse_truth_document

    store = get_typestore(Stores.ROS2_JAZZY)
    out = {}
    with Reader(path) as reader:
        conns = [c for c in reader.connections if c.topic == GROUND_TRUTH_TOPIC]
        for conn, _, raw in reader.messages(connections=conns):
            truth = parse_truth_document(store.deserialize_cdr(raw, conn.msgtype).data)
            out[truth.stamp_ns] = truth.bodies
    return out


def rss_mb() -> float:
    """Resident set size of this process, MiB."""
    with open("/proc/self/status", encoding="ascii") as handle:
        for line in handle:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def wait_for(condition: Callable[[], bool], timeout: float, period: float = 0.05) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if condition():
            return True
        time.sleep(period)
    return condition()


class Recorder:
    """A test node: publishers for the node's inputs, subscriptions recording every output."""

    INPUT_TYPES = {
        "image": "sensor_msgs/msg/Image",
        "camera_info": "sensor_msgs/msg/CameraInfo",
        "points": "sensor_msgs/msg/PointCloud2",
        "keypoints": "sensor_msgs/msg/PointCloud2",
    }
    OUTPUT_TYPES = {
        "/smplify3d/markers": "visualization_msgs/msg/MarkerArray",
        "/smplify3d/joints": "sensor_msgs/msg/PointCloud2",
        "/smplify3d/body_points": "sensor_msgs/msg/PointCloud2",
        "/smplify3d/people": "geometry_msgs/msg/PoseArray",
        "/smplify3d/bodies": "std_msgs/msg/String",
        "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    }

    def __init__(self, topics: dict[str, str], depth: int = 50) -> None:
        from rclpy.node import Node

        from msg_adapters import RclpyFactory

        self.factory = RclpyFactory()
        self.node = Node("smplify3d_test_recorder")
        self.received: dict[str, list[Any]] = {topic: [] for topic in self.OUTPUT_TYPES}
        self._lock = threading.Lock()
        self.publishers = {
            name: self.node.create_publisher(self.factory.message_class(t), topics[name], depth)
            for name, t in self.INPUT_TYPES.items()
        }
        for topic, t in self.OUTPUT_TYPES.items():
            self.node.create_subscription(self.factory.message_class(t), topic,
                                          lambda msg, topic=topic: self._record(topic, msg), depth)

    def _record(self, topic: str, msg: Any) -> None:
        with self._lock:
            self.received[topic].append(msg)

    def count(self, topic: str) -> int:
        with self._lock:
            return len(self.received[topic])

    def messages(self, topic: str) -> list[Any]:
        with self._lock:
            return list(self.received[topic])

    def publish_frame(self, msgs: dict[str, Any], pause: float = 0.0) -> None:
        for name in ("image", "camera_info", "keypoints", "points"):
            if name in msgs:
                self.publishers[name].publish(msgs[name])
                if pause:
                    time.sleep(pause)

    def last_diagnostics(self) -> dict[str, str]:
        msgs = self.messages("/diagnostics")
        if not msgs:
            return {}
        return {kv.key: kv.value for kv in msgs[-1].status[0].values}

    def wait_connected(self, node_name: str = "smplify3d", timeout: float = 10.0) -> bool:
        """True once every input publisher has a subscriber and every output a publisher."""
        def ready() -> bool:
            inputs = all(p.get_subscription_count() > 0 for p in self.publishers.values())
            outputs = all(self.node.count_publishers(t) > 0 for t in self.OUTPUT_TYPES)
            return inputs and outputs
        return wait_for(ready, timeout)


@contextmanager
def running_node(parameters: dict[str, Any] | None = None, share_fitter: bool = True) -> Iterator[tuple[Any, Recorder]]:
    """rclpy initialized, the node and a Recorder spinning in a background executor; all torn down after."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from smplify3d_ros.node import create_node

    isolate_ros_graph()
    context_owned = not rclpy.ok()
    if context_owned:
        rclpy.init()
    node = recorder = executor = thread = None
    try:
        node = create_node(parameters or {}, fitter=fitter() if share_fitter else None)
        t = node.node_config.topics
        topics = {"image": t.image, "camera_info": t.camera_info, "points": t.points, "keypoints": t.keypoints}
        recorder = Recorder(topics)
        executor = SingleThreadedExecutor()  # as `rclpy.spin` in the entry point; callbacks are short
        executor.add_node(node)
        executor.add_node(recorder.node)
        thread = threading.Thread(target=executor.spin, daemon=True)
        thread.start()
        assert recorder.wait_connected(), "the node's topics did not connect"
        yield node, recorder
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=5.0)
        if thread is not None:
            thread.join(timeout=5.0)
        if node is not None:
            node.destroy_node()
        if recorder is not None:
            recorder.node.destroy_node()
        if context_owned:
            rclpy.try_shutdown()


def level(status: Any) -> int:
    """A DiagnosticStatus level as int (rclpy stores the `byte` field as bytes)."""
    value = status.level
    return int.from_bytes(value, "little") if isinstance(value, (bytes, bytearray)) else int(value)


def mpjpe(keypoints3d: np.ndarray, truth: np.ndarray) -> float:
    return float(np.linalg.norm(np.asarray(keypoints3d) - np.asarray(truth), axis=-1).mean())


# -- bad inputs -------------------------------------------------------------------------------------------
# kind -> what the pipeline does with it: ("drop", reason) or ("published", counter that grows)
BAD_KINDS: dict[str, tuple[str, str]] = {
    "empty_cloud": ("drop", "empty_cloud"),
    "nan_cloud": ("drop", "no_finite_points"),
    "truncated_cloud": ("drop", "bad_points"),
    "zero_image": ("drop", "bad_image"),
    "truncated_image": ("drop", "bad_image"),
    "wrong_size_image": ("drop", "image_size_mismatch"),
    "bad_keypoints": ("drop", "bad_keypoints"),
    "bad_camera_info": ("drop", "bad_camera_info"),
    "no_people": ("published", "frames_without_people"),
    "out_of_image": ("published", "people_dropped.out_of_image"),
    "time_backwards": ("drop", "time_backwards"),
}


def frame_at(factory: Any, camera: Any, frame: Any, stamp: float) -> dict[str, Any]:
    """The fixture frame's messages, stamped `stamp` (image, camera info, keypoints; the scan 20 ms later)."""
    import dataclasses

    return bag_fixture.frame_messages(factory, camera, dataclasses.replace(frame, stamp=stamp))


def bad_frame(kind: str, factory: Any, camera: Any, frame: Any, stamp: float) -> dict[str, Any]:
    """One frame's messages with one defect (BAD_KINDS); `time_backwards` is a valid frame whose stamp the
    caller places before an earlier one."""
    from msg_adapters import make_pointcloud2, numpy_to_image, write_keypoints

    msgs = frame_at(factory, camera, frame, stamp)
    lidar_stamp = stamp + 0.02
    frame_id = bag_fixture.LIDAR_FRAME
    if kind == "empty_cloud":
        empty = np.zeros(0, np.float32)
        msgs["points"] = make_pointcloud2(lidar_stamp, frame_id, {"x": empty, "y": empty, "z": empty}, factory)
    elif kind == "nan_cloud":
        nan = np.full(500, np.nan, np.float32)
        msgs["points"] = make_pointcloud2(lidar_stamp, frame_id, {"x": nan, "y": nan, "z": nan}, factory)
    elif kind == "truncated_cloud":
        data = bytes(msgs["points"].data)
        msgs["points"].data = data[: len(data) // 2]
    elif kind == "zero_image":
        msgs["image"].width, msgs["image"].height, msgs["image"].step = 0, 0, 0
        msgs["image"].data = b""
    elif kind == "truncated_image":
        data = bytes(msgs["image"].data)
        msgs["image"].data = data[: len(data) // 3]
    elif kind == "wrong_size_image":
        msgs["image"] = numpy_to_image(np.zeros((10, 12, 3), np.uint8), "rgb8", stamp, bag_fixture.CAMERA_FRAME,
                                       factory)
    elif kind == "bad_keypoints":
        msgs["keypoints"] = make_pointcloud2(stamp, bag_fixture.CAMERA_FRAME, {
            "u": np.ones(17, np.float32), "v": np.ones(17, np.float32)}, factory)  # no `joint` field
    elif kind == "bad_camera_info":
        msgs["camera_info"].k = np.zeros(9)
    elif kind == "no_people":
        msgs["keypoints"] = write_keypoints(np.zeros((0, 17, 3)), np.zeros(0, np.int64), stamp,
                                            bag_fixture.CAMERA_FRAME, factory)
    elif kind == "out_of_image":
        kp = frame.keypoints.copy()
        kp[..., 0] += 1e5
        ids = np.arange(len(kp), dtype=np.int64)
        msgs["keypoints"] = write_keypoints(kp, ids, stamp, bag_fixture.CAMERA_FRAME, factory)
    elif kind != "time_backwards":
        raise ValueError(kind)
    return msgs


# -- a fitter for tests of the wiring, not of the fitting --------------------------------------------------
class StubModel:
    name = "stub"
    joint_names = ("hip", "knee")
    shape_names = ("s0",)


class StubFitter:
    """Returns one small fit per person, at the depth of its points (or 3 m); `calls` holds the people."""

    model = StubModel()
    faces_np = np.array([[0, 1, 2]])

    def __init__(self) -> None:
        self.calls: list[list] = []

    def fit(self, people, K, origin, options=None):
        from smplify3d_ros.types import BodyFit, BodyParams, FitQuality

        self.calls.append(people)
        fits = []
        for p in people:
            z = float(np.median(p.points[:, 2])) if len(p.points) else 3.0
            params = BodyParams("stub", np.zeros(1), np.zeros((2, 3)), np.zeros(3), np.array([0.0, 0.0, z]))
            if p.init is not None:
                params = p.init.copy()
            verts = np.array([[0, 0, z], [0.1, 0, z], [0, 0.1, z]], np.float32)
            fits.append(BodyFit(p.person_id, params, ["hip", "knee"], verts, np.tile([0, 0, z], (17, 1)).astype(
                np.float32), np.zeros((2, 3), np.float32), FitQuality(1.0, 0.01, len(p.points), [], True, 0.5)))
        return fits


def stub_replay(path: Any, output: Any = None, **kwargs: Any):
    """replay_bag with the default profile and the stub fitter (fast: for tests of everything but fitting)."""
    from smplify3d_ros.replay import replay_bag

    kwargs.setdefault("fitter", StubFitter())
    return replay_bag(path, output, progress=False, config=config(), node_config=kwargs.pop("node_config", None)
                      or node_config(), **kwargs)


def statuses(msg: Any) -> dict[str, tuple[int, str, dict[str, str]]]:
    """A DiagnosticArray as {status name: (level, message, {key: value})}."""
    return {s.name: (level(s), s.message, {kv.key: kv.value for kv in s.values}) for s in msg.status}


def last_statuses(recorder: Recorder) -> dict[str, tuple[int, str, dict[str, str]]]:
    msgs = recorder.messages("/diagnostics")
    return statuses(msgs[-1]) if msgs else {}


@contextmanager
def fake_modules(*names: str) -> Iterator[None]:
    """Import `names` from test/fakes (stand-ins for ROS packages not installable here) for a while."""
    import sys

    fakes = str(Path(__file__).resolve().parent / "fakes")
    saved = {name: sys.modules.pop(name, None) for name in names}
    sys.path.insert(0, fakes)
    try:
        yield
    finally:
        sys.path.remove(fakes)
        for name in names:
            for key in [k for k in sys.modules if k == name or k.startswith(name + ".")]:
                del sys.modules[key]
            if saved[name] is not None:
                sys.modules[name] = saved[name]


def publish_bag_at_recorded_timing(path, recorder, speed: float = 1.0) -> dict[str, list[int]]:
    """Every input message of the bag, deserialized as rclpy messages straight from the bag's CDR bytes, at
    the recorded timing; returns the stamps sent per input."""
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
