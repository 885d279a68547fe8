"""Parameters: every core key is a ROS parameter of the same dotted name (also from a standard
`--params-file`), integers are accepted for doubles, unknown names are warned about, and numeric ranges
are declared, matching the configuration's own checks."""

from __future__ import annotations

import math

import node_support
import pytest

from smplify3d_ros.config import ConfigError, load_config, to_dict
from smplify3d_ros.node import flatten, unflatten
from smplify3d_ros.runtime.config import PARAMETER_RANGES, load_node_config, parameter_range

CORE = ("fitting", "lidar", "people", "tracking")


def _numeric_keys() -> dict[str, float | int]:
    cfg, node = load_config(), load_node_config()
    values = flatten(to_dict(node))
    for section in CORE:
        values.update(flatten(to_dict(getattr(cfg, section)), f"{section}."))
    return {k: v for k, v in values.items() if isinstance(v, (int, float)) and not isinstance(v, bool)}


def _accepted(name: str, value: float | int) -> bool:
    override = unflatten({name: value})
    try:
        if name.split(".")[0] in CORE:
            load_config(None, override)
        else:
            load_node_config(None, {"node": override})
    except ConfigError:
        return False
    return True


@pytest.mark.parametrize("name", sorted(_numeric_keys()))
def test_declared_ranges_agree_with_the_configuration(name):
    default = _numeric_keys()[name]
    cast = type(default)
    bounds = parameter_range(name)
    if bounds is None:  # no range declared: the configuration must accept any value of the type
        probes = [-10**6, -1, 0, 1, 10**6]
        assert all(_accepted(name, cast(p)) for p in probes), f"{name} has a range: add it to PARAMETER_RANGES"
        return
    low, high = bounds
    assert low <= default <= high
    step = 1 if cast is int else 1e-6 * max(1.0, abs(low), abs(high) if math.isfinite(high) else 1.0)
    if math.isfinite(low):
        assert not _accepted(name, cast(low - step)), f"{name}: the range's low end is below the configuration's"
    if math.isfinite(high):
        assert not _accepted(name, cast(high + step)), f"{name}: the range's high end is above the configuration's"


def test_every_range_pattern_names_a_key():
    from fnmatch import fnmatchcase

    keys = _numeric_keys()
    for pattern in PARAMETER_RANGES:
        assert any(fnmatchcase(k, pattern) for k in keys), pattern


rclpy = pytest.importorskip("rclpy")


def test_every_core_key_is_a_parameter_with_the_profile_value(ros):
    from smplify3d_ros.node import create_node

    node = create_node({}, fitter=node_support.fitter())
    try:
        cfg = load_config()
        for section in CORE:
            for name, value in flatten(to_dict(getattr(cfg, section)), f"{section}.").items():
                got = node.get_parameter(name).value
                assert (list(got) if isinstance(value, list) else got) == value, name
        descriptor = node.describe_parameter("lidar.max_range_m")
        assert "farther than this" in descriptor.description and descriptor.read_only
        assert descriptor.floating_point_range[0].from_value == 0.0
        assert math.isinf(descriptor.floating_point_range[0].to_value)
        ints = node.describe_parameter("people.max_people").integer_range[0]
        assert (ints.from_value, ints.to_value) == (1, 100)
        assert node.describe_parameter("sync.slop_s").floating_point_range[0].to_value == 5.0
    finally:
        node.destroy_node()


def test_an_integer_is_accepted_for_a_double(ros):
    from rclpy.parameter import Parameter

    from smplify3d_ros.node import create_node

    node = create_node({"sync.slop_s": 1, "extrinsic.xyz": [0, 0, 1], "fitting.profiles.robot.lr": 1},
                       fitter=node_support.fitter())
    try:
        assert node.node_config.sync.slop_s == 1.0
        assert node.get_parameter("sync.slop_s").type_ == Parameter.Type.DOUBLE
        assert node.node_config.extrinsic.xyz == (0.0, 0.0, 1.0)
        assert node.config.fitting.profiles["robot"].lr == 1.0
    finally:
        node.destroy_node()


def test_a_params_file_reaches_the_core_and_unknown_names_are_warned(ros, tmp_path, monkeypatch):
    from rclpy.context import Context
    from rclpy.impl.rcutils_logger import RcutilsLogger

    from smplify3d_ros.node import Smplify3dNode

    warnings: list[str] = []
    real = RcutilsLogger.warning
    monkeypatch.setattr(RcutilsLogger, "warning", lambda self, msg, **kw: (warnings.append(msg), real(self, msg, **kw)))
    params = tmp_path / "robot.yaml"
    params.write_text("/**:\n  ros__parameters:\n    lidar:\n      max_range_m: 30.0\n"
                      "    fitting:\n      profiles:\n        robot:\n          lr: 0.03\n"
                      "    people:\n      max_peeple: 3\n")
    context = Context()
    rclpy.init(context=context, args=["--ros-args", "--params-file", str(params), "-p", "sync.slopp:=0.1",
                                      "-p", "sync.queue_size:=20", "-p", "sync.slop_s:=1"])
    try:
        node = Smplify3dNode(context=context, fitter=node_support.fitter())
        try:
            assert node.config.lidar.max_range_m == 30.0
            assert node.config.fitting.profiles["robot"].lr == 0.03
            assert node.node_config.sync.queue_size == 20
            assert node.node_config.sync.slop_s == 1.0, "-p sync.slop_s:=1: an integer for a double"
            assert not node.has_parameter("sync.slopp")
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    lines = [w for w in warnings if w.startswith("unknown parameter(s)")]
    assert len(lines) == 1, warnings
    assert "people.max_peeple (did you mean people.max_people?)" in lines[0]
    assert "sync.slopp (did you mean sync.slop_s?)" in lines[0]
