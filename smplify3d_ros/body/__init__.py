"""Body models behind one interface (`BodyModel`): Anny (default, embedded) and SMPL (user file)."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from smplify3d_ros.body.joints import BODY_JOINTS

if TYPE_CHECKING:
    from smplify3d_ros.body.base import BodyModel, BodyOutput


def __getattr__(name: str) -> Any:
    """`BodyModel`, `BodyOutput` on first use: they import torch, which `smpl-to-npz --help` need not."""
    if name in ("BodyModel", "BodyOutput"):
        from smplify3d_ros.body import base

        return getattr(base, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

__all__ = ["BODY_JOINTS", "BodyModel", "BodyOutput", "load_body_model"]

_CACHE: dict[tuple, BodyModel] = {}


def load_body_model(name: str = "anny", config=None, device: str = "cpu") -> BodyModel:
    """The body model `name`, built once per process and settings (building Anny takes seconds; the
    first build on a machine fills Anny's cache, about a minute: `smplify3d setup` does it ahead).

    `config` is a `fitting.config.BodyConfig`; without one, the defaults of params/base/fitting.yaml.
    """
    if config is None:
        from smplify3d_ros.config import load_config

        config = load_config().fitting.body
    key = (name, device, repr(config))
    if key not in _CACHE:
        if name == "anny":
            from smplify3d_ros.body.anny_model import AnnyBody

            model = AnnyBody(config.anny_shape_sigma, config.shape_bound_weight, config.anny_keypoint_support)
        elif name == "smpl":
            from smplify3d_ros.body.smpl_model import SmplBody

            model = SmplBody.from_config(config)
        else:
            raise ValueError(f"unknown body model {name!r}; known: 'anny', 'smpl'")
        _CACHE[key] = model.to(device).eval()
    return _CACHE[key]
