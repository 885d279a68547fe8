"""Packaging: package.xml, setup.py (a wheel really holds what colcon installs), launch file, profiles, RViz."""

from __future__ import annotations

import ast
import importlib.util
import re
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import pytest
import yaml

import smplify3d_ros

REPO = Path(__file__).resolve().parent.parent
PACKAGE = "smplify3d_ros"


def test_package_xml_is_format_3_ament_python_with_the_runtime_dependencies():
    root = ET.parse(REPO / "package.xml").getroot()
    assert root.tag == "package" and root.get("format") == "3"
    assert root.findtext("name") == PACKAGE
    assert root.findtext("version") == smplify3d_ros.__version__
    assert root.find("export/build_type").text == "ament_python"
    assert root.findtext("license") and root.findtext("maintainer") and root.findtext("description").strip()
    depends = {e.text for e in root.findall("exec_depend")}
    required = {"rclpy", "std_msgs", "sensor_msgs", "geometry_msgs", "visualization_msgs", "diagnostic_msgs",
                "builtin_interfaces", "rcl_interfaces", "tf2_ros_py", "message_filters", "launch", "launch_ros",
                "ros2launch", "python3-numpy", "python3-opencv", "python3-yaml", "python3-scipy"}
    assert required <= depends, required - depends
    # every message package the code builds messages from is a dependency, but hri_msgs: optional (used when
    # importable), its definitions carried for bags (msg_adapters/msg), no released Jazzy rosdep key
    optional = {"hri_msgs"}
    used = set()
    for path in [*(REPO / "msg_adapters").glob("*.py"), *(REPO / PACKAGE).glob("*.py")]:
        used |= set(re.findall(r'"([a-z_]+_msgs|builtin_interfaces)/(?:msg/)?[A-Z]\w+"', path.read_text()))
    assert used - optional <= depends, used - optional - depends


DEPEND_TAGS = ("depend", "build_depend", "build_export_depend", "buildtool_depend", "buildtool_export_depend",
               "exec_depend", "test_depend", "doc_depend")


def _rosdep_keys() -> dict:
    return yaml.safe_load((REPO / "test" / "data" / "rosdep_keys_jazzy.yaml").read_text())


def _package_xml_depends() -> list[tuple[str, str]]:
    root = ET.parse(REPO / "package.xml").getroot()
    return [(e.tag, (e.text or "").strip()) for e in root if e.tag in DEPEND_TAGS]


def test_package_xml_uses_only_verified_rosdep_keys():
    """Every dependency is a key checked against rosdistro (test/data/rosdep_keys_jazzy.yaml), none of them
    a pip-only key (rosdep's pip installer stops on Ubuntu 24.04's externally managed Python)."""
    verified = _rosdep_keys()
    keys, absent = verified["keys"], verified["absent"]
    depends = _package_xml_depends()
    assert depends
    unknown = sorted({key for _, key in depends if key not in keys})
    assert not unknown, f"not in test/data/rosdep_keys_jazzy.yaml (check rosdistro, then add): {unknown}"
    assert not [key for _, key in depends if key in absent]
    pip_only = sorted({key for _, key in depends if keys[key].get("installer") == "pip"})
    assert not pip_only, f"pip-only rosdep keys fail on Noble; use requirements-robot.txt: {pip_only}"
    assert "tf2_ros" not in {key for _, key in depends}, "the Python tf2_ros module is in tf2_ros_py"


def test_package_xml_buildtool_depends_are_released_jazzy_packages():
    """ament_python is a build type, not a rosdep key: `rosdep install` stops on it."""
    keys = _rosdep_keys()["keys"]
    tools = [key for tag, key in _package_xml_depends() if tag.startswith("buildtool")]
    bad = [key for key in tools if keys.get(key, {}).get("kind") != "ros"]
    assert not bad, f"buildtool_depend keys that are not released Jazzy packages: {bad}"
    assert "ament_python" not in tools


def test_verified_rosdep_key_list_names_its_sources():
    verified = _rosdep_keys()
    sources = verified["sources"]
    assert set(sources) == {"jazzy/distribution.yaml", "rosdep/python.yaml"}
    assert all(len(commit) == 40 for commit in sources.values())
    for key, entry in verified["keys"].items():
        assert entry["file"] in sources, key
        if entry["kind"] == "ros":
            assert entry["file"] == "jazzy/distribution.yaml" and entry["repository"] and entry["release"], key
        else:
            assert entry["kind"] == "system" and entry["installer"] in ("apt", "pip") and entry["noble"], key
    assert not set(verified["keys"]) & set(verified["absent"])
    assert {"ament_python", "hri_msgs"} <= set(verified["absent"])


