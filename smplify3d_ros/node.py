"""The ROS 2 node: parameters, subscriptions, synchronization, a fitting worker, publishers.

Wiring only: messages are synchronized here (`runtime.sync`, the replay's synchronizer) and handed to a
worker thread, which runs the step shared with replay (`runtime.processor.MessageProcessor`: convert,
the core frame path, output messages); the node publishes what comes back. The worker's queue is
bounded (`worker_queue_size`, latest-frame policy): when fitting is slower than the sensors, older
frames are dropped and counted, never queued without bound.

Parameters: `params_file` names a profile (`jackal_vlp16`, `ouster64`, ...) or a YAML path; every key of
its `node` section is declared as a ROS parameter of the same dotted name (`sync.slop_s`), every key of
its `people` section as `people.<key>`, and so are `fitting.body.model`, `fitting.profile` and
`fitting.device`. ROS parameters (command line, launch file) override the profile; the result is
validated like any configuration (errors name the key).
"""

from __future__ import annotations

import re
import sys
import threading
import time
from collections import deque
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
from rclpy.node import Node

from msg_adapters.factory import RclpyFactory
from smplify3d_ros.config import Config, ConfigError, load_config, params_dir, resolve_profile, to_dict
from smplify3d_ros.runtime.config import NodeConfig, load_node_config
from smplify3d_ros.runtime.messages import FrameMessages
from smplify3d_ros.runtime.outputs import DIAGNOSTICS_TYPE, NODE_NAME, OUTPUT_TYPES, OUTPUTS
from smplify3d_ros.runtime.processor import MessageProcessor
from smplify3d_ros.runtime.stats import DiagnosticsReporter
from smplify3d_ros.runtime.sync import make_synchronizer, sync_values
from smplify3d_ros.runtime.transforms import Transforms, transform_msg_matrix

FITTING_PARAMETERS = ("fitting.body.model", "fitting.profile", "fitting.device")
CORE_PARAMETER_SECTIONS = ("people",)  # core sections declared whole as ROS parameters


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
    """ROS parameter name -> value: the node section's keys, and the core keys exposed to ROS."""
    values = flatten(to_dict(node))
    fitting = flatten(to_dict(config.fitting), "fitting.")
    values.update({name: fitting[name] for name in FITTING_PARAMETERS})
    for name in CORE_PARAMETER_SECTIONS:
        values.update(flatten(to_dict(getattr(config, name)), f"{name}."))
    return values


def parameter_descriptions() -> dict[str, str]:
    base = params_dir() / "base"
    out = yaml_comments(base / "node.yaml")
    for name in ("fitting", *CORE_PARAMETER_SECTIONS):
        out.update({f"{name}.{k}": v for k, v in yaml_comments(base / f"{name}.yaml").items()})
    return out


