"""colcon builds the package as on the robot, and the install tree holds what `ros2 run`/`ros2 launch` use.

CI installs colcon-core and colcon-ros from PyPI into .venv (.ci/install); the build runs on a copy of
the package in a temporary workspace, with the Python that runs the tests, as the robot runs colcon
from its venv's Python (docs/robot.md). Skipped when colcon is not installed.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
PACKAGE = "smplify3d_ros"
SOURCES = ("setup.py", "setup.cfg", "package.xml", "README.md", "resource", "params", "launch", "rviz",
           PACKAGE, "msg_adapters")

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("colcon_core") is None or importlib.util.find_spec("colcon_ros") is None,
    reason="colcon-core and colcon-ros are not installed (bash .ci/install installs them)")


@pytest.fixture(scope="module")
def build(tmp_path_factory) -> dict:
    """`python -m colcon build` in a fresh workspace holding a copy of the package."""
    ws = tmp_path_factory.mktemp("colcon_ws")
    src = ws / "src" / PACKAGE
    src.mkdir(parents=True)
    for name in SOURCES:
        path = REPO / name
        if path.is_dir():
            shutil.copytree(path, src / name, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
        elif path.exists():
            shutil.copy(path, src / name)
    env = {k: v for k, v in os.environ.items() if not k.startswith(("COLCON_", "AMENT_"))}
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "colcon", "build", "--event-handlers", "console_direct+"],
                          cwd=ws, env=env, capture_output=True, text=True, timeout=300)
    seconds = time.perf_counter() - start
    print(f"colcon build: {seconds:.2f} s")
    return {"ws": ws, "proc": proc, "prefix": ws / "install" / PACKAGE, "seconds": seconds}


def test_colcon_builds_the_package_as_a_ros_ament_python_package(build):
    proc = build["proc"]
    assert proc.returncode == 0, proc.stdout[-4000:] + proc.stderr[-4000:]
    prefix = build["prefix"]
    # written by colcon-ros' ament_python build (package.xml identified): without the AMENT_PREFIX_PATH
    # hook, `source install/setup.bash` would not let ros2 run / ros2 launch find the package
    assert (prefix / "share" / PACKAGE / "hook" / "ament_prefix_path.dsv").is_file()
    assert (prefix / "share" / "colcon-core" / "packages" / PACKAGE).is_file()
    assert (build["ws"] / "install" / "setup.sh").is_file()  # and setup.bash where colcon-bash is installed


def test_install_tree_holds_the_executables_and_share_files(build):
    assert build["proc"].returncode == 0
    prefix = build["prefix"]
    share = prefix / "share" / PACKAGE
    for exe in ("smplify3d_node", "smplify3d"):
        path = prefix / "lib" / PACKAGE / exe  # where `ros2 run smplify3d_ros <exe>` looks
        assert path.is_file() and os.access(path, os.X_OK), path
    assert (share / "package.xml").read_text() == (REPO / "package.xml").read_text()
    assert (prefix / "share" / "ament_index" / "resource_index" / "packages" / PACKAGE).is_file()
    assert (share / "launch" / "smplify3d.launch.py").is_file()
    assert (share / "rviz" / "smplify3d.rviz").is_file()
    for path in [*(REPO / "params").glob("*.yaml"), *(REPO / "params" / "base").glob("*.yaml")]:
        installed = share / path.relative_to(REPO)
        assert installed.read_text() == path.read_text(), installed
    assert (share / "params" / "ouster64.yaml").is_file() and (share / "params" / "base" / "node.yaml").is_file()


def test_executables_run_with_the_python_that_ran_colcon(build):
    """Running colcon with the venv's Python is what makes the node use the venv's packages (torch, anny)."""
    assert build["proc"].returncode == 0
    node = build["prefix"] / "lib" / PACKAGE / "smplify3d_node"
    assert node.read_text().splitlines()[0] == f"#!{sys.executable}"
    assert "'console_scripts', 'smplify3d_node'" in node.read_text()


@pytest.mark.skipif(importlib.util.find_spec("ament_index_python") is None, reason="ament_index_python missing")
def test_installed_package_is_found_through_the_ament_index(build):
    """With the install prefix on AMENT_PREFIX_PATH (what `source install/setup.bash` sets), the package
    imports from the install tree and the launch file finds its RViz template in the installed share."""
    assert build["proc"].returncode == 0
    prefix = build["prefix"]
    (site,) = (prefix / "lib").glob("python3*/site-packages")
    script = (
        "import importlib.util, smplify3d_ros\n"
        "from ament_index_python.packages import get_package_share_directory as share\n"
        f"spec = importlib.util.spec_from_file_location('lf', share('{PACKAGE}') + '/launch/smplify3d.launch.py')\n"
        "lf = importlib.util.module_from_spec(spec); spec.loader.exec_module(lf)\n"
        "print(smplify3d_ros.__file__); print(share('smplify3d_ros')); print(lf.rviz_template_path())\n"
    )
    env = {k: v for k, v in os.environ.items() if not k.startswith(("COLCON_", "AMENT_"))}
    env.update(PYTHONPATH=str(site), AMENT_PREFIX_PATH=str(prefix))
    proc = subprocess.run([sys.executable, "-c", script], cwd=build["ws"], env=env, capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr[-4000:]
    module, share_dir, template = proc.stdout.split()
    assert Path(module).is_relative_to(site)
    assert Path(share_dir) == prefix / "share" / PACKAGE
    assert Path(template) == prefix / "share" / PACKAGE / "rviz" / "smplify3d.rviz"
