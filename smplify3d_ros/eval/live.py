"""`smplify3d bench-live BAG`: the node live, in this process, fed a recording at its recorded rate.

The node (`smplify3d_ros.node`) and a recorder of `~/bodies` spin in this process over the local ROS graph
(loopback, a domain of their own). A player publishes the bag's input topics through rclpy at the recorded
timing, every stamp shifted by one offset so that the frames look captured now. The player runs in a
process of its own, as a robot's camera and LiDAR drivers do (`--in-process-player`: in the node's
process, where reading and publishing the bag competes with the fitting for Python's interpreter lock).
The node subscribes to the bag's own input topics, found as `smplify3d replay` finds them (the profile's
topic names where the bag has them, else the bag's only topic of the right type: a bag that holds only
`.../compressed` images is played and subscribed as compressed); `-p topics.<name>=...` still wins.
Printed: frames played, bodies documents received, the output rate while the bag played, and the
latency from the image stamp to the moment `~/bodies` arrives (median, 95th percentile), plus the node's
own counters (each stage's latency, stale frames dropped, warm and cold fits). Without rclpy it says so
and exits 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from smplify3d_ros.cli import at_least
from smplify3d_ros.eval.ros_domain import random_free_domain
from smplify3d_ros.keypoints import COCO17_NAMES

DEFAULT_PROFILE = "jackal_vlp16"  # the node's own default params_file
FIRST_BODIES_MAX_S = 30.0  # s, longest wait past the settle for the first ~/bodies (a machine loaded by other work)
PLAYER_MATCH_MAX_S = 30.0  # s, longest wait for the player and the node to match each other
INPUT_TYPES = {
    "image": "sensor_msgs/msg/Image",
    "compressed_image": "sensor_msgs/msg/CompressedImage",
    "camera_info": "sensor_msgs/msg/CameraInfo",
    "points": "sensor_msgs/msg/PointCloud2",
    "keypoints": "sensor_msgs/msg/PointCloud2",
}


@dataclass
class LiveAccuracy:
    """The published bodies against the bag's ground truth (`/ground_truth/bodies`), as a robot got them:
    only the frames the node published (the others it dropped, keeping up), each at its own stamp."""

    frames: int  # published documents whose stamp has a ground-truth frame
    people: int  # ground-truth people in those frames with a body of their id
    missed: int  # ... without one
    mpjpe_mm: float  # mean over `people` of the COCO-17 joint error, mm


@dataclass
class LiveResult:
    frames_played: int = 0
    duration_s: float = 0.0  # from the first to the last played message
    bodies: list[tuple[int, int, int]] = field(default_factory=list)  # (stamp ns, received ns, people)
    diagnostics: dict[str, str] = field(default_factory=dict)
    offset_ns: int | None = None  # what the player added to every stamp of the bag
    joints: dict[int, dict[int, np.ndarray]] = field(default_factory=dict)  # stamp ns -> id -> (17, 3), m
    accuracy: LiveAccuracy | None = None  # with a bag that has ground truth

    @property
    def latencies_ms(self) -> np.ndarray:
        return np.array([(received - stamp) * 1e-6 for stamp, received, _ in self.bodies])

    def text(self) -> str:
        lat = self.latencies_ms
        rate = len(self.bodies) / self.duration_s if self.duration_s > 0 else float("nan")
        people = np.mean([n for _, _, n in self.bodies]) if self.bodies else 0.0
        lines = [f"frames played {self.frames_played} in {self.duration_s:.1f} s; ~/bodies received "
                 f"{len(self.bodies)} ({people:.1f} people per frame)",
                 f"output rate {rate:.1f} Hz"]
        if len(lat):
            lines.append(f"latency image stamp -> ~/bodies: median {np.median(lat):.0f} ms, "
                         f"95th percentile {np.percentile(lat, 95):.0f} ms, max {lat.max():.0f} ms")
        if self.accuracy is not None:
            a = self.accuracy
            lines.append(f"ground truth, frames published: MPJPE {a.mpjpe_mm:.1f} mm over {a.people} people in "
                         f"{a.frames} frames ({a.missed} missed)")
        keys = [k for k in sorted(self.diagnostics) if k.startswith(("queue.", "tracking.", "sync.matched",
                                                                       "latency_ms.", "drop."))]
        lines += [f"  {k}: {self.diagnostics[k]}" for k in keys]
        return "\n".join(lines)


class _Player:
    """Publishers for the node's inputs; publishes a bag's messages with shifted stamps."""

    def __init__(self, topics: dict[str, str], rclpy_node: Any) -> None:
        """`topics`: input name (`INPUT_TYPES` key) -> topic; empty topics are not played."""
        from msg_adapters import RclpyFactory

        self.node = rclpy_node
        self.factory = RclpyFactory()
        self.topics = {topic: name for name, topic in topics.items() if topic}
        self.publishers = {name: rclpy_node.create_publisher(self.factory.message_class(INPUT_TYPES[name]), topic,
                                                             10)
                           for topic, name in self.topics.items()}

    def play(self, path: Path, speed: float, stop: threading.Event) -> tuple[int, float, int | None]:
        """(frames played, seconds, the offset added to every stamp in ns) of one pass over the bag at
        `speed` times its recorded rate."""
        from rclpy.serialization import deserialize_message
        from rosbags.rosbag2 import Reader

        frames, first_wall, last_wall, offset = 0, None, None, None
        with Reader(path) as reader:
            conns = [c for c in reader.connections if c.topic in self.topics]
            start_bag = None
            for conn, t, raw in reader.messages(connections=conns):
                if stop.is_set():
                    break
                name = self.topics[conn.topic]
                start_bag = t if start_bag is None else start_bag
                first_wall = time.monotonic() if first_wall is None else first_wall
                delay = (t - start_bag) * 1e-9 / speed - (time.monotonic() - first_wall)
                if delay > 0:
                    time.sleep(delay)
                publisher = self.publishers[name]
                msg = deserialize_message(bytes(raw), publisher.msg_type)
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                offset = time.time_ns() - stamp if offset is None else offset
                shifted = stamp + offset
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(shifted, 1_000_000_000)
                publisher.publish(msg)
                frames += name in ("image", "compressed_image")
                last_wall = time.monotonic()
        return frames, (last_wall - first_wall) if first_wall is not None and last_wall else 0.0, offset

    def wait_for_delivery(self, timeout_s: float) -> bool:
        """Whether the reliable subscribers acknowledged every message within `timeout_s` (a process that
        exits first takes its unacknowledged messages with it)."""
        from rclpy.duration import Duration

        deadline = time.monotonic() + timeout_s
        return all(p.wait_for_all_acked(Duration(seconds=max(deadline - time.monotonic(), 0.0)))
                   for p in self.publishers.values())

    def wait_for_subscribers(self, timeout_s: float) -> bool:
        """Whether every publisher was matched by a subscriber within `timeout_s` (discovery)."""
        return _wait_for(lambda: all(p.get_subscription_count() > 0 for p in self.publishers.values()), timeout_s)


def input_topics(node_config: Any) -> dict[str, str]:
    """The node's input topics by `INPUT_TYPES` name."""
    t = node_config.topics
    return {"image": t.image, "compressed_image": t.compressed_image, "camera_info": t.camera_info,
            "points": t.points, "keypoints": t.keypoints}


