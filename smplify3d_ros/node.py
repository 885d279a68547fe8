"""The ROS 2 node: parameters, subscriptions, synchronization, a fitting worker, publishers.

Wiring only: messages are synchronized here (`runtime.sync`, the replay's synchronizer) and handed to a
worker thread, which runs the step shared with replay (`runtime.processor.MessageProcessor`: convert,
the core frame path, output messages); the node publishes what comes back. The worker's queue is
bounded (`worker_queue_size`, latest-frame policy): when fitting is slower than the sensors, older
frames are dropped and counted, never queued without bound. Every subscription callback counts a
message it cannot handle under its input's name; none raises.

Parameters: `params_file` names a profile (`jackal_vlp16`, `ouster64`, ...) or a YAML path; every key of
its `node`, `fitting`, `lidar` and `people` sections is a ROS parameter of the same dotted name
(`sync.slop_s`, `lidar.max_range_m`), read-only, with its comment from params/base/*.yaml as description
and its range (runtime/config.py PARAMETER_RANGES). ROS parameters (command line, `--params-file`, launch
file) override the profile; the result is validated like any configuration before anything is declared
(errors name the key); an integer is taken for a double; names the node does not have are warned about.

Optional ROS packages, used when importable: tf2_ros (TF lookups at the image's stamp), tf2_msgs (the
extrinsic on /tf_static, body frames on /tf), message_filters (its synchronizer), hri_msgs (REP-155's
tracked list and skeletons, the Skeleton2D keypoint input). Without them the node says so in its log.
"""

from __future__ import annotations

import array
import difflib
import re
import sys
import threading
import time
from collections import Counter, deque
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.node import Node

from msg_adapters import clip
from msg_adapters.factory import RclpyFactory
from msg_adapters.hri import BodyIds, has_type, skeletons_to_keypoints
from msg_adapters.keypoints import write_keypoints
from smplify3d_ros.config import Config, ConfigError, load_config, params_dir, resolve_profile, to_dict
from smplify3d_ros.runtime.config import NodeConfig, load_node_config, parameter_range
from smplify3d_ros.runtime.messages import FrameMessages
from smplify3d_ros.runtime.outputs import DIAGNOSTICS_TYPE, NODE_NAME, OUTPUT_TYPES, OUTPUTS, output_type
from smplify3d_ros.runtime.stats import DiagnosticsReporter, InputCheck, InputMonitor, LogLimiter, input_level
from smplify3d_ros.runtime.sync import SkeletonAssembler, SkeletonSet, make_synchronizer, sync_values
from smplify3d_ros.runtime.transforms import (
    TF_STATIC_TOPIC,
    TF_TOPIC,
    Transforms,
    TransformUnavailable,
    extrinsic_tf_message,
    transform_msg_matrix,
)

CORE_PARAMETER_SECTIONS = ("fitting", "lidar", "people", "tracking")  # core sections declared whole as ROS parameters
TOPIC_TOKEN = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")  # one token of a ROS 2 topic name (a REP-155 id)
RCLPY_PARAMETERS = {"use_sim_time", "start_type_description_service"}  # declared by rclpy's Node itself


# -- parameters -------------------------------------------------------------------------------------------
def yaml_comments(path: Path) -> dict[str, str]:
    """Dotted key -> the one-line comment of that key in a params YAML file (`key: value  # comment`)."""
    comments: dict[str, str] = {}
    stack: list[tuple[int, str]] = []
    pattern = re.compile(r"^(\s*)([A-Za-z_][\w]*):\s*(.*)$")
    for line in path.read_text(encoding="utf-8").splitlines():
        m = pattern.match(line)
        if not m:
            continue
        indent, key, rest = len(m.group(1)), m.group(2), m.group(3)
        while stack and stack[-1][0] >= indent:
            stack.pop()
        stack.append((indent, key))
        if "#" in rest:
            comments[".".join(k for _, k in stack)] = rest.split("#", 1)[1].strip()
    return comments


