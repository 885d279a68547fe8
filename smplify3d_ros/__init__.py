"""smplify3d_ros: SMPLify-3D human mesh recovery from camera keypoints and LiDAR, for ROS 2.

The library's entry points, imported on first use (so that `import smplify3d_ros` stays light):
`fit_frame(frame_or_observations, config, K)` fits one frame; `load_config(profile, overrides)` loads
the core configuration; `FrameFitter` is the frame path the node, the replay and the bench run.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_LAZY = {"fit_frame": "smplify3d_ros.frame_fitter", "FrameFitter": "smplify3d_ros.frame_fitter",
         "load_config": "smplify3d_ros.config"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
