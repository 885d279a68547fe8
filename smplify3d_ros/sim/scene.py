"""Synthetic scenes: the robot's sensor mount, people standing on the ground, walls, boxes and pillars.

World frame: REP-103, on the ground under the camera: x forward, y left, z up. The camera optical frame
(x right, y down, z forward) sits `camera_height_m` above the origin, pitched down by `camera_pitch_deg`;
the LiDAR frame (x forward, y left, z up, level) sits above and behind it. People are posed by the body
model directly in the camera frame, then shifted vertically so that their lowest vertex touches the
ground. Static surfaces are built in the world frame and moved into the camera frame for ray casting.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
import trimesh
from scipy.spatial.transform import Rotation

from smplify3d_ros.body.joints import JOINT_INDEX
from smplify3d_ros.camera import transform_points
from smplify3d_ros.keypoints import PART_INDEX
from smplify3d_ros.sim.config import MountConfig, RenderConfig, SceneConfig
from smplify3d_ros.sim.poses import PROP_CARRIED_BOX, PROP_POST, PROP_SEAT, PROP_STEP, Pose
from smplify3d_ros.sim.raycast import LABEL_GROUND, LABEL_STATIC, RayScene
from smplify3d_ros.types import BodyParams

_PELVIS_START_HEIGHT = 1.0  # m, pelvis height before the body is dropped onto the ground
_SEAT_BEHIND_PELVIS = 1.0 / 3.0  # fraction of a seat's depth behind the hip joints (under the buttocks)
_SOLE_BAND_M = 0.04  # vertices this close above a foot's lowest one are its sole
_STEP_BEHIND_HEEL_M = 0.05  # a step reaches this far behind the raised heel; the rest lies ahead
_POST_MIN_HEIGHT_M = 0.9  # a leaning person's back touches the post above this height


# -- the sensor mount ---------------------------------------------------------------------------------
@dataclass
class Mount:
    T_world_cam: np.ndarray  # (4, 4) camera optical frame -> world
    T_world_lidar: np.ndarray  # (4, 4) LiDAR frame -> world

    @property
    def T_cam_world(self) -> np.ndarray:
        return np.linalg.inv(self.T_world_cam)

    @property
    def T_cam_lidar(self) -> np.ndarray:
        """LiDAR-frame points -> camera frame (the extrinsic a Frame carries)."""
        return self.T_cam_world @ self.T_world_lidar

    @property
    def up_cam(self) -> np.ndarray:
        """The world's up direction in the camera frame."""
        return self.T_cam_world[:3, :3] @ np.array([0.0, 0.0, 1.0])


def make_mount(cfg: MountConfig) -> Mount:
    p = np.deg2rad(cfg.camera_pitch_deg)
    x_c = np.array([0.0, -1.0, 0.0])  # optical x: right
    z_c = np.array([np.cos(p), 0.0, -np.sin(p)])  # optical z: forward, pitched down
    y_c = np.cross(z_c, x_c)  # optical y: down
    T_world_cam = np.eye(4)
    T_world_cam[:3, :3] = np.stack([x_c, y_c, z_c], axis=1)
    T_world_cam[:3, 3] = (0.0, 0.0, cfg.camera_height_m)
    T_world_lidar = np.eye(4)
    T_world_lidar[:3, 3] = (-cfg.lidar_behind_camera_m, 0.0, cfg.camera_height_m + cfg.lidar_above_camera_m)
    return Mount(T_world_cam, T_world_lidar)


# -- people -------------------------------------------------------------------------------------------
@dataclass
class PersonPlacement:
    """Where and how one person stands, before the body model poses them."""

    person_id: int
    preset: str
    shape: np.ndarray  # (S,) phenotypes
    pose: Pose
    position: np.ndarray  # (2,) world x, y of the pelvis, m
    heading: float  # rad, world yaw of the direction the person faces (0: +x, away from the robot)


