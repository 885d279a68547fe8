"""The core configuration: what the library, the drivers and the benchmarks share for one frame.

`load_config(profile, overrides)` reads params/base/*.yaml, applies a profile (`params/<name>.yaml` or a
YAML path) and `overrides`, and validates the core sections:
- `fitting` (`fitting.config.FittingConfig`): the body model and the method;
- `lidar` (`lidar.config.ExtractionConfig`): person points from full scans;
- `people` (`PeopleConfig`): which detected people a frame fits;
- `tracking` (`tracking.config.TrackingConfig`): people followed across frames.
The drivers' section (`node`, `runtime.config`) and the simulator's (`sim`, `sim.config`) are loaded by
their owners from the same profile; this module imports neither, nor any ROS or message code.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from smplify3d_ros.fitting.config import FittingConfig
from smplify3d_ros.lidar.config import ExtractionConfig
from smplify3d_ros.settings import (  # noqa: F401 - re-exported: the configuration API in one place
    DEFAULT_PROFILE,
    ConfigError,
    from_dict,
    load_sections,
    params_dir,
    require,
    resolve_profile,
    to_dict,
)
from smplify3d_ros.tracking.config import TrackingConfig


@dataclass(frozen=True)
class PeopleConfig:
    """Which detected people a frame fits (values in params/base/people.yaml)."""

    max_people: int  # people fitted per frame, largest keypoint boxes first
    min_keypoints: int  # people with fewer usable keypoints are not fitted
    keypoint_margin: float  # keypoints this far outside the image (fraction of its size) are missing
    score_level: float  # a plainly seen joint's score; a less confident detector's frames scale up to it (0: never)
    score_max_gain: float  # ... by at most this factor

    def __post_init__(self) -> None:
        require(1 <= self.max_people <= 100, "max_people must be in [1, 100]")
        require(1 <= self.min_keypoints <= 17, "min_keypoints must be in [1, 17]")
        require(0.0 <= self.keypoint_margin <= 10.0, "keypoint_margin must be in [0, 10]")
        require(0.0 <= self.score_level <= 1.0, "score_level must be in [0, 1] (0: scores as given)")
        require(self.score_max_gain >= 1.0, "score_max_gain must be >= 1")


@dataclass
class Config:
    """The core sections of one profile."""

    fitting: FittingConfig
    lidar: ExtractionConfig
    people: PeopleConfig
    tracking: TrackingConfig

    def __post_init__(self) -> None:
        require(self.tracking.warm_profile in self.fitting.profiles,
                f"tracking.warm_profile {self.tracking.warm_profile!r} is not one of fitting.profiles "
                f"{sorted(self.fitting.profiles)}")


CORE_SECTIONS: dict[str, type] = {"fitting": FittingConfig, "lidar": ExtractionConfig, "people": PeopleConfig,
                                  "tracking": TrackingConfig}


def load_config(profile: str | Path | None = None, overrides: Mapping[str, Any] | None = None) -> Config:
    """The core configuration of `profile` (default: params/jackal_vlp16.yaml) with `overrides` applied
    (a nested mapping of sections, e.g. `{"fitting": {"min_points": 20}}`)."""
    values = load_sections(profile, overrides)
    missing = sorted(set(CORE_SECTIONS) - set(values))
    if missing:
        raise ConfigError(f"missing section {missing[0]!r} (params/base/{missing[0]}.yaml)")
    return Config(**{name: from_dict(cls, values[name], name) for name, cls in CORE_SECTIONS.items()})
