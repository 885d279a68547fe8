"""smplify3d_ros: an ament_python package (colcon build) that is also pip-installable (`pip install -e .`)."""

import re
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

PACKAGE = "smplify3d_ros"
HERE = Path(__file__).resolve().parent
VERSION = re.search(r'__version__ = "([^"]+)"', (HERE / PACKAGE / "__init__.py").read_text()).group(1)
SHARE = f"share/{PACKAGE}"
README = HERE / "README.md"

setup(
    name=PACKAGE,
    version=VERSION,
    description="SMPLify-3D human mesh recovery from camera keypoints and LiDAR, for ROS 2",
    long_description=README.read_text(encoding="utf-8") if README.exists() else "",
    long_description_content_type="text/markdown",
    license="MIT",
    packages=find_packages(include=[PACKAGE, f"{PACKAGE}.*", "msg_adapters", "msg_adapters.*"]),
    package_data={"msg_adapters": ["*.md", "msg/*/*.msg"]},  # msg: hri_msgs definitions for rosbags
    data_files=[
        ("share/ament_index/resource_index/packages", [f"resource/{PACKAGE}"]),
        (SHARE, ["package.xml"]),
        (f"{SHARE}/params", sorted(glob("params/*.yaml"))),
        (f"{SHARE}/params/base", sorted(glob("params/base/*.yaml"))),
        (f"{SHARE}/params/nav2", sorted(glob("params/nav2/*.yaml"))),  # costmap example (docs/node.md, "Nav2")
        (f"{SHARE}/launch", sorted(glob("launch/*.launch.py"))),
        (f"{SHARE}/rviz", sorted(glob("rviz/*.rviz"))),
    ],
    # ROS installs resolve dependencies from package.xml (rosdep); pip reads this list. The ROS message
    # packages (rclpy, sensor_msgs, ...) are not on PyPI: `smplify3d replay` and the library run without them.
    install_requires=[
        "setuptools",
        "numpy>=1.24",
        "scipy>=1.10",
        "PyYAML>=6.0",
        "opencv-python-headless>=4.8",
        "torch>=2.1",
        "roma>=1.4",
        "anny>=0.6",
        "kiss-icp>=1.0",
        "trimesh>=4.0",
        "embreex>=2.17",
        "rosbags>=0.11",
        "mcap>=1.1",
        "tqdm>=4.60",
        "matplotlib>=3.7",
    ],
    # `smplify3d tune` (smplify3d_ros/eval/tune.py): a development tool, never needed on the robot
    extras_require={"test": ["pytest>=7", "ruff"], "bench": ["optuna>=5.0"]},
    python_requires=">=3.10",
    zip_safe=False,
    tests_require=["pytest"],
    entry_points={
        "console_scripts": [
            "smplify3d_node = smplify3d_ros.node:main",
            "smplify3d = smplify3d_ros.cli:main",
        ],
    },
)