# setup.py install_requires names provided by apt through a rosdep key of package.xml on the robot
APT_PROVIDED = {"numpy": "python3-numpy", "scipy": "python3-scipy", "PyYAML": "python3-yaml",
                "opencv-python-headless": "python3-opencv", "tqdm": "python3-tqdm",
                "matplotlib": "python3-matplotlib"}
APT_OWNED = {"numpy", "scipy", "pyyaml", "opencv-python", "opencv-python-headless", "opencv-contrib-python",
             "opencv-contrib-python-headless", "tqdm", "matplotlib"}


def _requirement_names(path: Path) -> dict[str, str]:
    names = {}
    for line in path.read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line and not line.startswith("-"):
            names[re.split(r"[<>=!~;\[ ]", line, maxsplit=1)[0].lower()] = line
    return names


def _install_requires() -> list[str]:
    tree = ast.parse((REPO / "setup.py").read_text())
    call = next(n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup")
    (value,) = [k.value for k in call.keywords if k.arg == "install_requires"]
    return [re.split(r"[<>=!~;\[ ]", r, maxsplit=1)[0] for r in ast.literal_eval(value)]


def test_robot_requirements_leave_ros_and_apt_packages_alone():
    robot = _requirement_names(REPO / "requirements-robot.txt")
    assert robot
    assert not [name for name in robot if name.startswith("ros-")], "ROS comes from apt on the robot"
    assert not set(robot) & APT_OWNED, "pip copies of apt's python3-* packages break the apt modules"
    assert all(not re.search(r"==", spec) for spec in robot.values()), "no exact pins on the robot"
    text = (REPO / "requirements-robot.txt").read_text()
    assert "--index-url https://download.pytorch.org/whl/cpu" in text  # torch's CPU build, documented


def test_robot_install_covers_every_runtime_requirement():
    """Each install_requires entry of setup.py comes from rosdep (package.xml) or requirements-robot.txt."""
    robot = set(_requirement_names(REPO / "requirements-robot.txt"))
    depends = {key for _, key in _package_xml_depends()}
    missing = []
    for name in _install_requires():
        if name == "setuptools":
            continue  # the build tool itself: in every venv, and python3-setuptools with colcon
        if name in APT_PROVIDED:
            if APT_PROVIDED[name] not in depends:
                missing.append(f"{name} (rosdep key {APT_PROVIDED[name]})")
        elif name.lower() not in robot:
            missing.append(f"{name} (requirements-robot.txt)")
    assert not missing, missing


def test_setup_py_declares_entry_points_packages_and_data():
    tree = ast.parse((REPO / "setup.py").read_text())
    text = (REPO / "setup.py").read_text()
    assert "smplify3d_node = smplify3d_ros.node:main" in text
    assert "smplify3d = smplify3d_ros.cli:main" in text
    assert any(isinstance(n, ast.Call) and getattr(n.func, "id", "") == "setup" for n in ast.walk(tree))
    assert (REPO / "resource" / PACKAGE).exists()
    cfg = (REPO / "setup.cfg").read_text()
    assert "script_dir=$base/lib/smplify3d_ros" in cfg and "install_scripts=$base/lib/smplify3d_ros" in cfg


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> zipfile.ZipFile:
    """Build the wheel from a copy of the sources (the checkout stays clean)."""
    src = tmp_path_factory.mktemp("src")
    for name in ("setup.py", "setup.cfg", "package.xml", "README.md"):
        if (REPO / name).exists():
            shutil.copy(REPO / name, src / name)
    for name in ("resource", "params", "launch", "rviz", PACKAGE, "msg_adapters"):
        shutil.copytree(REPO / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q",
                           "-w", str(out), str(src)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (path,) = out.glob("smplify3d_ros-*.whl")
    return zipfile.ZipFile(path)


def test_wheel_holds_packages_entry_points_and_share_files(wheel):
    names = set(wheel.namelist())
    assert "smplify3d_ros/node.py" in names and "smplify3d_ros/replay/run.py" in names
    assert "smplify3d_ros/fitting/fitter.py" in names and "msg_adapters/pointcloud2.py" in names
    assert "msg_adapters/BODIES_SCHEMA.md" in names
    data = f"smplify3d_ros-{smplify3d_ros.__version__}.data/data/"
    share = f"{data}share/{PACKAGE}/"
    expected = [f"{data}share/ament_index/resource_index/packages/{PACKAGE}", f"{share}package.xml",
                f"{share}launch/smplify3d.launch.py", f"{share}rviz/smplify3d.rviz"]
    expected += [f"{share}params/{p.name}" for p in (REPO / "params").glob("*.yaml")]
    expected += [f"{share}params/base/{p.name}" for p in (REPO / "params" / "base").glob("*.yaml")]
    expected += [f"{share}params/nav2/{p.name}" for p in (REPO / "params" / "nav2").glob("*.yaml")]
    missing = [e for e in expected if e not in names]
    assert not missing, missing
    (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    text = wheel.read(entry_points).decode()
    assert "smplify3d_node = smplify3d_ros.node:main" in text and "smplify3d = smplify3d_ros.cli:main" in text


def _launch_source() -> str:
    return (REPO / "launch" / "smplify3d.launch.py").read_text()


def test_launch_file_compiles_and_its_arguments_are_node_parameters():
    from smplify3d_ros.config import load_config
    from smplify3d_ros.node import parameter_defaults
    from smplify3d_ros.runtime.config import load_node_config

    source = _launch_source()
    tree = ast.parse(source)
    compile(source, "smplify3d.launch.py", "exec")
    assert any(isinstance(n, ast.FunctionDef) and n.name == "generate_launch_description" for n in tree.body)
    arguments = next(ast.literal_eval(n.value) for n in tree.body
                     if isinstance(n, ast.Assign) and getattr(n.targets[0], "id", "") == "ARGUMENTS")
    parameters = parameter_defaults(load_config(), load_node_config())
    for _, name, _ in arguments:
        assert name in parameters, f"launch argument sets unknown parameter {name!r}"
    assert 'executable="smplify3d_node"' in source and 'package=PACKAGE' in source


@pytest.mark.skipif(importlib.util.find_spec("launch_ros") is None, reason="launch_ros not installed")
def test_launch_file_loads_with_ros_launch():  # pragma: no cover - needs a full ROS install
    from launch import LaunchDescription
    from launch.launch_description_sources import PythonLaunchDescriptionSource

    source = PythonLaunchDescriptionSource(str(REPO / "launch" / "smplify3d.launch.py"))
    description = source.try_get_launch_description_without_context()
    assert isinstance(description, LaunchDescription)
    names = {a.name for a in description.get_launch_arguments()}
    assert {"params_file", "ros_params_file", "namespace", "points", "image", "compressed_image", "camera_info",
            "keypoints", "rviz"} <= names


def test_profiles_load_and_node_yaml_documents_every_key():
    from smplify3d_ros.config import load_config, params_dir
    from smplify3d_ros.node import yaml_comments

    for path in sorted(params_dir().glob("*.yaml")):
        load_config(path.stem)  # raises on unknown keys or bad values
    for name in ("jackal_vlp16", "ouster64", "humanm3"):
        assert (params_dir() / f"{name}.yaml").exists()
    base = yaml.safe_load((params_dir() / "base" / "node.yaml").read_text())
    comments = yaml_comments(params_dir() / "base" / "node.yaml")

    def leaves(d, prefix=""):
        for k, v in d.items():
            if isinstance(v, dict):
                yield from leaves(v, f"{prefix}{k}.")
            else:
                yield f"{prefix}{k}"

    undocumented = [key for key in leaves(base) if not comments.get(key)]
    assert not undocumented, undocumented


def test_rviz_template_shows_the_outputs():
    """The RViz view is a YAML template; the launch file fills its placeholders (test_launch.py)."""
    rviz = yaml.safe_load((REPO / "rviz" / "smplify3d.rviz").read_text())
    displays = rviz["Visualization Manager"]["Displays"]
    topics = {d["Topic"]["Value"] for d in displays if isinstance(d.get("Topic"), dict)}
    assert {"${markers}", "${joints}", "${people}", "${body_points}", "${points}", "${image}"} <= topics
    assert rviz["Visualization Manager"]["Global Options"]["Fixed Frame"] == "${fixed_frame}"
