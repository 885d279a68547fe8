"""The package's import graph: no cycle (function-level imports included), a core (body/, fitting/,
lidar/, tracking/) that imports no ROS, message, driver, simulator or evaluation module, and a configuration that
loads none of them."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
PACKAGES = ("smplify3d_ros", "msg_adapters")
CORE = ("smplify3d_ros.body", "smplify3d_ros.fitting", "smplify3d_ros.lidar", "smplify3d_ros.tracking")
NOT_IN_CORE = ("rclpy", "msg_adapters", "smplify3d_ros.sim", "smplify3d_ros.eval", "smplify3d_ros.runtime",
               "smplify3d_ros.replay", "smplify3d_ros.node", "launch", "tf2_ros", "message_filters")


def _modules() -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in sorted((REPO / package).rglob("*.py")):
            parts = path.relative_to(REPO).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def _type_checking_lines(tree: ast.AST) -> set[int]:
    lines: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            for child in node.body:
                lines.update(range(child.lineno, (child.end_lineno or child.lineno) + 1))
    return lines


def imports_of(name: str, path: Path, modules: dict[str, Path]) -> set[str]:
    """Every module `name` imports, at module or function level (not under `if TYPE_CHECKING`)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _type_checking_lines(tree)
    found: set[str] = set()
    for node in ast.walk(tree):
        if getattr(node, "lineno", None) in skip:
            continue
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = name.split(".")[: -node.level + (1 if path.name == "__init__.py" else 0) or None]
                base = ".".join([*package, base] if base else package)
            found.add(base)
            found.update(f"{base}.{alias.name}" for alias in node.names if f"{base}.{alias.name}" in modules)
    return found


def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: {m for m in imports_of(name, path, modules) if m in modules and m != name}
            for name, path in modules.items()}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                out.append(sorted(component))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for v in graph:
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    graph = _graph()
    assert len(graph) > 60, "the graph covers the package"
    # a package imports its modules' parent package implicitly: drop the edges to a package's own __init__
    graph = {m: {d for d in deps if not m.startswith(d + ".")} for m, deps in graph.items()}
    assert _cycles(graph) == []


def test_core_imports_no_driver_simulator_or_evaluation_code():
    modules = _modules()
    for name, path in modules.items():
        if name.startswith(CORE):
            bad = sorted(m for m in imports_of(name, path, modules) if m.startswith(NOT_IN_CORE))
            assert not bad, f"{name} imports {bad}"


def test_config_and_core_load_no_messages_simulator_or_ros():
    code = ("import sys, smplify3d_ros.fitting; from smplify3d_ros.config import load_config; load_config(); "
            "from smplify3d_ros.fitting.fitter import Fitter; "
            "print(sorted(m for m in sys.modules if m.startswith(('msg_adapters', 'smplify3d_ros.sim', "
            "'smplify3d_ros.eval', 'smplify3d_ros.runtime', 'rclpy'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip() == "[]", out.stdout