@dataclass
class PlacedPerson:
    """A posed person: ground-truth parameters and geometry in the camera frame."""

    placement: PersonPlacement
    params: BodyParams
    vertices: np.ndarray  # (V, 3) float32, camera frame
    joints: np.ndarray  # (J, 3) float32
    keypoints3d: np.ndarray  # (17, 3) float32

    @property
    def person_id(self) -> int:
        return self.placement.person_id


def body_rotation_world(heading: float, lean_deg: float) -> np.ndarray:
    """Canonical body axes (x left, y up, z forward) -> world, facing `heading`, leaning forward."""
    forward = np.array([np.cos(heading), np.sin(heading), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    left = np.cross(up, forward)
    R = np.stack([left, up, forward], axis=1)
    lean = np.deg2rad(lean_deg)
    Rx = np.array([[1, 0, 0], [0, np.cos(lean), -np.sin(lean)], [0, np.sin(lean), np.cos(lean)]])
    return R @ Rx


def pose_people(model, placements: list[PersonPlacement], mount: Mount) -> list[PlacedPerson]:
    """Pose every person with one batched forward pass and drop each onto the ground (z = 0)."""
    if not placements:
        return []
    R_cw = mount.T_cam_world[:3, :3]
    root, transl = [], []
    for pl in placements:
        R = R_cw @ body_rotation_world(pl.heading, pl.pose.lean_deg)
        root.append(Rotation.from_matrix(R).as_rotvec())
        p_world = np.array([pl.position[0], pl.position[1], _PELVIS_START_HEIGHT])
        transl.append(transform_points(p_world[None], mount.T_cam_world)[0])
    dtype = torch.get_default_dtype()
    with torch.no_grad():
        out = model(
            torch.as_tensor(np.stack([pl.shape for pl in placements]), dtype=dtype),
            torch.as_tensor(np.stack([pl.pose.pose for pl in placements]), dtype=dtype),
            torch.as_tensor(np.stack(root), dtype=dtype),
            torch.as_tensor(np.stack(transl), dtype=dtype),
        )
    up = mount.up_cam
    height0 = mount.T_world_cam[2, 3]
    people = []
    for i, pl in enumerate(placements):
        verts = out.vertices[i].double().numpy()
        lowest = float((verts @ up).min()) + height0  # world z of the lowest vertex
        shift = -lowest * up
        params = BodyParams(
            model.name,
            pl.shape.astype(np.float64),
            pl.pose.pose.astype(np.float64),
            root[i].astype(np.float64),
            (transl[i] + shift).astype(np.float64),
        )
        people.append(
            PlacedPerson(
                placement=pl,
                params=params,
                vertices=(verts + shift).astype(np.float32),
                joints=(out.joints[i].double().numpy() + shift).astype(np.float32),
                keypoints3d=(out.keypoints[i].double().numpy() + shift).astype(np.float32),
            )
        )
    return people


def footprint(vertices_world: np.ndarray) -> tuple[np.ndarray, float]:
    """Centre (x, y) and radius of the smallest centred circle holding a body's ground projection."""
    centre = 0.5 * (vertices_world[:, :2].min(axis=0) + vertices_world[:, :2].max(axis=0))
    radius = float(np.linalg.norm(vertices_world[:, :2] - centre, axis=1).max())
    return centre, radius


# -- static objects -----------------------------------------------------------------------------------
@dataclass
class SceneObject:
    """A static surface in the world frame."""

    kind: str  # "ground", "wall", "box", "pillar", "seat", "carried_box"
    vertices: np.ndarray  # (n, 3) float64, world frame
    faces: np.ndarray  # (m, 3) int64

    @property
    def label(self) -> int:
        return LABEL_GROUND if self.kind == "ground" else LABEL_STATIC


def ground_plane(half_size: float) -> SceneObject:
    s = half_size
    v = np.array([[-s, -s, 0.0], [s, -s, 0.0], [s, s, 0.0], [-s, s, 0.0]])
    return SceneObject("ground", v, np.array([[0, 1, 2], [0, 2, 3]]))


def box_object(
    kind: str, centre: np.ndarray, extents: np.ndarray, R: np.ndarray | None = None
) -> SceneObject:
    """An axis-aligned box of `extents` (x, y, z), rotated by R about its centre, in the world frame."""
    mesh = trimesh.creation.box(extents=extents)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    if R is not None:
        v = v @ R.T
    return SceneObject(kind, v + centre, np.asarray(mesh.faces, dtype=np.int64))


def pillar_object(centre_xy: np.ndarray, radius: float, height: float) -> SceneObject:
    mesh = trimesh.creation.cylinder(radius=radius, height=height, sections=24)
    v = np.asarray(mesh.vertices, dtype=np.float64) + [centre_xy[0], centre_xy[1], height / 2.0]
    return SceneObject("pillar", v, np.asarray(mesh.faces, dtype=np.int64))


def wall_object(a: np.ndarray, b: np.ndarray, height: float) -> SceneObject:
    """A vertical rectangle from ground point a to ground point b."""
    v = np.array([[a[0], a[1], 0.0], [b[0], b[1], 0.0], [b[0], b[1], height], [a[0], a[1], height]])
    return SceneObject("wall", v, np.array([[0, 1, 2], [0, 2, 3]]))


def room_walls(front: float, back: float, half_width: float, height: float) -> list[SceneObject]:
    c = [
        np.array(p)
        for p in ((front, half_width), (front, -half_width), (-back, -half_width), (-back, half_width))
    ]
    return [wall_object(c[i], c[(i + 1) % 4], height) for i in range(4)]


def vertices_world(person: PlacedPerson, mount: Mount) -> np.ndarray:
    """A posed person's vertices in the world frame (float64)."""
    return transform_points(person.vertices.astype(np.float64), mount.T_world_cam)


def prop_objects(person: PlacedPerson, model, mount: Mount, cfg: SceneConfig) -> list[SceneObject]:
    """A seat under a sitting person, a box between a carrying person's hands."""
    props = person.placement.pose.props
    if not props:
        return []
    verts = vertices_world(person, mount)
    R_body = body_rotation_world(person.placement.heading, 0.0)  # level body axes in the world
    left, forward = R_body[:, 0], R_body[:, 2]
    objects = []
    if PROP_SEAT in props:
        pelvis = transform_points(person.params.transl[None], mount.T_world_cam)[0]
        width, depth = cfg.seat_size_m
        centre = pelvis[:2] + forward[:2] * (depth / 2.0 - _SEAT_BEHIND_PELVIS * depth)
        rel = verts[:, :2] - centre
        inside = (np.abs(rel @ left[:2]) <= width / 2) & (np.abs(rel @ forward[:2]) <= depth / 2)
        seat_parts = [PART_INDEX[p] for p in ("torso", "left_upper_leg", "right_upper_leg")]
        vertex_part = _vertex_parts(model)
        inside &= np.isin(vertex_part, seat_parts)
        top = float(verts[inside, 2].min()) if inside.any() else float(pelvis[2])
        if top > 0.05:
            c = np.array([centre[0], centre[1], top / 2.0])
            objects.append(box_object("seat", c, np.array([width, top, depth]), R_body))
    if PROP_STEP in props and person.placement.pose.side is not None:
        objects += _step_under_foot(person, model, verts, forward, left, cfg)
    if PROP_POST in props:
        objects.append(_post_behind(person, verts, forward, cfg))
    if PROP_CARRIED_BOX in props:
        joints = transform_points(person.joints.astype(np.float64), mount.T_world_cam)
        lw, rw = joints[JOINT_INDEX["left_wrist"]], joints[JOINT_INDEX["right_wrist"]]
        width_box, height_box, depth_box = cfg.carried_box_m
        width_box = min(width_box, max(abs((lw - rw) @ left) - 0.06, 0.15))
        centre = 0.5 * (lw + rw) + forward * 0.02
        objects.append(
            box_object("carried_box", centre, np.array([width_box, height_box, depth_box]), R_body)
        )
    return objects


def _step_under_foot(person: PlacedPerson, model, verts: np.ndarray, forward: np.ndarray, left: np.ndarray,
                     cfg: SceneConfig) -> list[SceneObject]:
    """A step whose top carries the raised foot's sole, reaching ahead of it (none if the foot is low)."""
    foot = verts[_vertex_parts(model) == PART_INDEX[f"{person.placement.pose.side}_lower_leg"]]
    top = float(foot[:, 2].min())
    if top < 0.05:
        return []
    sole = foot[foot[:, 2] < top + _SOLE_BAND_M]
    heel = float((sole[:, :2] @ forward[:2]).min())
    width, depth = cfg.step_size_m
    along = heel - _STEP_BEHIND_HEEL_M + depth / 2.0
    across = float(sole[:, :2].mean(axis=0) @ left[:2])
    centre = along * forward[:2] + across * left[:2]
    R_body = np.stack([left, np.array([0.0, 0.0, 1.0]), forward], axis=1)
    return [box_object("step", np.array([centre[0], centre[1], top / 2.0]), np.array([width, top, depth]), R_body)]


def _post_behind(person: PlacedPerson, verts: np.ndarray, forward: np.ndarray, cfg: SceneConfig) -> SceneObject:
    """A vertical post touching the back of a leaning person (above `_POST_MIN_HEIGHT_M`)."""
    high = verts[verts[:, 2] > _POST_MIN_HEIGHT_M]
    back = float((high[:, :2] @ forward[:2]).min())
    radius = cfg.post_radius_m
    centre_line = float(high[:, :2].mean(axis=0) @ np.array([-forward[1], forward[0]]))
    side = np.array([-forward[1], forward[0]])
    centre = (back - radius) * forward[:2] + centre_line * side
    return pillar_object(centre, radius, cfg.pillar_height_m)


_VERTEX_PART_CACHE: dict[int, np.ndarray] = {}


def _vertex_parts(model) -> np.ndarray:
    """(V,) body part of each vertex (the part of its first face), -1 for none."""
    key = id(model)
    if key not in _VERTEX_PART_CACHE:
        faces = model.faces.cpu().numpy()
        parts = model.part_of_face.cpu().numpy()
        n_vertices = int(faces.max()) + 1
        out = np.full(n_vertices, -1, dtype=np.int64)
        out[faces[::-1].ravel()] = np.repeat(parts[::-1], 3)
        _VERTEX_PART_CACHE[key] = out
    return _VERTEX_PART_CACHE[key]


def move_person(person: PlacedPerson, position: np.ndarray, mount: Mount) -> PlacedPerson:
    """The same body with its pelvis moved horizontally to world `position` (x, y)."""
    delta_world = np.array(
        [position[0] - person.placement.position[0], position[1] - person.placement.position[1], 0.0]
    )
    delta = mount.T_cam_world[:3, :3] @ delta_world
    placement = PersonPlacement(
        person.placement.person_id,
        person.placement.preset,
        person.placement.shape,
        person.placement.pose,
        np.asarray(position, dtype=np.float64),
        person.placement.heading,
    )
    params = person.params.copy()
    params.transl = params.transl + delta
    return PlacedPerson(
        placement,
        params,
        (person.vertices + delta).astype(np.float32),
        (person.joints + delta).astype(np.float32),
        (person.keypoints3d + delta).astype(np.float32),
    )


def turn_person(person: PlacedPerson, angle: float, mount: Mount, model) -> PlacedPerson:
    """The same body turned by `angle` (rad, counter-clockwise from above) about the vertical through
    its footprint's centre: it stays inside its footprint circle, so every clearance placement checked
    against that circle still holds."""
    from smplify3d_ros.geometry import move_body

    centre, _ = footprint(vertices_world(person, mount))
    c, s = np.cos(angle), np.sin(angle)
    T_world = np.eye(4)
    T_world[:2, :2] = [[c, -s], [s, c]]
    T_world[:2, 3] = centre - T_world[:2, :2] @ centre
    T = mount.T_cam_world @ T_world @ mount.T_world_cam
    params = person.params.copy()
    dtype = torch.get_default_dtype()
    with torch.no_grad():
        rotation_centre = model.rotation_center(torch.as_tensor(params.shape[None], dtype=dtype),
                                                torch.as_tensor(params.transl[None], dtype=dtype))[0]
    params.root_orient, params.transl, _ = move_body(params.root_orient, params.transl,
                                                     rotation_centre.double().numpy(), T)
    pl = person.placement
    placement = PersonPlacement(pl.person_id, pl.preset, pl.shape, pl.pose,
                                T_world[:2, :2] @ pl.position + T_world[:2, 3], pl.heading + angle)

    def moved(points: np.ndarray) -> np.ndarray:
        return transform_points(points.astype(np.float64), T).astype(np.float32)

    return PlacedPerson(placement, params, moved(person.vertices), moved(person.joints), moved(person.keypoints3d))


# -- random layouts -----------------------------------------------------------------------------------
@dataclass
class Scene:
    """Everything in front of the sensors, ready for ray casting (camera frame)."""

    mount: Mount
    people: list[PlacedPerson]
    objects: list[SceneObject]
    ray_scene: RayScene
    face_colors: np.ndarray  # (F, 3) uint8 albedo of every ray-scene face
    person_faces: dict[int, slice] = field(default_factory=dict)  # faces of each person in the ray scene


def _circles_clear(
    centre: np.ndarray, radius: float, circles: list[tuple[np.ndarray, float]], gap: float
) -> bool:
    return all(np.linalg.norm(centre - c) >= radius + r + gap for c, r in circles)


def place_people(
    rng: np.random.Generator,
    people: list[PlacedPerson],
    mount: Mount,
    cfg: SceneConfig,
    distance_range: tuple[float, float],
    half_fov: float,
) -> list[PlacedPerson]:
    """Spread posed people (pelvis at the world origin) over the camera's view without overlaps.

    Bearings stay `fov_margin_deg` inside the horizontal field of view; with `occlusion_pair_prob` a
    person goes right behind someone already placed, so that they occlude each other.
    """
    max_bearing = max(half_fov - np.deg2rad(cfg.fov_margin_deg), 0.0)
    placed: list[PlacedPerson] = []
    circles: list[tuple[np.ndarray, float]] = []
    for person in people:
        centre0, radius = footprint(vertices_world(person, mount))
        offset = centre0 - person.placement.position
        position = None
        for _ in range(cfg.placement_tries):
            if placed and rng.random() < cfg.occlusion_pair_prob:
                k = int(rng.integers(len(placed)))
                front = placed[k].placement.position
                bearing = np.arctan2(front[1], front[0]) + np.deg2rad(
                    rng.uniform(-cfg.occlusion_bearing_deg, cfg.occlusion_bearing_deg)
                )
                distance = np.linalg.norm(front) + circles[k][1] + radius + rng.uniform(*cfg.occlusion_gap_m)
                if distance > distance_range[1]:
                    continue
            else:
                bearing = rng.uniform(-max_bearing, max_bearing)
                distance = rng.uniform(*distance_range)
            candidate = distance * np.array([np.cos(bearing), np.sin(bearing)])
            if _circles_clear(candidate + offset, radius, circles, cfg.person_gap_m):
                position = candidate
                break
        if position is None:
            continue  # crowded: leave this person out rather than overlap bodies
        moved = move_person(person, position, mount)
        placed.append(moved)
        circles.append((position + offset, radius))
    return placed


def random_objects(
    rng: np.random.Generator,
    cfg: SceneConfig,
    keep_out: list[tuple[np.ndarray, float]],
    room: tuple[float, float, float] | None,
    half_fov: float,
) -> list[SceneObject]:
    """Boxes and pillars around the robot, clear of people (`keep_out` circles) and of each other.

    `room` = (front, back, half_width) keeps them inside the walls.
    """
    objects: list[SceneObject] = []
    circles = list(keep_out)
    n_boxes = int(rng.integers(cfg.n_boxes[0], cfg.n_boxes[1] + 1))
    n_pillars = int(rng.integers(cfg.n_pillars[0], cfg.n_pillars[1] + 1))
    for kind in ["box"] * n_boxes + ["pillar"] * n_pillars:
        if kind == "box":
            size = rng.uniform(*cfg.box_size_m, 2)
            height = rng.uniform(*cfg.box_height_m)
            radius = float(np.linalg.norm(size) / 2)
        else:
            radius = float(rng.uniform(*cfg.pillar_radius_m))
        for _ in range(cfg.placement_tries):
            distance = rng.uniform(*cfg.object_distance_m)
            bearing = rng.uniform(-np.pi, np.pi) if rng.random() < 0.5 else rng.uniform(-half_fov, half_fov)
            centre = distance * np.array([np.cos(bearing), np.sin(bearing)])
            if room is not None:
                front, back, half_width = room
                if not (-back + radius < centre[0] < front - radius and abs(centre[1]) < half_width - radius):
                    continue
            if not _circles_clear(centre, radius, circles, cfg.object_clearance_m):
                continue
            if kind == "box":
                yaw = rng.uniform(0, np.pi / 2)
                R = Rotation.from_euler("z", yaw).as_matrix()
                objects.append(
                    box_object("box", np.array([*centre, height / 2]), np.array([*size, height]), R)
                )
            else:
                objects.append(pillar_object(centre, radius, cfg.pillar_height_m))
            circles.append((centre, radius))
            break
    return objects


def room_for(rng: np.random.Generator, cfg: SceneConfig, circles: list[tuple[np.ndarray, float]]):
    """(front, back, half_width) of a room enclosing every circle with a margin."""
    far = max((c[0] + r for c, r in circles), default=0.0)
    side = max((abs(c[1]) + r for c, r in circles), default=0.0)
    margin = rng.uniform(*cfg.wall_margin_m)
    front = far + margin
    half_width = max(rng.uniform(*cfg.room_half_width_m), side + cfg.wall_margin_m[0])
    return front, cfg.room_back_m, half_width


def person_colors(rng: np.random.Generator, model, style: RenderConfig) -> np.ndarray:
    """(F, 3) uint8 albedo of a person's faces: skin, a top, trousers; bare forearms half the time."""
    palette = np.asarray(style.clothing_palette, dtype=np.uint8)
    top, bottom = rng.choice(len(palette), 2, replace=False)
    parts = model.part_of_face.cpu().numpy()
    colors = np.empty((len(parts), 3), dtype=np.uint8)
    colors[:] = style.skin_rgb
    upper = ["torso", "left_upper_arm", "right_upper_arm"]
    if rng.random() < 0.5:
        upper += ["left_lower_arm", "right_lower_arm"]
    colors[np.isin(parts, [PART_INDEX[p] for p in upper])] = palette[top]
    legs = ["left_upper_leg", "right_upper_leg", "left_lower_leg", "right_lower_leg"]
    colors[np.isin(parts, [PART_INDEX[p] for p in legs])] = palette[bottom]
    return colors


def assemble(
    rng: np.random.Generator,
    model,
    mount: Mount,
    people: list[PlacedPerson],
    objects: list[SceneObject],
    style: RenderConfig,
) -> Scene:
    """Everything into one labelled camera-frame `RayScene` with per-face colours."""
    parts, colors, person_faces = [], [], {}
    faces = model.faces.cpu().numpy()
    n_faces = 0
    for person in people:
        parts.append((person.vertices, faces, person.person_id))
        colors.append(person_colors(rng, model, style))
        person_faces[person.person_id] = slice(n_faces, n_faces + len(faces))
        n_faces += len(faces)
    kind_rgb = {"ground": style.ground_rgb, "wall": style.wall_rgb}
    for obj in objects:
        parts.append((transform_points(obj.vertices, mount.T_cam_world), obj.faces, obj.label))
        colors.append(
            np.tile(np.asarray(kind_rgb.get(obj.kind, style.object_rgb), np.uint8), (len(obj.faces), 1))
        )
        n_faces += len(obj.faces)
    return Scene(mount, people, objects, RayScene.from_parts(parts), np.concatenate(colors), person_faces)