def overrides_from_parameters(values: dict[str, Any]) -> dict[str, Any]:
    """ROS parameter values -> a `load_sections` overrides mapping (sections fitting, people, node)."""
    core = ("fitting", *CORE_PARAMETER_SECTIONS)
    out: dict[str, Any] = {"node": unflatten({k: v for k, v in values.items() if k.split(".")[0] not in core})}
    for name in core:
        out[name] = unflatten({k[len(name) + 1:]: v for k, v in values.items() if k.split(".")[0] == name})
    return out


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
        super().__init__(NODE_NAME, **kwargs)
        self.config, self.node_config = self._load_config()
        self.factory = RclpyFactory()
        node_cfg = self.node_config
        self.get_logger().info(
            f"body model {self.config.fitting.body.model}, optimizer profile {self.config.fitting.profile}, "
            f"device {self.config.fitting.device}; loading the body model")
        self.processor = MessageProcessor(self.config, node_cfg, self.factory, fitter=fitter,
                                          transforms=self._transforms(), log=self.get_logger())
        self._output_pubs = {
            name: self.create_publisher(self.factory.message_class(OUTPUT_TYPES[name]), f"~/{name}", 10)
            for name in OUTPUTS if getattr(node_cfg.publish, name)
        }
        self._diagnostics_pub = self.create_publisher(
            self.factory.message_class(DIAGNOSTICS_TYPE), "/diagnostics", 10)
        self._reporter = DiagnosticsReporter(f"{self.get_name()}: fitting", "smplify3d_ros")
        self._processor_values: dict[str, Any] = self.processor.stats.values()
        self._queue = FrameQueue(node_cfg.worker_queue_size)
        self._stopping = threading.Event()
        self.worker_errors = 0
        self._inputs: list[tuple[str, str]] = []  # (name, topic)
        self._received: dict[str, int] = {}
        self._last_rates: tuple[float, dict[str, int]] = (time.monotonic(), {})
        self._subscribe()
        self._worker = threading.Thread(target=self._work, name="smplify3d_fitting", daemon=True)
        self._worker.start()
        self._timer = self.create_timer(node_cfg.diagnostics_period_s, self._publish_diagnostics)
        self.get_logger().info(
            "ready: " + ", ".join(f"{name} <- {topic}" for name, topic in self._inputs)
            + f"; sync {type(self.sync).__name__}")

    # -- set-up -------------------------------------------------------------------------------------------
    def _load_config(self) -> tuple[Config, NodeConfig]:
        from rcl_interfaces.msg import ParameterDescriptor

        default_profile = "jackal_vlp16"
        profile = self.declare_parameter(
            "params_file", default_profile,
            ParameterDescriptor(description="params profile name (params/<name>.yaml) or path to a profile YAML",
                                read_only=True)).value
        try:
            resolve_profile(profile)
            config, node = load_config(profile), load_node_config(profile)
        except ConfigError as e:
            raise ConfigError(f"params_file {profile!r}: {e}") from None
        descriptions = parameter_descriptions()
        values = {}
        for name, default in parameter_defaults(config, node).items():
            descriptor = ParameterDescriptor(description=descriptions.get(name, ""), read_only=True)
            try:
                values[name] = self.declare_parameter(name, default, descriptor).value
            except Exception as e:  # noqa: BLE001 - rclpy raises several types for a bad override
                raise ConfigError(f"parameter {name!r}: {e}") from None
        overrides = overrides_from_parameters(values)
        return load_config(profile, overrides), load_node_config(profile, overrides)

    def _transforms(self) -> Transforms:
        ext = self.node_config.extrinsic
        lookup = None
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

    def _tf_lookup(self, target: str, source: str, stamp_ns: int) -> np.ndarray | None:
        import tf2_ros
        from rclpy.duration import Duration
        from rclpy.time import Time

        try:
            t = self._tf_buffer.lookup_transform(
                target, source, Time(), timeout=Duration(seconds=self.node_config.extrinsic.tf_timeout_s))
        except tf2_ros.TransformException:
            return None
        return transform_msg_matrix(t)

    def _subscribe(self) -> None:
        from rclpy.qos import qos_profile_sensor_data

        cfg = self.node_config
        topics = cfg.topics
        msg = self.factory.message_class
        inputs: list[tuple[str, str, type]] = []
        if topics.image_topic:
            image_type = "sensor_msgs/msg/CompressedImage" if topics.compressed else "sensor_msgs/msg/Image"
            inputs.append(("image", topics.image_topic, msg(image_type)))
        inputs += [
            ("camera_info", topics.camera_info, msg("sensor_msgs/msg/CameraInfo")),
            ("points", topics.points, msg("sensor_msgs/msg/PointCloud2")),
            ("keypoints", topics.keypoints, msg("sensor_msgs/msg/PointCloud2")),
        ]
        self._inputs = [(name, topic) for name, topic, _ in inputs]
        self._received = {name: 0 for name, _ in self._inputs}
        names = [name for name, _, _ in inputs]
        self.sync = make_synchronizer(len(inputs), cfg.sync.slop_s, cfg.sync.queue_size,
                                      partial(self._on_synced, names), cfg.sync.use_message_filters,
                                      self.get_logger())
        self._subscriptions_in = [
            self.create_subscription(cls, topic, partial(self._on_input, i, name), qos_profile_sensor_data)
            for i, (name, topic, cls) in enumerate(inputs)
        ]
        if topics.init_bodies:
            self._received["init_bodies"] = 0
            self._inputs.append(("init_bodies", topics.init_bodies))
            self._init_sub = self.create_subscription(
                msg("std_msgs/msg/String"), topics.init_bodies, self._on_init_bodies, 10)

    # -- callbacks (keep short: count, hand off) ----------------------------------------------------------
    def _on_input(self, index: int, name: str, msg: Any) -> None:
        self._received[name] += 1
        try:
            self.sync.add(index, msg)
        except Exception as e:  # noqa: BLE001 - a message without a usable header must not stop spinning
            self.processor.stats.drops["bad_stamp"] += 1
            self.get_logger().warning(f"{name}: dropped a message without a usable stamp ({type(e).__name__})")

    def _on_init_bodies(self, msg: Any) -> None:
        self._received["init_bodies"] += 1
        self.processor.add_init_bodies(msg)

    def _on_synced(self, names: list[str], *msgs: Any) -> None:
        by_name = dict(zip(names, msgs, strict=True))
        self._queue.put(FrameMessages(
            camera_info=by_name["camera_info"], points=by_name["points"], keypoints=by_name["keypoints"],
            image=by_name.get("image"), compressed=self.node_config.topics.compressed,
            received_s=time.monotonic(),
        ))

    # -- the worker ---------------------------------------------------------------------------------------
    def _work(self) -> None:
        while not self._stopping.is_set():
            msgs = self._queue.get(timeout=0.2)
            if msgs is None:
                continue
            try:
                self.processor.stats.record("queue", time.monotonic() - msgs.received_s)
                result = self.processor.process(msgs)  # never raises for bad input
                self._processor_values = self.processor.stats.values()
                if self._stopping.is_set():
                    break
                for name, out in result.outputs.items():
                    self._publish(self._output_pubs.get(name), out)
            except Exception as e:  # noqa: BLE001 - keep the worker alive whatever happens
                self.worker_errors += 1
                self.get_logger().error(f"fitting worker: {type(e).__name__}: {e}")

    def _publish(self, publisher: Any, msg: Any) -> None:
        if publisher is None:
            return
        try:
            publisher.publish(msg)
        except Exception:
            if not self._stopping.is_set():
                raise

    # -- diagnostics --------------------------------------------------------------------------------------
    def input_rates(self) -> dict[str, float]:
        now = time.monotonic()
        last_t, last = self._last_rates
        counts = dict(self._received)
        dt = max(now - last_t, 1e-9)
        self._last_rates = (now, counts)
        return {name: (n - last.get(name, 0)) / dt for name, n in counts.items()}

    def diagnostic_values(self) -> dict[str, Any]:
        values: dict[str, Any] = {f"rate_hz.{name}": rate for name, rate in self.input_rates().items()}
        values.update({f"received.{name}": n for name, n in self._received.items()})
        values.update(sync_values(self.sync))
        values["queue.dropped_stale"] = self._queue.dropped
        values["worker_errors"] = self.worker_errors
        values["queue.length"] = len(self._queue)
        values.update(self._processor_values)
        return values

    def _publish_diagnostics(self) -> None:
        msg = self._reporter.message(self.get_clock().now().to_msg(), self.diagnostic_values(), self.factory)
        self._publish(self._diagnostics_pub, msg)

    # -- shutdown -----------------------------------------------------------------------------------------
    def destroy_node(self) -> None:
        self._stopping.set()
        self._queue.close()
        if self._worker.is_alive() and self._worker is not threading.current_thread():
            self._worker.join(timeout=10.0)
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
