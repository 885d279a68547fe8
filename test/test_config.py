"""The configuration: typed, acyclic, every shipped key effective; fit_frame's fitter cache bounded."""

from __future__ import annotations

import dataclasses
import typing

import numpy as np
import pytest
import yaml

from smplify3d_ros.config import CORE_SECTIONS, Config, load_config
from smplify3d_ros.runtime.config import NodeConfig, load_node_config
from smplify3d_ros.settings import ConfigError, base_values, load_sections, params_dir, to_dict
from smplify3d_ros.sim.config import SimConfig, load_sim_config

SECTION_CLASSES = {**CORE_SECTIONS, "node": NodeConfig, "sim": SimConfig}
PROFILES = sorted(p.stem for p in params_dir().glob("*.yaml"))


def _dataclasses(cls: type) -> typing.Iterator[type]:
    """`cls` and every dataclass its fields hold (directly, in a dict or in a list)."""
    yield cls
    for hint in typing.get_type_hints(cls).values():
        for arg in (hint, *typing.get_args(hint)):
            if dataclasses.is_dataclass(arg):
                yield from _dataclasses(arg)


def _leaves(values: dict, prefix: str = "") -> typing.Iterator[tuple[str, object]]:
    for key, value in values.items():
        if isinstance(value, dict) and value:
            yield from _leaves(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def _loaded(profile: str) -> dict:
    """Every section of a profile as its owner loads it, back as plain values."""
    config = load_config(profile)
    return {**{name: to_dict(getattr(config, name)) for name in CORE_SECTIONS},
            "node": to_dict(load_node_config(profile)), "sim": to_dict(load_sim_config(profile))}


def test_sections_declare_types_and_ranges_not_values():
    """params/base/*.yaml is the single source of values: no field has a default."""
    for cls in {c for root in SECTION_CLASSES.values() for c in _dataclasses(root)}:
        for f in dataclasses.fields(cls):
            assert f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING, (cls, f.name)
    assert set(base_values()) == set(SECTION_CLASSES), "one params/base file per section"
    assert typing.get_type_hints(Config) == dict(CORE_SECTIONS.items()), "the core config is typed, no Any"


@pytest.mark.parametrize("profile", PROFILES)
def test_every_profile_key_changes_the_loaded_value(profile):
    """A key in a shipped profile that equals the base (or that no section reads) is a dead setting."""
    overrides = yaml.safe_load((params_dir() / f"{profile}.yaml").read_text()) or {}
    base, loaded = _loaded_base(), _loaded(profile)
    for key, value in _leaves(overrides):
        section, *path = key.split(".")
        old, new = _get(base[section], path), _get(loaded[section], path)
        assert new == _plain(value), f"{profile}: {key} is not what the profile says"
        assert new != old, f"{profile}: {key} = {value!r} is the base value already: remove it"


def _loaded_base() -> dict:
    if not hasattr(_loaded_base, "cache"):
        _loaded_base.cache = _loaded("jackal_vlp16")  # the default profile overrides nothing
    return _loaded_base.cache


def _get(values: dict, path: list[str]):
    for part in path:
        values = values[part]
    return values


def _plain(value):
    return [_plain(v) for v in value] if isinstance(value, (list, tuple)) else value


def test_default_profile_is_the_base():
    assert (yaml.safe_load((params_dir() / "jackal_vlp16.yaml").read_text()) or {}) == {}
    assert load_sections("jackal_vlp16") == base_values()


def test_min_points_is_the_fitters():
    """`lidar.min_points` set only a flag nothing read; the fitter's `fitting.min_points` is the one setting."""
    assert load_config("ouster64").fitting.min_points == base_values()["fitting"]["min_points"]
    assert "min_points" not in base_values()["lidar"]
    with pytest.raises(ConfigError, match="unknown key 'lidar.min_points'"):
        load_config(overrides={"lidar": {"min_points": 20}})


@pytest.mark.parametrize("mean", [[0.5] * 5, [0.5] * 5 + [1.2], [0.5] * 7])
def test_anny_shape_mean_must_be_six_phenotypes_in_range(mean):
    with pytest.raises(ConfigError, match="anny_shape_mean must be 6 phenotypes in"):
        load_config(overrides={"fitting": {"body": {"anny_shape_mean": mean}}})


def test_people_below_min_points_are_fitted_from_the_image(anny_model):
    """`fitting.min_points` (the Ouster-64 profile keeps the base's): one point fewer, image-only."""
    from smplify3d_ros.eval.synthetic import default_intrinsics, make_person
    from smplify3d_ros.fitting.fitter import Fitter
    from smplify3d_ros.fitting.options import FitOptions

    K = default_intrinsics()
    config = load_config("ouster64").fitting
    fitter = Fitter(config, anny_model)
    flags = {}
    for n in (config.min_points - 1, config.min_points):
        person = make_person(anny_model, np.random.default_rng(2), K, distance=5.0, yaw=0.2, n_points=n,
                             point_noise=0.01, keypoint_noise_px=2.0)
        assert len(person.observation.points) == n
        flags[n] = fitter.fit([person.observation], K, options=FitOptions(optimize=False))[0].flags
    assert "image_only" in flags[config.min_points - 1] and "image_only" not in flags[config.min_points]


def test_fit_frame_keeps_a_bounded_cache_keyed_by_value(monkeypatch):
    from smplify3d_ros import frame_fitter

    built = []

    class CountingFitter:
        def __init__(self, config):
            built.append(config)
            self.config = config

    monkeypatch.setattr(frame_fitter, "Fitter", CountingFitter)
    monkeypatch.setattr(frame_fitter, "_FITTERS", type(frame_fitter._FITTERS)())
    for _ in range(6):  # six equal configurations, each from its own load_config() call
        fitter = frame_fitter.cached_fitter(load_config().fitting)
    assert len(built) == 1 and fitter.config.profile == "robot"
    for profile in ("thesis", "robot", "thesis"):
        fitter = frame_fitter.cached_fitter(load_config(overrides={"fitting": {"profile": profile}}).fitting)
        assert fitter.config.profile == profile, "the fitter of the configuration asked for"
    for seed in range(10):
        frame_fitter.cached_fitter(load_config(overrides={"fitting": {"seed": seed}}).fitting)
    assert len(frame_fitter._FITTERS) <= frame_fitter.FITTER_CACHE_SIZE
