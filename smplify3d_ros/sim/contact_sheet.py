"""Contact sheets of the simulator's pose library and body shapes, to check by eye that they look human.

    python -m smplify3d_ros.sim.contact_sheet [--out docs/pose_library.png] [--shapes docs/body_shapes.png]

Each pose family is drawn from the front and from the side (two random samples each; walking and
running at two gait phases), rendered with the simulator's own ray-cast camera.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from smplify3d_ros.sim.camera import render
from smplify3d_ros.sim.config import MountConfig, SimConfig, default_sim_config
from smplify3d_ros.sim.people import SHAPE_PRESETS, preset_shape
from smplify3d_ros.sim.poses import FAMILIES, PHASED_FAMILIES, sample_pose
from smplify3d_ros.sim.scene import (
    PersonPlacement,
    assemble,
    ground_plane,
    make_mount,
    pose_people,
    prop_objects,
)
from smplify3d_ros.types import CameraModel

_VIEW_DISTANCE = 3.6  # m from camera to pelvis
_VIEW_HEIGHT = 1.0  # m camera height, looking level
_VIEW_SIZE = (220, 330)  # width, height in pixels
_VIEW_FOCAL = 330.0  # px


def _view_camera() -> CameraModel:
    w, h = _VIEW_SIZE
    K = np.array([[_VIEW_FOCAL, 0, (w - 1) / 2], [0, _VIEW_FOCAL, (h - 1) / 2], [0, 0, 1.0]])
    return CameraModel(K=K, width=w, height=h)


def render_person(model, cfg: SimConfig, shape: np.ndarray, pose, heading: float) -> np.ndarray:
    """(H, W, 3) image of one person at `_VIEW_DISTANCE` in front of a level camera."""
    mount = make_mount(MountConfig(_VIEW_HEIGHT, 0.0, 0.0, 0.0))
    placement = PersonPlacement(0, "", shape, pose, np.array([_VIEW_DISTANCE, 0.0]), heading)
    person = pose_people(model, [placement], mount)[0]
    objects = [ground_plane(cfg.scene.ground_half_size_m)]
    objects += prop_objects(person, model, mount, cfg.scene)
    style = dataclasses.replace(cfg.render, clothing_palette=list(cfg.render.clothing_palette[:2]))
    scene = assemble(np.random.default_rng(0), model, mount, [person], objects, style)
    return render(scene.ray_scene, _view_camera(), scene.face_colors, style, mount.T_world_cam).image


def pose_sheet(model, cfg: SimConfig, out: Path, seed: int = 0) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(seed)
    shape = preset_shape("adult_male", model.shape_names)
    samples = 2
    fig, axes = plt.subplots(2 * samples, len(FAMILIES), figsize=(len(FAMILIES) * 1.6, 2 * samples * 2.3))
    for col, family in enumerate(FAMILIES):
        for s in range(samples):
            phase = s / samples + 0.1 if family in PHASED_FAMILIES else None
            pose = sample_pose(model, family, rng, phase=phase)
            for v, (view, heading) in enumerate((("front", np.pi), ("side", np.pi / 2))):
                ax = axes[2 * s + v, col]
                ax.imshow(render_person(model, cfg, shape, pose, heading))
                ax.set_xticks([])
                ax.set_yticks([])
                title = f"{family} {view}" + (f" φ={phase:.2f}" if phase is not None else "")
                ax.set_title(title, fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def shape_sheet(model, cfg: SimConfig, out: Path, seed: int = 0) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(seed)
    names = list(SHAPE_PRESETS)
    fig, axes = plt.subplots(2, len(names), figsize=(len(names) * 1.6, 2 * 2.3))
    for col, name in enumerate(names):
        shape = preset_shape(name, model.shape_names)
        pose = sample_pose(model, "standing", rng, variation_scale=0.0)
        for row, heading in enumerate((np.pi, np.pi / 2)):
            ax = axes[row, col]
            ax.imshow(render_person(model, cfg, shape, pose, heading))
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(name, fontsize=7)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/pose_library.png"))
    parser.add_argument("--shapes", type=Path, default=Path("docs/body_shapes.png"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    from smplify3d_ros.body import load_body_model

    cfg = default_sim_config()
    model = load_body_model(cfg.body_model)
    pose_sheet(model, cfg, args.out, args.seed)
    shape_sheet(model, cfg, args.shapes, args.seed)
    print(f"wrote {args.out} and {args.shapes}")


if __name__ == "__main__":
    main()
