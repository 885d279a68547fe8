"""launch/smplify3d.launch.py without ROS: argument handling and the RViz view rendered from its template.

`launch` and `launch_ros` are not installable here (no PyPI wheels); the launch file keeps them out of its
module level, so everything up to the launch actions (`launch_plan`) is tested as plain Python.
"""

from __future__ import annotations

import ast
import importlib.util
import sys
from pathlib import Path

import pytest
import yaml

REPO = Path(__file__).resolve().parent.parent
LAUNCH_FILE = REPO / "launch" / "smplify3d.launch.py"
TEMPLATE = (REPO / "rviz" / "smplify3d.rviz").read_text()


@pytest.fixture(scope="module")
def lf():
    """The launch file as a module, loaded while `launch` and `launch_ros` cannot be imported."""
    saved = {name: sys.modules.get(name) for name in ("launch", "launch_ros")}
    sys.modules.update(launch=None, launch_ros=None)  # None in sys.modules: `import launch` raises
    try:
        spec = importlib.util.spec_from_file_location("smplify3d_launch", LAUNCH_FILE)
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    finally:
        for name, value in saved.items():
            if value is None:
                sys.modules.pop(name, None)
            else:
                sys.modules[name] = value
    return module


def displays(rviz_text: str) -> dict[str, dict]:
    rviz = yaml.safe_load(rviz_text)
    return {d["Name"]: d for d in rviz["Visualization Manager"]["Displays"]}


def topic(rviz_text: str, display: str) -> str:
    return displays(rviz_text)[display]["Topic"]["Value"]


def fixed_frame(rviz_text: str) -> str:
    return yaml.safe_load(rviz_text)["Visualization Manager"]["Global Options"]["Fixed Frame"]


def test_launch_file_compiles_and_declares_every_argument(lf):
    source = LAUNCH_FILE.read_text()
    compile(source, str(LAUNCH_FILE), "exec")
    tree = ast.parse(source)
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert {"generate_launch_description", "launch_plan", "profile_settings"} <= functions
    names = [name for name, _, _ in lf.LAUNCH_ARGUMENTS] + [arg for arg, _, _ in lf.ARGUMENTS]
    assert len(names) == len(set(names))
    required = {"params_file", "ros_params_file", "namespace", "rviz", "image", "compressed_image",
                "camera_info", "points", "keypoints"}
    assert required <= set(names), required - set(names)
    assert 'executable="smplify3d_node"' in source and lf.PACKAGE == "smplify3d_ros"


def test_template_placeholders_are_the_ones_the_launch_file_fills(lf):
    placeholders = set(lf._PLACEHOLDER.findall(TEMPLATE))
    assert placeholders == {"points", "image", "camera_enabled", "fixed_frame", "markers", "joints",
                            "body_points", "people"}
    assert set(lf.rviz_values(lf.effective_settings(lf.profile_settings("jackal_vlp16"), {}, {}), "")) \
        >= placeholders


def test_render_substitutes_every_placeholder_and_rejects_a_missing_value(lf):
    assert lf.render_rviz_config("a: ${x}\nb: ${y} ${x}\n", {"x": "/p", "y": "q"}) == "a: /p\nb: q /p\n"
    with pytest.raises(KeyError, match="y"):
        lf.render_rviz_config("a: ${x}\nb: ${y}\n", {"x": "/p"})


@pytest.mark.parametrize(("topic_name", "namespace", "expected"), [
    ("/velodyne_points", "", "/velodyne_points"),
    ("/velodyne_points", "robot1", "/velodyne_points"),   # absolute names ignore the namespace
    ("velodyne_points", "", "/velodyne_points"),
    ("velodyne_points", "robot1", "/robot1/velodyne_points"),
    ("velodyne_points", "/robot1/", "/robot1/velodyne_points"),
    ("~/markers", "", "/smplify3d/markers"),
    ("~/markers", "robot1", "/robot1/smplify3d/markers"),
    ("~/markers", "/a/b", "/a/b/smplify3d/markers"),
    ("", "robot1", ""),
])
def test_resolve_topic_follows_ros_name_resolution(lf, topic_name, namespace, expected):
    assert lf.resolve_topic(topic_name, namespace) == expected


