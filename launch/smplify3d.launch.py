"""Launch the SMPLify-3D node on the robot (ROS 2 Jazzy), optionally with RViz.

    ros2 launch smplify3d_ros smplify3d.launch.py
    ros2 launch smplify3d_ros smplify3d.launch.py params_file:=ouster64 rviz:=true
    ros2 launch smplify3d_ros smplify3d.launch.py namespace:=robot1 points:=velodyne_points rviz:=true
    ros2 launch smplify3d_ros smplify3d.launch.py ros_params_file:=/path/robot_params.yaml

`params_file` is a profile name (params/<name>.yaml in the package share) or a path to a profile YAML
(overrides on top of params/base/*.yaml). `ros_params_file` is a standard ROS 2 parameters file
(`/**: {ros__parameters: {topics.points: ...}}`, as for `--params-file`) applied on top of the profile.
The other arguments, when set, override both for one run; left empty, the value from the files holds.
Precedence: profile < ros_params_file < launch arguments. Arguments: `ros2 launch smplify3d_ros
smplify3d.launch.py --show-args`, or docs/robot.md.

With `rviz:=true` the bundled view (rviz/smplify3d.rviz, a template with ${...} placeholders) is rendered
at launch time with the topics the node really uses (profile, parameters file, arguments) and its
namespace, written to a temporary file and opened in RViz.

Everything up to the launch actions is plain Python (`launch_plan`), importable and tested without a ROS
install (test/test_launch.py); `launch` and `launch_ros` are imported only by the launch functions.
"""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

PACKAGE = "smplify3d_ros"
NODE_NAME = "smplify3d"
DEFAULT_PROFILE = "jackal_vlp16"
RVIZ_TEMPLATE = "smplify3d.rviz"

# (launch argument, node parameter, description): per-robot settings; empty keeps the files' value.
ARGUMENTS = [
    ("image", "topics.image", "sensor_msgs/Image topic"),
    ("compressed_image", "topics.compressed_image", "sensor_msgs/CompressedImage topic (instead of image)"),
    ("camera_info", "topics.camera_info", "sensor_msgs/CameraInfo topic"),
    ("points", "topics.points", "LiDAR sensor_msgs/PointCloud2 topic"),
    ("keypoints", "topics.keypoints", "2D keypoint PointCloud2 (u, v, score, person, joint)"),
    ("init_bodies", "topics.init_bodies", "std_msgs/String bodies JSON with initial estimates"),
    ("output_frame", "output_frame", "frame of the outputs (profile default: the camera optical frame)"),
    ("body_model", "fitting.body.model", "body model: anny or smpl"),
    ("fitting_profile", "fitting.profile", "optimizer profile: robot or thesis"),
    ("device", "fitting.device", "torch device: cpu, cuda or auto"),
]

# (launch argument, default, description): the arguments that are not node parameters of their own.
LAUNCH_ARGUMENTS = [
    ("params_file", DEFAULT_PROFILE, "profile name (params/<name>.yaml) or path to a profile YAML"),
    ("ros_params_file", "", "ROS 2 parameters YAML (ros__parameters) applied on top of the profile; "
                            "empty: none"),
    ("namespace", "", "node namespace: outputs on /<namespace>/smplify3d/..., relative input topics "
                      "resolved in it"),
    ("use_sim_time", "false", "use /clock (bag playback)"),
    ("rviz", "false", "start RViz with the bundled view, rendered for the node's topics and namespace"),
]

TOPIC_KEYS = ("image", "compressed_image", "camera_info", "points", "keypoints", "init_bodies")
OUTPUTS = ("markers", "joints", "body_points", "people", "bodies")  # the node's ~/<name> publishers
_PLACEHOLDER = re.compile(r"\$\{([a-z_]+)\}")