def bag_topic_parameters(bag: Path, params: str | None, overrides: dict[str, Any]) -> dict[str, str]:
    """The node's input-topic parameters (`topics.*`) for the topics `bag` holds, resolved as the replay
    resolves them (`replay.reader.resolve_topics`). Raises `ReplayError` for a bag without the inputs."""
    from smplify3d_ros.node import overrides_from_parameters
    from smplify3d_ros.replay.reader import BagReader
    from smplify3d_ros.runtime.config import load_node_config

    node_config = load_node_config(params or DEFAULT_PROFILE, overrides_from_parameters(overrides))
    with BagReader(bag, node_config) as reader:
        found = reader.topics
    image = found.image or ""
    return {"topics.image": "" if found.compressed else image, "topics.compressed_image": image if found.compressed
            else "", "topics.camera_info": found.camera_info, "topics.points": found.points,
            "topics.keypoints": found.keypoints}


def play_main(argv: list[str]) -> int:
    """The player process: `python -m smplify3d_ros.eval.live --play BAG TOPICS_JSON SPEED`. Publishes
    once its subscribers are matched, then prints `{"frames": N, "duration_s": S, "offset_ns": O}` on stdout."""
    import rclpy

    bag, topics, speed = Path(argv[0]), json.loads(argv[1]), float(argv[2])
    rclpy.init()
    try:
        node = rclpy.create_node("smplify3d_bench_live_player")
        player = _Player(topics, node)
        if not player.wait_for_subscribers(PLAYER_MATCH_MAX_S):
            raise RuntimeError(f"no subscriber matched the player's topics within {PLAYER_MATCH_MAX_S:.0f} s")
        # our side of the match is made; the subscriptions' side may come later (messages published before
        # it are lost: on a loaded machine a whole 6-frame bag went unheard 2 s after ours): the parent says
        # when every subscription of the node has matched a publisher of ours
        print("matched", flush=True)
        if sys.stdin.readline().strip() != "go":
            raise RuntimeError("the parent process did not say go")
        frames, duration, offset = player.play(bag, speed, threading.Event())
        player.wait_for_delivery(PLAYER_MATCH_MAX_S)  # a reliable subscriber's last messages before we exit
        print(json.dumps({"frames": frames, "duration_s": duration, "offset_ns": offset}), flush=True)
        node.destroy_node()
    except KeyboardInterrupt:
        return 130
    except Exception as e:  # noqa: BLE001 - one line for the user, not a traceback
        print(f"smplify3d bench-live player: {bag}: {type(e).__name__}: {e}", file=sys.stderr)
        return 1
    finally:
        rclpy.try_shutdown()
    return 0