def flatten(values: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in values.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten(value, name + "."))
        else:
            out[name] = list(value) if isinstance(value, tuple) else value
    return out


def unflatten(values: dict[str, Any]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for name, value in values.items():
        *parents, leaf = name.split(".")
        node = out
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = value
    return out


def parameter_defaults(config: Config, node: NodeConfig) -> dict[str, Any]:
    """ROS parameter name -> value: every key of the node section and of the core sections."""
    values = flatten(to_dict(node))
    for name in CORE_PARAMETER_SECTIONS:
        values.update(flatten(to_dict(getattr(config, name)), f"{name}."))
    return values


def parameter_descriptions() -> dict[str, str]:
    base = params_dir() / "base"
    out = yaml_comments(base / "node.yaml")
    for name in CORE_PARAMETER_SECTIONS:
        out.update({f"{name}.{k}": v for k, v in yaml_comments(base / f"{name}.yaml").items()})
    return out


def overrides_from_parameters(values: dict[str, Any]) -> dict[str, Any]:
    """ROS parameter values -> a `load_sections` overrides mapping (the core sections and node)."""
    core = CORE_PARAMETER_SECTIONS
    out: dict[str, Any] = {"node": unflatten({k: v for k, v in values.items() if k.split(".")[0] not in core})}
    for name in core:
        out[name] = unflatten({k[len(name) + 1:]: v for k, v in values.items() if k.split(".")[0] == name})
    return out


def coerce_override(value: Any, default: Any) -> Any:
    """A ROS parameter override in the type of its default where that loses nothing: `-p sync.slop_s:=1`
    parses as an integer, and rclpy would refuse it for a double parameter."""
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(default, list) and default and all(isinstance(v, float) for v in default):
        items = list(value) if isinstance(value, (list, tuple, array.array)) else None
        if items is not None and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in items):
            return [float(v) for v in items]
    return value


def descriptor_for(name: str, default: Any, description: str) -> Any:
    """A read-only ParameterDescriptor with the key's comment and, for numbers, its range."""
    from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

    descriptor = ParameterDescriptor(description=description, read_only=True)
    bounds = parameter_range(name)
    if bounds is None or isinstance(default, bool):
        return descriptor
    low, high = bounds
    if isinstance(default, float):
        descriptor.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=float(high))]
    elif isinstance(default, int):  # step 0: no step constraint
        descriptor.integer_range = [IntegerRange(from_value=_int64(low), to_value=_int64(high), step=0)]
    return descriptor


def _int64(value: float) -> int:
    """An IntegerRange bound (int64): infinite bounds become the int64 limits."""
    return int(max(min(value, 2**63 - 1), -(2**63)))


def unknown_parameter_warning(unknown: list[str], known: list[str]) -> str:
    """One log line naming parameters the node does not have, with the nearest known names."""
    parts = []
    for name in sorted(unknown):
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.75)
        parts.append(clip(name, 80) + (f" (did you mean {close[0]}?)" if close else ""))
    return "unknown parameter(s), ignored: " + ", ".join(parts)


class TopicPublishers:
    """Publishers of the absolute output topics (REP-155 per-body topics, /tf), made on first use. Those
    of a body unseen for `forget_after_s` are destroyed, so that the graph does not grow with every id.
    Used from the worker thread only."""

    PERSISTENT = ("/tracked", TF_TOPIC)  # not per body: kept

    def __init__(self, node: Node, forget_after_s: float) -> None:
        self.node = node
        self.forget_after_s = forget_after_s
        self._pubs: dict[str, tuple[Any, float]] = {}  # topic -> (publisher, last use, monotonic)

    def get(self, topic: str) -> Any:
        if not topic.startswith("/"):
            return None  # a node-relative output that is switched off
        entry = self._pubs.get(topic)
        publisher = entry[0] if entry else self.node.create_publisher(
            self.node.factory.message_class(output_type(topic)), topic, 10)
        self._pubs[topic] = (publisher, time.monotonic())
        return publisher

    def forget_stale(self) -> None:
        now = time.monotonic()
        for topic, (publisher, used) in list(self._pubs.items()):
            if now - used > self.forget_after_s and not topic.endswith(self.PERSISTENT):
                del self._pubs[topic]
                self.node.destroy_publisher(publisher)

    def topics(self) -> list[str]:
        return sorted(self._pubs)