def profile_settings(profile: str) -> dict[str, Any]:
    """The input topics and frames of a profile (name or YAML path), from the package's config loader.

    The only call into smplify3d_ros from this file: when the loader's API changes, this is what to adapt.
    """
    from smplify3d_ros.runtime.config import load_node_config

    node = load_node_config(profile or None)
    return {
        "topics": {key: getattr(node.topics, key) for key in TOPIC_KEYS},
        "output_frame": node.output_frame,
        "camera_frame": node.extrinsic.camera_frame,
    }


def normalize_namespace(namespace: str) -> str:
    """'' -> '' (the root namespace); 'robot1', '/robot1/' -> '/robot1'."""
    namespace = namespace.strip().strip("/")
    return f"/{namespace}" if namespace else ""


def resolve_topic(topic: str, namespace: str, node_name: str = NODE_NAME) -> str:
    """The absolute name of `topic` for a node named `node_name` in `namespace` (ROS 2 name resolution):
    absolute names stay, `~/x` is the node's private name, anything else is relative to the namespace."""
    if topic == "":
        return ""
    ns = normalize_namespace(namespace)
    if topic.startswith("/"):
        return topic
    if topic == "~" or topic.startswith("~/"):
        return f"{ns}/{node_name}{topic[1:]}".rstrip("/")
    return f"{ns}/{topic}"


def read_ros_params(path: str | os.PathLike | None, namespace: str = "",
                    node_name: str = NODE_NAME) -> dict[str, Any]:
    """The parameters a ROS 2 parameters file gives the node, as dotted names (`topics.points`).

    Sections read: `/**`, `/**/<node name>`, the node name and its fully qualified name, in file order
    (later ones win); other wildcard patterns are not read here (the node itself still gets them).
    Nested dictionaries are flattened to dotted names, as ROS does.
    """
    if not path:
        return {}
    data = yaml.safe_load(Path(path).read_text()) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a ROS 2 parameters file maps node names to ros__parameters")
    fqn = f"{normalize_namespace(namespace)}/{node_name}"
    applies = {"/**", f"/**/{node_name}", node_name, fqn, fqn.lstrip("/")}
    values: dict[str, Any] = {}

    def flatten(d: Mapping[str, Any], prefix: str = "") -> None:
        for key, value in d.items():
            if isinstance(value, Mapping):
                flatten(value, f"{prefix}{key}.")
            else:
                values[f"{prefix}{key}"] = value

    for section, content in data.items():
        if str(section) in applies and isinstance(content, Mapping):
            flatten(content.get("ros__parameters") or {})
    return values


def effective_settings(profile: Mapping[str, Any], ros_params: Mapping[str, Any],
                       arguments: Mapping[str, str]) -> dict[str, Any]:
    """Topics and output frame as the node will use them: profile < ROS parameters file < launch arguments."""
    topics = dict(profile["topics"])
    output_frame = profile["output_frame"]
    for key in TOPIC_KEYS:
        if f"topics.{key}" in ros_params:
            topics[key] = str(ros_params[f"topics.{key}"])
        if arguments.get(key, "") != "":
            topics[key] = arguments[key]
    if "output_frame" in ros_params:
        output_frame = str(ros_params["output_frame"])
    if arguments.get("output_frame", "") != "":
        output_frame = arguments["output_frame"]
    camera_frame = str(ros_params.get("extrinsic.camera_frame", profile["camera_frame"]))
    return {"topics": topics, "output_frame": output_frame, "camera_frame": camera_frame}


def rviz_values(settings: Mapping[str, Any], namespace: str) -> dict[str, str]:
    """The value of each placeholder of the RViz template, for the node's settings and namespace."""
    topics = settings["topics"]
    image = resolve_topic(topics["image"], namespace)
    values = {
        "points": resolve_topic(topics["points"], namespace),
        "image": image,  # the Camera display shows raw images only; off when the node has none
        "camera_enabled": "true" if image else "false",
        # the outputs are published in output_frame; empty: the camera optical frame
        "fixed_frame": settings["output_frame"] or settings["camera_frame"],
    }
    values.update({name: resolve_topic(f"~/{name}", namespace) for name in OUTPUTS})
    return values