def _play_in_child(bag: Path, topics: dict[str, str], speed: float,
                   subscribed: Any = lambda: True) -> tuple[int, float, int | None]:
    """(frames, seconds, stamp offset ns) played by a player process (`play_main`) on this process's ROS
    domain, once its publishers have matched their subscribers and `subscribed()` (the subscriptions' side
    of the match) holds."""
    command = [sys.executable, "-m", "smplify3d_ros.eval.live", "--play", str(bag), json.dumps(topics), str(speed)]
    child = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    try:
        if child.stdout.readline().strip() == "matched":
            if not _wait_for(subscribed, PLAYER_MATCH_MAX_S):
                raise RuntimeError(f"the node's subscriptions matched no publisher within {PLAYER_MATCH_MAX_S:.0f} s")
            child.stdin.write("go\n")
            child.stdin.flush()
        out, _ = child.communicate()
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    if child.returncode != 0:
        raise RuntimeError(f"the player process exited with status {child.returncode}")
    played = json.loads(out.strip().splitlines()[-1])
    offset = played.get("offset_ns")
    return int(played["frames"]), float(played["duration_s"]), None if offset is None else int(offset)


def run_live(bag: Path, params: str | None, overrides: dict[str, Any], speed: float, settle_s: float,
             in_process_player: bool = False) -> LiveResult:
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node

    from msg_adapters import RclpyFactory
    from smplify3d_ros.node import create_node

    if "ROS_DOMAIN_ID" not in os.environ:  # a domain of its own: another run beside this one would feed it its bag
        os.environ["ROS_DOMAIN_ID"] = str(random_free_domain())
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init()
    result = LiveResult()
    node = helper = executor = None
    try:
        bag_topics = bag_topic_parameters(bag, params, overrides)
        node = create_node({"params_file": params or DEFAULT_PROFILE, **bag_topics, **overrides})
        helper = Node("smplify3d_bench_live")
        topics = input_topics(node.node_config)
        player = _Player(topics, helper) if in_process_player else None
        factory = RclpyFactory()
        lock = threading.Lock()

        def on_bodies(msg: Any) -> None:
            received = time.time_ns()
            doc = json.loads(msg.data)
            stamp = doc["stamp"]["sec"] * 1_000_000_000 + doc["stamp"]["nanosec"]
            joints = {int(b["id"]): np.array([b["joints3d"][name] for name in COCO17_NAMES], np.float64)
                      for b in doc["bodies"]}
            with lock:
                result.bodies.append((stamp, received, len(doc["bodies"])))
                result.joints[stamp] = joints

        def on_diagnostics(msg: Any) -> None:
            for status in msg.status:
                if status.name.startswith(node.get_name()):
                    result.diagnostics.update({kv.key: kv.value for kv in status.values})

        helper.create_subscription(factory.message_class("std_msgs/msg/String"), f"/{node.get_name()}/bodies",
                                   on_bodies, 50)
        helper.create_subscription(factory.message_class("diagnostic_msgs/msg/DiagnosticArray"), "/diagnostics",
                                   on_diagnostics, 50)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.add_node(helper)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()
        inputs = [sub for sub in node.subscriptions if sub.topic_name in set(topics.values()) - {""}]

        def subscribed() -> bool:  # the subscriptions' side of the match
            return all(sub.get_publisher_count() > 0 for sub in inputs)

        if player is not None:
            # both sides of the match, as for the player process: what is published before is lost
            if not (player.wait_for_subscribers(PLAYER_MATCH_MAX_S) and _wait_for(subscribed, PLAYER_MATCH_MAX_S)):
                raise RuntimeError(f"the player and the node did not match within {PLAYER_MATCH_MAX_S:.0f} s")
            result.frames_played, result.duration_s, result.offset_ns = player.play(bag, speed, threading.Event())
        else:
            result.frames_played, result.duration_s, result.offset_ns = _play_in_child(bag, topics, speed, subscribed)
        time.sleep(settle_s)  # the last frame's fit and one diagnostics period
        if not result.bodies:  # the first fit ran past the settle (a machine loaded by other work)
            _wait_for(lambda: bool(result.bodies), FIRST_BODIES_MAX_S, period_s=0.2)
            time.sleep(settle_s)  # ... then the diagnostics that report it
    finally:
        if executor is not None:
            executor.shutdown(timeout_sec=5.0)
        for n in (node, helper):
            if n is not None:
                n.destroy_node()
        rclpy.try_shutdown()
    result.accuracy = live_accuracy(bag, result)
    return result