def camera_frame_parent(buffer: Any, frame: str) -> str | None:
    """The TF parent of `frame` in a tf2_ros Buffer (None: TF does not know the frame)."""
    import yaml

    try:
        frames = yaml.safe_load(buffer.all_frames_as_yaml()) or {}
    except Exception:  # noqa: BLE001 - an unreadable dump means: unknown
        return None
    entry = frames.get(frame) if isinstance(frames, dict) else None
    return str(entry.get("parent")) if isinstance(entry, dict) and entry.get("parent") else None


def input_qos(cfg: Any) -> Any:
    """rclpy QoSProfile of one input's `qos.<name>` settings (keep-last history, volatile)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    reliability = ReliabilityPolicy.RELIABLE if cfg.reliability == "reliable" else ReliabilityPolicy.BEST_EFFORT
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=cfg.depth, reliability=reliability,
                      durability=DurabilityPolicy.VOLATILE)


# -- the node ---------------------------------------------------------------------------------------------
class FrameQueue:
    """Bounded hand-off between the synchronizer and the worker: a full queue drops its oldest frame."""

    def __init__(self, maxsize: int) -> None:
        self.maxsize = maxsize
        self._items: deque[FrameMessages] = deque()
        self._cond = threading.Condition()
        self.dropped = 0
        self.closed = False

    def put(self, item: FrameMessages) -> None:
        with self._cond:
            if len(self._items) >= self.maxsize:
                self._items.popleft()
                self.dropped += 1
            self._items.append(item)
            self._cond.notify()

    def get(self, timeout: float) -> FrameMessages | None:
        with self._cond:
            self._cond.wait_for(lambda: self._items or self.closed, timeout)
            return self._items.popleft() if self._items and not self.closed else None

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._items.clear()
            self._cond.notify_all()

    def __len__(self) -> int:
        with self._cond:
            return len(self._items)


class Smplify3dNode(Node):
    """See the module docstring. `fitter` reuses a loaded `Fitter` (tests, embedding: it must match the
    node's fitting configuration); other keyword arguments go to rclpy's Node (`parameter_overrides`)."""

    def __init__(self, fitter: Any = None, **kwargs: Any) -> None:
        # every -p / --params-file entry is declared first, so that names the node does not have are seen
        # (and warned about) instead of silently ignored; _load_config re-declares the known ones typed
        super().__init__(NODE_NAME, automatically_declare_parameters_from_overrides=True, **kwargs)
        self.config, self.node_config = self._load_config()
        from smplify3d_ros.runtime.heap import freeze_startup_heap
        from smplify3d_ros.runtime.processor import MessageProcessor  # torch: once the parameters are valid

        self.factory = RclpyFactory()
        node_cfg = self.node_config
        self.get_logger().info(
            f"body model {self.config.fitting.body.model}, optimizer profile {self.config.fitting.profile}, "
            f"device {self.config.fitting.device}; loading the body model")
        self.processor = MessageProcessor(self.config, node_cfg, self.factory, fitter=fitter,
                                          transforms=self._transforms(), log=self.get_logger())
        self.processor.frames.start_background()  # the refreshes' process loads its model while we set up
        self._output_pubs = {
            name: self.create_publisher(self.factory.message_class(OUTPUT_TYPES[name]), f"~/{name}", 10)
            for name in OUTPUTS if getattr(node_cfg.publish, name)
        }
        if node_cfg.publish.lazy:
            self.processor.skip_outputs = self._unsubscribed_outputs
        self._topic_pubs = TopicPublishers(self, node_cfg.publish.hri_forget_after_s)
        self._start_hri_outputs()
        self._diagnostics_pub = self.create_publisher(
            self.factory.message_class(DIAGNOSTICS_TYPE), "/diagnostics", 10)
        self._reporter = DiagnosticsReporter(f"{self.get_name()}: fitting", "smplify3d_ros")
        self._processor_values: dict[str, Any] = self.processor.stats.values()
        self._queue = FrameQueue(node_cfg.worker_queue_size)
        self._stopping = threading.Event()
        self.worker_errors = 0
        self._inputs: list[tuple[str, str]] = []  # (name, topic)
        self._logs = LogLimiter(self.get_logger())
        self.qos_incompatible: Counter = Counter()  # publishers per input whose QoS cannot match ours
        # ready before any frame, and before the inputs are subscribed: their rates count from then on
        self.processor.frames.start_background(wait=True)
        self._subscribe()
        self._start_extrinsic_tf()
        freeze_startup_heap()  # the body model and torch out of the collector's walks (runtime/heap.py)
        self._worker = threading.Thread(target=self._work, name="smplify3d_fitting", daemon=True)
        self._worker.start()
        self._timer = self.create_timer(node_cfg.diagnostics_period_s, self._publish_diagnostics)
        self.get_logger().info(
            "ready: " + ", ".join(f"{name} <- {topic}" for name, topic in self._inputs)
            + f"; sync {type(self.sync).__name__}")

    # -- set-up -------------------------------------------------------------------------------------------
    def _take_overrides(self) -> dict[str, Any]:
        """Name -> value of every parameter override (command line, params files, `parameter_overrides`),
        undeclared again so that `_load_config` can declare the node's own with their types and ranges."""
        overrides = {}
        for name, parameter in self.get_parameters_by_prefix("").items():
            if name not in RCLPY_PARAMETERS:
                overrides[name] = parameter.value
                self.undeclare_parameter(name)
        return overrides

    def _load_config(self) -> tuple[Config, NodeConfig]:
        from rcl_interfaces.msg import ParameterDescriptor

        overrides = self._take_overrides()
        profile = overrides.pop("params_file", "jackal_vlp16")
        self.declare_parameter("params_file", profile, ParameterDescriptor(
            description="params profile name (params/<name>.yaml) or path to a profile YAML", read_only=True))
        try:
            resolve_profile(profile)
            defaults = parameter_defaults(load_config(profile), load_node_config(profile))
        except ConfigError as e:
            raise ConfigError(f"params_file {clip(profile)!r}: {e}") from None
        values = {name: coerce_override(overrides.pop(name, default), default) for name, default in defaults.items()}
        # validated before declaring: a bad value is a configuration error that names the key and the rule
        sections = overrides_from_parameters(values)
        config, node = load_config(profile, sections), load_node_config(profile, sections)
        descriptions = parameter_descriptions()
        for name, value in values.items():
            try:
                self.declare_parameter(name, value, descriptor_for(name, defaults[name], descriptions.get(name, "")),
                                       ignore_override=True)
            except Exception as e:  # noqa: BLE001 - rclpy raises several types for a bad value
                raise ConfigError(f"parameter {name!r}: {clip(e)}") from None
        if overrides:
            self.get_logger().warning(unknown_parameter_warning(list(overrides), list(defaults)))
        return config, node

    def _transforms(self) -> Transforms:
        ext = self.node_config.extrinsic
        lookup = None
        self._tf_buffer = None
        if ext.use_tf:
            try:
                import tf2_ros
            except ImportError:
                self.get_logger().info("tf2_ros is not installed: using the extrinsic parameters")
            else:
                self._tf_buffer = tf2_ros.Buffer()
                self._tf_listener = tf2_ros.TransformListener(self._tf_buffer, self)
                lookup = self._tf_lookup
        return Transforms(ext, lookup, log=self.get_logger())

    def _tf_lookup(self, target: str, source: str, stamp_ns: int, source_stamp_ns: int | None = None,
                   fixed_frame: str | None = None) -> np.ndarray | None:
        """TF at the image's stamp, waiting up to `extrinsic.tf_timeout_s` (the worker thread waits; the
        listener fills the buffer from the executor). None: TF does not know the frames; raises
        TransformUnavailable when it knows them but not at that time (see runtime/transforms.py)."""
        import tf2_ros
        from rclpy.duration import Duration
        from rclpy.time import Time

        timeout = Duration(seconds=self.node_config.extrinsic.tf_timeout_s)
        at = Time(nanoseconds=stamp_ns, clock_type=self.get_clock().clock_type)
        try:
            if fixed_frame:
                source_at = Time(nanoseconds=source_stamp_ns, clock_type=at.clock_type)
                t = self._tf_buffer.lookup_transform_full(target, at, source, source_at, fixed_frame, timeout)
            else:
                t = self._tf_buffer.lookup_transform(target, source, at, timeout=timeout)
        except (tf2_ros.LookupException, tf2_ros.ConnectivityException):
            return None
        except tf2_ros.TransformException as e:  # extrapolation, timeout: known frames, not at that time
            raise TransformUnavailable(f"TF {clip(source)} -> {clip(target)} at {stamp_ns * 1e-9:.3f} s: "
                                       f"{clip(e)}") from None
        return transform_msg_matrix(t)

    def _start_hri_outputs(self) -> None:
        """Say which ROS4HRI outputs this install can publish: hri_msgs and tf2_msgs are optional."""
        if not self.node_config.publish.hri:
            return
        outputs = self.processor.outputs
        if not outputs.hri_msgs:
            self.get_logger().info("hri_msgs (ROS4HRI) is not installed: "
                                   f"{outputs.hri.namespace}/tracked and <id>/skeleton2d are not published")
        outputs.hri.tf_frames = has_type(self.factory, "tf2_msgs/msg/TFMessage")
        if not outputs.hri.tf_frames:
            self.get_logger().info("tf2_msgs is not installed: no body_<id> frames on /tf")

    def _start_extrinsic_tf(self) -> None:
        """`extrinsic.publish_tf`: the parameter extrinsic on /tf_static (tf2_msgs needed). With tf2_ros the
        node first watches TF for `publish_tf_wait_s`: a camera frame that already has a parent (the robot's
        URDF, the camera driver) is left alone, since a TF frame has one parent."""
        ext = self.node_config.extrinsic
        self._static_tf_pub = None
        if not ext.publish_tf:
            return
        if not has_type(self.factory, "tf2_msgs/msg/TFMessage"):
            self.get_logger().info("tf2_msgs is not installed: the extrinsic parameters are not published on "
                                   "/tf_static (extrinsic.publish_tf)")
            return
        cls = self.factory.message_class("tf2_msgs/msg/TFMessage")
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)  # as tf2's static broadcaster
        self._static_tf_pub = self.create_publisher(cls, TF_STATIC_TOPIC, latched)
        if self._tf_buffer is None or ext.publish_tf_wait_s == 0:
            self._publish_extrinsic_tf()
        else:
            self._static_tf_timer = self.create_timer(ext.publish_tf_wait_s, self._publish_extrinsic_tf_once)

    def _publish_extrinsic_tf_once(self) -> None:
        self._static_tf_timer.cancel()
        ext = self.node_config.extrinsic
        parent = camera_frame_parent(self._tf_buffer, ext.camera_frame)
        if parent is not None and parent != ext.lidar_frame:
            self.get_logger().info(f"TF already gives {ext.camera_frame!r} a parent ({clip(parent)!r}): the "
                                   "extrinsic parameters are not published on /tf_static")
            return
        self._publish_extrinsic_tf()

    def _publish_extrinsic_tf(self) -> None:
        ext = self.node_config.extrinsic
        self._publish(self._static_tf_pub, extrinsic_tf_message(ext, self.get_clock().now().to_msg(), self.factory))
        self.get_logger().info(f"published the extrinsic parameters on /tf_static: {ext.lidar_frame} -> "
                               f"{ext.camera_frame}")

    def _synchronized_inputs(self) -> list[tuple[str, str, type]]:
        """(name, topic, message class) of the synchronized inputs, in the synchronizer's order. With
        `keypoint_input: skeleton2d` the keypoints come from `<topics.hri_bodies>/tracked` and each listed
        body's `skeleton2d` (hri_msgs), joined per stamp into the keypoint encoding."""
        topics, msg = self.node_config.topics, self.factory.message_class
        inputs: list[tuple[str, str, type]] = []
        if topics.image_topic:
            image_type = "sensor_msgs/msg/CompressedImage" if topics.compressed else "sensor_msgs/msg/Image"
            inputs.append(("image", topics.image_topic, msg(image_type)))
        if self.node_config.keypoint_input == "skeleton2d":
            keypoints = ("keypoints", f"{topics.hri_bodies}/tracked", msg("hri_msgs/msg/IdsList"))
        else:
            keypoints = ("keypoints", topics.keypoints, msg("sensor_msgs/msg/PointCloud2"))
        return inputs + [
            ("camera_info", topics.camera_info, msg("sensor_msgs/msg/CameraInfo")),
            ("points", topics.points, msg("sensor_msgs/msg/PointCloud2")),
            keypoints,
        ]

    def _subscribe(self) -> None:
        cfg = self.node_config
        if cfg.keypoint_input == "skeleton2d" and not has_type(self.factory, "hri_msgs/msg/Skeleton2D"):
            raise ConfigError("keypoint_input skeleton2d needs hri_msgs (ROS4HRI), which is not installed")
        inputs = self._synchronized_inputs()
        self._inputs = [(name, topic) for name, topic, _ in inputs]
        if cfg.topics.init_bodies:
            self._inputs.append(("init_bodies", cfg.topics.init_bodies))
        self.monitor = InputMonitor([name for name, _ in self._inputs], cfg.diagnostics.rate_window_s)
        names = [name for name, _, _ in inputs]
        self.sync_names = names
        latest = [names.index("camera_info")] if cfg.sync.latest_camera_info else []
        self.sync = make_synchronizer(len(inputs), cfg.sync.slop_s, cfg.sync.queue_size,
                                      partial(self._on_synced, names), cfg.sync.use_message_filters,
                                      self.get_logger(), latest)
        self._subscriptions_in = [self._subscription(name, topic, cls, self._handler(i, name))
                                  for i, (name, topic, cls) in enumerate(inputs)]
        if cfg.topics.init_bodies:
            self._subscriptions_in.append(self._subscription(
                "init_bodies", cfg.topics.init_bodies, self.factory.message_class("std_msgs/msg/String"),
                self.processor.add_init_bodies))

    def _handler(self, index: int, name: str) -> Any:
        if name == "camera_info":
            return partial(self._on_camera_info, index)
        if name == "keypoints" and self.node_config.keypoint_input == "skeleton2d":
            self._skeletons = SkeletonAssembler(partial(self._on_skeleton_set, index))
            self._body_ids = BodyIds(self.node_config.publish.hri_id_prefix)
            self._body_subs: dict[str, tuple[Any, float]] = {}
            return self._on_tracked
        return partial(self._on_input, index)

    def _subscription(self, name: str, topic: str, cls: type, handle: Any, monitored: bool = True) -> Any:
        """A subscription with the input's QoS (`qos.<name>`) whose callback never raises (a bad message is
        counted under the input's name and logged, rate-limited)."""
        from rclpy.event_handler import SubscriptionEventCallbacks

        events = SubscriptionEventCallbacks(incompatible_qos=partial(self._on_incompatible_qos, name, topic))
        return self.create_subscription(cls, topic, partial(self._on_message, name, handle, monitored),
                                        input_qos(getattr(self.node_config.qos, name)), event_callbacks=events)

    # -- callbacks (keep short: count, hand off) ----------------------------------------------------------
    def _on_message(self, name: str, handle: Any, monitored: bool, msg: Any) -> None:
        if monitored:
            self.monitor.arrived(name)
        try:
            handle(msg)
        except Exception as e:  # noqa: BLE001 - a bad message must never stop spinning
            self.monitor.failed(name)
            self._logs.warning(f"bad.{name}", f"{name}: dropped a message that could not be handled: "
                               f"{type(e).__name__}: {clip(e)}")

    def _on_input(self, index: int, msg: Any) -> None:
        self.sync.add(index, msg)  # raises for a message without a usable header: counted by _on_message

    def _on_camera_info(self, index: int, msg: Any) -> None:
        self._image_size = (int(msg.width), int(msg.height))  # Skeleton2D points are normalized by it
        self.sync.add(index, msg)

    def _on_tracked(self, msg: Any) -> None:
        """`<hri_bodies>/tracked`: follow each listed body's skeleton2d, then hand the list on."""
        now, ns = time.monotonic(), self.node_config.topics.hri_bodies
        cls = self.factory.message_class("hri_msgs/msg/Skeleton2D")
        for bid in (str(i) for i in msg.ids):
            if bid not in self._body_subs and TOPIC_TOKEN.fullmatch(bid):
                self._body_subs[bid] = (self._subscription(
                    "keypoints", f"{ns}/{bid}/skeleton2d", cls, partial(self._skeletons.add_skeleton, bid),
                    monitored=False), now)
            elif bid in self._body_subs:
                self._body_subs[bid] = (self._body_subs[bid][0], now)
        for bid, (sub, seen) in list(self._body_subs.items()):
            if now - seen > self.node_config.publish.hri_forget_after_s:
                del self._body_subs[bid]
                self.destroy_subscription(sub)
        self._skeletons.add_tracked(msg)

    def _on_skeleton_set(self, index: int, skeletons: SkeletonSet) -> None:
        """A stamp's skeletons -> the keypoint encoding, into the synchronizer as the keypoints input."""
        size = getattr(self, "_image_size", None)
        if size is None:  # no camera info yet: normalized points cannot be placed
            self.monitor.failed("keypoints")
            return
        kp, ids = skeletons_to_keypoints(skeletons.skeletons, *size, self._body_ids)
        header = skeletons.header
        self.sync.add(index, write_keypoints(kp, ids, header.stamp, str(header.frame_id), self.factory,
                                             self.node_config.keypoint_format))

    def _on_incompatible_qos(self, name: str, topic: str, event: Any) -> None:
        self.qos_incompatible[name] += 1
        qos = getattr(self.node_config.qos, name)
        policy = getattr(getattr(event, "last_policy_kind", None), "name", "?")
        self.get_logger().warning(
            f"{topic}: a publisher offers a QoS incompatible with qos.{name} ({qos.reliability}, policy {policy}): "
            f"no messages from it. A best_effort publisher needs qos.{name}.reliability:=best_effort")

    def _on_synced(self, names: list[str], *msgs: Any) -> None:
        by_name = dict(zip(names, msgs, strict=True))
        frame = FrameMessages(
            camera_info=by_name["camera_info"], points=by_name["points"], keypoints=by_name["keypoints"],
            image=by_name.get("image"), compressed=self.node_config.topics.compressed,
            received_s=time.monotonic(),
        )
        try:  # how late the set was complete after its stamp: sensor, detector and transport delay
            frame.arrival_s = (self.get_clock().now().nanoseconds - frame.stamp_ns) * 1e-9
        except Exception:  # noqa: BLE001 - a header the worker counts as bad
            pass
        self._queue.put(frame)

    # -- the worker ---------------------------------------------------------------------------------------
    def _work(self) -> None:
        while not self._stopping.is_set():
            msgs = self._queue.get(timeout=0.2)
            if msgs is None:
                continue
            try:
                self.processor.stats.record("queue", time.monotonic() - msgs.received_s)
                if msgs.arrival_s is not None and msgs.arrival_s >= 0.0:  # the stats are the worker's alone
                    self.processor.stats.record("arrival", msgs.arrival_s)
                result = self.processor.process(msgs)  # never raises for bad input
                self._processor_values = self.processor.stats.values()
                if self._stopping.is_set():
                    break
                for name, out in result.outputs.items():
                    self._publish(self._output_pubs.get(name) or self._topic_pubs.get(name), out)
                self._topic_pubs.forget_stale()
            except Exception as e:  # noqa: BLE001 - keep the worker alive whatever happens
                self.worker_errors += 1
                self.get_logger().error(f"fitting worker: {type(e).__name__}: {clip(e)}")

    def _unsubscribed_outputs(self) -> list[str]:
        """The outputs nobody subscribes to now (publish.lazy): not built, as the mesh markers alone cost
        about 20 ms a frame with one person, 35 with three. A subscriber that comes gets the next frame's."""
        return [name for name, pub in self._output_pubs.items() if pub.get_subscription_count() == 0]

    def _publish(self, publisher: Any, msg: Any) -> None:
        if publisher is None:
            return
        try:
            publisher.publish(msg)
        except Exception:
            if not self._stopping.is_set():
                raise

    # -- diagnostics --------------------------------------------------------------------------------------
    def input_statuses(self, now: float) -> list[tuple[str, str, str, dict]]:
        """(name, level, message, values) of every input (`stats.input_level`)."""
        d = self.node_config.diagnostics
        return [(name, *input_level(self.monitor, name, InputCheck(
            topic, getattr(d.expected_hz, name), d.rate_tolerance, d.stale_after_s), now))
            for name, topic in self._inputs]

    def no_frame_reason(self, now: float) -> str | None:
        """Why no frame can be built now (a synchronized input silent), or None. An input the frames take
        the latest message of (the camera info) blocks them only until its first message."""
        stale = self.node_config.diagnostics.stale_after_s
        latest = {self.sync_names[i] for i in self.sync.latest_inputs}
        silent = [(name, self.monitor.silent_s(name, now)) for name in self.sync_names
                  if name not in latest or not self.monitor.received.get(name)]
        silent = [(name, s) for name, s in silent if s >= stale]
        if not silent:
            return None
        return ", ".join(f"{name} silent for {s:.1f} s" for name, s in silent)

    def diagnostic_values(self, now: float | None = None) -> dict[str, Any]:
        now = time.monotonic() if now is None else now
        monitor = self.monitor
        values: dict[str, Any] = {f"rate_hz.{name}": monitor.rate_hz(name, now) for name, _ in self._inputs}
        values.update({f"received.{name}": n for name, n in monitor.received.items()})
        values.update({f"bad_messages.{name}": n for name, n in sorted(monitor.errors.items())})
        values.update({f"qos_incompatible.{name}": n for name, n in sorted(self.qos_incompatible.items())})
        values.update(sync_values(self.sync))
        values["queue.dropped_stale"] = self._queue.dropped
        values["worker_errors"] = self.worker_errors
        values["queue.length"] = len(self._queue)
        values.update(self._processor_values)
        return values

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        msg = self._reporter.message(self.get_clock().now().to_msg(), self.diagnostic_values(now), self.factory,
                                     inputs=self.input_statuses(now), no_frame=self.no_frame_reason(now))
        self._publish(self._diagnostics_pub, msg)

    # -- shutdown -----------------------------------------------------------------------------------------
    def destroy_node(self) -> None:
        self._stopping.set()
        self._queue.close()
        if self._worker.is_alive() and self._worker is not threading.current_thread():
            self._worker.join(timeout=10.0)
        self.processor.frames.close()  # the background refreshes' process
        super().destroy_node()


def main(args: list[str] | None = None) -> int:
    """`smplify3d_node` entry point: spin until Ctrl-C (exit 0) or a configuration error (exit 2)."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = Smplify3dNode()
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as e:
        print(f"smplify3d_node: configuration error: {e}", file=sys.stderr)
        code = 2
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return code


def create_node(parameters: dict[str, Any] | None = None, **kwargs: Any) -> Smplify3dNode:
    """A node with ROS parameter overrides given as a dict (tests, embedding); rclpy must be initialized."""
    from rclpy.parameter import Parameter

    overrides = [Parameter(name, value=value) for name, value in (parameters or {}).items()]
    return Smplify3dNode(parameter_overrides=overrides, **kwargs)

if __name__ == "__main__":
    sys.exit(main())