def render_rviz_config(template: str, values: Mapping[str, str]) -> str:
    """The template with each ${name} replaced; a placeholder without a value is an error."""
    missing = sorted({name for name in _PLACEHOLDER.findall(template) if name not in values})
    if missing:
        raise KeyError(f"RViz template placeholders without a value: {', '.join(missing)}")
    return _PLACEHOLDER.sub(lambda m: str(values[m.group(1)]), template)


def rviz_template_path() -> Path:
    """The RViz template: in the installed package share, else next to this file in a source checkout."""
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory(PACKAGE)) / "rviz" / RVIZ_TEMPLATE
        if path.is_file():
            return path
    except Exception:  # noqa: BLE001 - not installed as an ament package: use the checkout
        pass
    return Path(__file__).resolve().parent.parent / "rviz" / RVIZ_TEMPLATE


def _is_true(value: str) -> bool:
    return value.strip().lower() in ("true", "1", "yes", "on")


def launch_plan(arguments: Mapping[str, str], template: str | None = None) -> dict[str, Any]:
    """What the launch starts, from the argument values: the node's namespace and `parameters` list, and
    the rendered RViz config (None without rviz:=true). `template` is the RViz template text (default:
    the installed one)."""
    namespace = normalize_namespace(arguments.get("namespace", ""))
    profile = arguments.get("params_file", "") or DEFAULT_PROFILE
    ros_params_file = arguments.get("ros_params_file", "")
    overrides: dict[str, Any] = {
        "params_file": profile,
        "use_sim_time": _is_true(arguments.get("use_sim_time", "false")),
    }
    for arg, name, _ in ARGUMENTS:
        value = arguments.get(arg, "")
        if value != "":
            overrides[name] = value
    parameters: list[Any] = [ros_params_file] if ros_params_file else []
    parameters.append(overrides)  # last: the launch arguments win over the parameters file
    rviz_config = None
    if _is_true(arguments.get("rviz", "false")):
        settings = effective_settings(profile_settings(profile), read_ros_params(ros_params_file, namespace),
                                      arguments)
        if template is None:
            template = rviz_template_path().read_text()
        rviz_config = render_rviz_config(template, rviz_values(settings, namespace))
    return {"namespace": namespace, "parameters": parameters, "rviz_config": rviz_config}


def _launch_setup(context, *args, **kwargs):
    from launch.substitutions import LaunchConfiguration
    from launch_ros.actions import Node

    names = [name for name, _, _ in LAUNCH_ARGUMENTS] + [arg for arg, _, _ in ARGUMENTS]
    plan = launch_plan({name: LaunchConfiguration(name).perform(context) for name in names})
    actions = [Node(
        package=PACKAGE,
        executable="smplify3d_node",
        name=NODE_NAME,
        namespace=plan["namespace"],
        output="screen",
        emulate_tty=True,
        parameters=plan["parameters"],
    )]
    if plan["rviz_config"] is not None:
        with tempfile.NamedTemporaryFile("w", prefix="smplify3d_", suffix=".rviz", delete=False) as f:
            f.write(plan["rviz_config"])
        actions.append(Node(
            package="rviz2",
            executable="rviz2",
            name="rviz2",
            arguments=["-d", f.name],
            parameters=[{"use_sim_time": plan["parameters"][-1]["use_sim_time"]}],
            output="screen",
        ))
    return actions


def generate_launch_description():
    from launch import LaunchDescription
    from launch.actions import DeclareLaunchArgument, OpaqueFunction

    declared = [DeclareLaunchArgument(name, default_value=default, description=text)
                for name, default, text in LAUNCH_ARGUMENTS]
    declared += [DeclareLaunchArgument(arg, default_value="", description=f"{text}; empty: as in the files")
                 for arg, _, text in ARGUMENTS]
    return LaunchDescription([*declared, OpaqueFunction(function=_launch_setup)])
