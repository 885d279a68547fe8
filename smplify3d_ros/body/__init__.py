"""Body models behind one interface (`BodyModel`): Anny (default, embedded) and SMPL (user file)."""

from __future__ import annotations

import contextlib
import io
import logging
import os
import sys
import tempfile
from collections.abc import Iterator
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
log = logging.getLogger(__name__)


def _quiet_warp() -> None:
    """Anny's skinning initializes NVIDIA Warp, which prints a banner and per-module load times unless told
    before `wp.init()` (run when anny's skinning module is imported): `warp.config.log_level` from Warp
    1.19 on, `warp.config.quiet` before."""
    try:
        import warp
    except ImportError:
        return
    if hasattr(warp.config, "log_level"):
        warp.config.log_level = getattr(warp, "LOG_WARNING", 30)
    else:
        warp.config.quiet = True


@contextlib.contextmanager
def _output_to_log(level: int) -> Iterator[None]:
    """What the body model's libraries write to stdout / stderr goes to this module's logger instead: at
    the file-descriptor level too, since Warp's native library prints its CUDA driver warning past
    sys.stdout. Only around the model's construction, before a node spins."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = (os.dup(1), os.dup(2))
    text = io.StringIO()
    with tempfile.TemporaryFile() as native:
        os.dup2(native.fileno(), 1)
        os.dup2(native.fileno(), 2)
        try:
            with contextlib.redirect_stdout(text), contextlib.redirect_stderr(text):
                yield
        finally:
            for fd, copy in zip((1, 2), saved, strict=True):
                os.dup2(copy, fd)
                os.close(copy)
            native.seek(0)
            lines = native.read().decode("utf-8", "replace").splitlines() + text.getvalue().splitlines()
    for line in lines:
        if line.strip():
            log.log(level, "%s", line.rstrip())


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
        _quiet_warp()
        # on a CPU the CUDA driver warning is expected: debug; on a GPU what Warp says may matter
        with _output_to_log(logging.DEBUG if device == "cpu" else logging.WARNING):
            _CACHE[key] = _build(name, config, device)
    return _CACHE[key]


def _build(name: str, config, device: str) -> BodyModel:
    if name == "anny":
        from smplify3d_ros.body.anny_model import AnnyBody

        model = AnnyBody(config.anny_shape_sigma, config.shape_bound_weight, config.anny_keypoint_support,
                         config.anny_shape_mean)
    elif name == "smpl":
        from smplify3d_ros.body.smpl_model import SmplBody

        model = SmplBody.from_config(config)
    else:
        raise ValueError(f"unknown body model {name!r}; known: 'anny', 'smpl'")
    return model.to(device).eval()