def _wait_for(condition: Any, timeout_s: float, period_s: float = 0.05) -> bool:
    """Poll `condition()` until it holds or `timeout_s` has passed; whether it held."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() >= deadline:
            return False
        time.sleep(period_s)
    return True


def live_accuracy(bag: Path, result: LiveResult) -> LiveAccuracy | None:
    """The published bodies of `result` against the bag's ground truth (None without any): each document's
    stamp less the player's offset is a frame of the bag; its people are matched by id."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    from smplify3d_ros.eval.truth import GROUND_TRUTH_TOPIC, parse_truth_document

    if result.offset_ns is None or not result.joints:
        return None
    wanted = {stamp - result.offset_ns: joints for stamp, joints in result.joints.items()}
    frames = people = missed = 0
    error_sum = 0.0
    typestore = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == GROUND_TRUTH_TOPIC]
        for conn, _, raw in reader.messages(connections=conns):
            truth = parse_truth_document(typestore.deserialize_cdr(raw, conn.msgtype).data)
            fitted = wanted.get(truth.stamp_ns)
            if fitted is None:
                continue
            frames += 1
            for body in truth.bodies:
                if body.keypoints3d is None or body.detected is False:
                    continue
                if body.person_id not in fitted:
                    missed += 1
                    continue
                people += 1
                error_sum += float(np.linalg.norm(fitted[body.person_id] - body.keypoints3d, axis=1).mean())
    if frames == 0:
        return None
    return LiveAccuracy(frames, people, missed, 1000.0 * error_sum / people if people else float("nan"))


def _parameter(text: str) -> tuple[str, Any]:
    import yaml

    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE (a ROS parameter of the node), got {text!r}")
    return key, yaml.safe_load(value)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("bag", type=Path, metavar="BAG", help="rosbag2 recording (directory, .mcap or .db3)")
    parser.add_argument("--params", metavar="PROFILE", default=None, help="params profile of the node")
    parser.add_argument("-p", dest="parameters", type=_parameter, action="append", default=[],
                        metavar="NAME=VALUE", help="a ROS parameter of the node (repeatable)")
    parser.add_argument("--speed", type=at_least(0.0, float, strict=True), default=1.0,
                        help="playback speed (1: the recorded rate)")
    parser.add_argument("--settle", type=at_least(0.0, float), default=3.0,
                        help="seconds to wait after the last message")
    parser.add_argument("--json", type=Path, default=None, help="write the figures to this JSON file")
    parser.add_argument("--in-process-player", action="store_true",
                        help="play the bag in the node's process (default: a process of its own, as sensor drivers)")


def run(args: argparse.Namespace) -> int:
    try:
        import rclpy  # noqa: F401
    except ImportError:
        print("smplify3d bench-live: needs rclpy (a ROS 2 install or the ros-jazzy-rclpy wheel)", file=sys.stderr)
        return 2
    if not args.bag.exists():
        print(f"smplify3d bench-live: {args.bag} does not exist", file=sys.stderr)
        return 2
    try:
        result = run_live(args.bag, args.params, dict(args.parameters), args.speed, args.settle,
                          args.in_process_player)
    except RuntimeError as e:  # the player process failed (it said why on stderr)
        print(f"smplify3d bench-live: {e}", file=sys.stderr)
        return 1
    print(result.text())
    if result.frames_played == 0:
        print(f"smplify3d bench-live: {args.bag}: no image frames were played (the node's image topic is not "
              "in the bag; see -p topics.image=... or topics.compressed_image=...)", file=sys.stderr)
    if args.json is not None:
        lat = result.latencies_ms
        args.json.write_text(json.dumps({
            "bag": str(args.bag), "player": "in-process" if args.in_process_player else "process",
            "frames_played": result.frames_played, "duration_s": result.duration_s,
            "bodies_received": len(result.bodies),
            "rate_hz": len(result.bodies) / result.duration_s if result.duration_s else None,
            "latency_ms_median": float(np.median(lat)) if len(lat) else None,
            "latency_ms_p95": float(np.percentile(lat, 95)) if len(lat) else None,
            "accuracy": None if result.accuracy is None else dataclasses.asdict(result.accuracy),
            "diagnostics": result.diagnostics,
        }, indent=1))
    return 0 if result.bodies else 1


if __name__ == "__main__" and sys.argv[1:2] == ["--play"]:
    sys.exit(play_main(sys.argv[2:]))
