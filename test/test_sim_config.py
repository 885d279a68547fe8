"""The simulator section of the configuration: every value in params/base/sim.yaml, validated."""

from __future__ import annotations

import copy

import pytest

from smplify3d_ros.settings import ConfigError, base_values, from_dict
from smplify3d_ros.sim.config import SimConfig, default_sim_config


def test_base_values_load():
    cfg = default_sim_config()
    assert set(cfg.lidar.sensors) == {"vlp16", "os1_32", "os1_64", "os1_128"}
    assert set(cfg.sequence.scenarios) == {"walk", "crossing", "close", "far", "people"}
    assert cfg.lidar.sensors["vlp16"].channels == 16


@pytest.mark.parametrize(
    "path,value,message",
    [
        (("lidar", "sensors", "vlp16", "dropout"), 1.5, "dropout"),
        (("scene", "distance_range_m"), [5.0, 2.0], "distance_range_m"),
        (("camera", "hfov_deg"), 400.0, "hfov_deg"),
        (("people", "preset_weights"), {"giant": 1.0}, "giant"),
        (("detector", "swap_prob"), -0.1, "swap_prob"),
    ],
)
def test_out_of_range_values_name_the_key(path, value, message):
    values = copy.deepcopy(base_values()["sim"])
    node = values
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ConfigError, match=message):
        from_dict(SimConfig, values, "sim")


def test_missing_and_unknown_keys():
    values = copy.deepcopy(base_values()["sim"])
    del values["mount"]["camera_height_m"]
    with pytest.raises(ConfigError, match="camera_height_m"):
        from_dict(SimConfig, values, "sim")
    values = copy.deepcopy(base_values()["sim"])
    values["hmr"]["typo"] = 1.0
    with pytest.raises(ConfigError, match="typo"):
        from_dict(SimConfig, values, "sim")