def test_default_view_matches_the_default_profile(lf):
    plan = lf.launch_plan({"rviz": "true"}, TEMPLATE)
    text = plan["rviz_config"]
    assert not lf._PLACEHOLDER.search(text)
    assert topic(text, "LiDAR") == "/velodyne_points"
    assert topic(text, "Camera") == "/camera/color/image_raw" and displays(text)["Camera"]["Enabled"] is True
    assert {topic(text, n) for n in ("Bodies", "Joints", "People", "Body points")} == {
        "/smplify3d/markers", "/smplify3d/joints", "/smplify3d/people", "/smplify3d/body_points"}
    assert fixed_frame(text) == "camera_color_optical_frame"


def test_ouster_profile_shows_the_ouster_cloud(lf):
    text = lf.launch_plan({"params_file": "ouster64", "rviz": "true"}, TEMPLATE)["rviz_config"]
    assert topic(text, "LiDAR") == "/ouster/points"


def test_profile_given_as_a_yaml_path(lf, tmp_path):
    profile = tmp_path / "my_robot.yaml"
    profile.write_text("node:\n  topics:\n    points: /my_lidar/points\n    image: ''\n")
    text = lf.launch_plan({"params_file": str(profile), "rviz": "true"}, TEMPLATE)["rviz_config"]
    assert topic(text, "LiDAR") == "/my_lidar/points"
    assert displays(text)["Camera"]["Enabled"] is False  # no raw image topic: the Camera display is off


def test_namespace_moves_the_outputs_and_relative_inputs(lf):
    plan = lf.launch_plan({"namespace": "robot1", "points": "velodyne_points", "rviz": "true"}, TEMPLATE)
    assert plan["namespace"] == "/robot1"
    text = plan["rviz_config"]
    assert topic(text, "Bodies") == "/robot1/smplify3d/markers"
    assert topic(text, "Joints") == "/robot1/smplify3d/joints"
    assert topic(text, "LiDAR") == "/robot1/velodyne_points"
    assert topic(text, "Camera") == "/camera/color/image_raw"  # the profile's absolute topic stays


def test_arguments_override_the_profile_for_node_and_view(lf):
    args = {"params_file": "ouster64", "points": "/lidar/top", "image": "/cam/image", "output_frame": "base_link",
            "keypoints": "/det/kp", "device": "cuda", "rviz": "true", "use_sim_time": "true"}
    plan = lf.launch_plan(args, TEMPLATE)
    (overrides,) = plan["parameters"]
    assert overrides == {"params_file": "ouster64", "use_sim_time": True, "topics.points": "/lidar/top",
                         "topics.image": "/cam/image", "topics.keypoints": "/det/kp", "output_frame": "base_link",
                         "fitting.device": "cuda"}
    text = plan["rviz_config"]
    assert topic(text, "LiDAR") == "/lidar/top" and topic(text, "Camera") == "/cam/image"
    assert fixed_frame(text) == "base_link"


def test_ros_params_file_is_passed_first_and_read_for_the_view(lf, tmp_path):
    params = tmp_path / "robot.yaml"
    params.write_text(yaml.safe_dump({
        "/**": {"ros__parameters": {"topics": {"points": "/from_file/points", "image": "/from_file/image"}}},
        "/robot1/smplify3d": {"ros__parameters": {"topics.camera_info": "/from_file/info",
                                                  "extrinsic.camera_frame": "cam_optical"}},
        "/other_node": {"ros__parameters": {"topics.points": "/not/for/us"}},
    }))
    args = {"ros_params_file": str(params), "namespace": "robot1", "image": "/arg/image", "rviz": "true"}
    plan = lf.launch_plan(args, TEMPLATE)
    assert plan["parameters"][0] == str(params)  # a file path: launch_ros loads it as ROS parameters
    assert plan["parameters"][-1]["topics.image"] == "/arg/image"  # launch arguments come last and win
    text = plan["rviz_config"]
    assert topic(text, "LiDAR") == "/from_file/points"
    assert topic(text, "Camera") == "/arg/image"
    assert fixed_frame(text) == "cam_optical"
    assert lf.read_ros_params(params, "robot1")["topics.camera_info"] == "/from_file/info"
    assert "topics.camera_info" not in lf.read_ros_params(params, "robot2")


def test_no_rviz_renders_nothing_and_needs_no_profile_lookup(lf):
    plan = lf.launch_plan({"params_file": "does_not_matter_without_rviz"})
    assert plan["rviz_config"] is None
    assert plan["parameters"] == [{"params_file": "does_not_matter_without_rviz", "use_sim_time": False}]


def test_template_is_found_without_an_ament_install(lf):
    assert lf.rviz_template_path().read_text() == TEMPLATE
