"""BodyFit[] -> visualization_msgs/MarkerArray: a mesh, a skeleton and a label per person.

Namespaces and ids: `mesh` (TRIANGLE_LIST), `skeleton` (LINE_LIST of COCO-17 bones), `label`
(TEXT_VIEW_FACING "id 3"); the marker id is the person id in all three, the colour is fixed per id.
People present in `previous_ids` but not now get DELETE markers in all three namespaces, so RViz never
shows a stale body.

Speed: rclpy builds one Python object per geometry_msgs/Point, which dominates for big meshes. Points
are built once per vertex and shared by every triangle that uses the vertex (the list holds the same
object several times; do not mutate points in place). A 27k-triangle mesh converts in about 8 ms with
rclpy (12 ms with rosbags), but rclpy's publish() then spends about 35 ms converting the 81k Points to C;
`max_triangles` subsamples faces (leaving holes) where that is too slow.

Size: with `grid_m` (the node's `publish.geometry_grid_m`, 1/256 m) the mesh's coordinates are rounded to
the grid and given relative to the marker's pose (`mesh_origin`), and the triangles come in
`compressible_order`: the same mesh within half a grid cell, in about a third of the bytes a bag's zstd
chunks would otherwise need (a MarkerArray of three people: 1.2 MB raw).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from msg_adapters.factory import MessageFactory, resolve_factory
from smplify3d_ros.keypoints import COCO17_SKELETON, KP
from smplify3d_ros.types import BodyFit

MESH_NS, SKELETON_NS, LABEL_NS = "mesh", "skeleton", "label"
MARKER_NAMESPACES = (MESH_NS, SKELETON_NS, LABEL_NS)
# visualization_msgs/Marker constants (fixed by the message definition).
LINE_LIST, TEXT_VIEW_FACING, TRIANGLE_LIST = 5, 9, 11
ADD, DELETE = 0, 2

# Tableau-10: distinct, readable on RViz's dark background. RGB in [0, 1].
PALETTE: tuple[tuple[float, float, float], ...] = tuple(
    (int(h[0:2], 16) / 255.0, int(h[2:4], 16) / 255.0, int(h[4:6], 16) / 255.0)
    for h in ("1f77b4", "ff7f0e", "2ca02c", "d62728", "9467bd", "8c564b", "e377c2", "7f7f7f", "bcbd22",
              "17becf")
)


def person_color(person_id: int) -> tuple[float, float, float]:
    """The fixed RGB colour of a person id."""
    return PALETTE[int(person_id) % len(PALETTE)]


def decimate_faces(faces: np.ndarray, max_triangles: int | None) -> np.ndarray:
    """Every k-th face so that at most `max_triangles` remain (None or 0: all faces)."""
    if not max_triangles or len(faces) <= max_triangles:
        return faces
    return faces[:: -(-len(faces) // int(max_triangles))]


def compressible_order(faces: np.ndarray) -> np.ndarray:
    """The same triangles, same winding, each starting at its lowest vertex index and sorted by their
    indices: triangles that share vertices come together, which a bag's zstd chunks compress ~10 % better."""
    if not len(faces):
        return faces
    rotated = np.take_along_axis(faces, (np.argmin(faces, axis=1)[:, None] + np.arange(3)) % 3, axis=1)
    return rotated[np.lexsort((rotated[:, 2], rotated[:, 1], rotated[:, 0]))]


def _check_faces(faces: Any) -> np.ndarray:
    f = np.asarray(faces)
    if f.ndim != 2 or f.shape[1] != 3 or (f.size and f.dtype.kind not in "iu"):
        raise ValueError(f"faces must be an (F, 3) integer array, got {f.dtype} {f.shape}")
    if f.size and f.min() < 0:
        raise ValueError("faces contain negative vertex indices")
    return f.astype(np.int64, copy=False)


class _MarkerMaker:
    def __init__(self, factory: MessageFactory, stamp: Any, frame_id: str, alpha: float, lifetime_s: float):
        self.f = factory
        self.header = factory.header(stamp, frame_id)
        self.alpha = alpha
        self.lifetime = factory.duration(lifetime_s)

    def marker(self, ns: str, pid: int, kind: int, points: list | None = None, scale=(1.0, 1.0, 1.0),
               position=(0.0, 0.0, 0.0), text: str = "", alpha: float | None = None) -> Any:
        f = self.f
        r, g, b = person_color(pid)
        pose = f.make(
            "geometry_msgs/msg/Pose",
            position=f.make("geometry_msgs/msg/Point", x=position[0], y=position[1], z=position[2]),
            orientation=f.make("geometry_msgs/msg/Quaternion", x=0.0, y=0.0, z=0.0, w=1.0),
        )
        return f.make(
            "visualization_msgs/msg/Marker",
            header=self.header, ns=ns, id=pid, type=kind, action=ADD, pose=pose,
            scale=f.make("geometry_msgs/msg/Vector3", x=scale[0], y=scale[1], z=scale[2]),
            color=f.make("std_msgs/msg/ColorRGBA", r=r, g=g, b=b, a=self.alpha if alpha is None else alpha),
            lifetime=self.lifetime, points=points or [], text=text,
        )

    def delete(self, ns: str, pid: int) -> Any:
        return self.f.make("visualization_msgs/msg/Marker", header=self.header, ns=ns, id=pid, action=DELETE)


def snap(values: np.ndarray, grid_m: float) -> np.ndarray:
    """`values` rounded to multiples of `grid_m` (0: unchanged). A power-of-two grid (1/256 m) leaves
    most of each float's mantissa zero, which zstd compresses: a mesh topic's bag chunks halve."""
    return values if not grid_m else np.round(values / grid_m) * grid_m


# On a grid, a mesh marker's points are given relative to its pose, which is put 6 m short of the body's
# centre on each axis: every coordinate then lies in [4, 8) m, one binary exponent, and differs from the
# others only in its few low mantissa bits (about 20 % fewer compressed bytes than camera-frame points).
BINADE_CENTRE_M = 6.0


def mesh_origin(vertices: np.ndarray, grid_m: float) -> np.ndarray:
    """(3,) the mesh marker's position: on the grid, `BINADE_CENTRE_M` short of the finite vertices'
    centre (zeros without a grid or without finite vertices)."""
    finite = vertices[np.isfinite(vertices).all(axis=1)]
    if not grid_m or not len(finite):
        return np.zeros(3)
    return snap(finite.mean(axis=0), grid_m) - BINADE_CENTRE_M


def _mesh_points(factory: MessageFactory, verts: np.ndarray, faces: np.ndarray, decimated: bool) -> list:
    if len(faces) and faces.max() >= len(verts):
        raise ValueError(f"faces index vertex {faces.max()} but the mesh has {len(verts)} vertices")
    finite = np.isfinite(verts).all(axis=1)
    if not finite.all():
        faces = faces[finite[faces].all(axis=1)]
    idx = faces.reshape(-1)
    if decimated:  # build Points only for the vertices the kept faces use
        used, idx = np.unique(idx, return_inverse=True)
        verts = verts[used]
    points = factory.points(verts)
    return [points[i] for i in idx.tolist()]


def _skeleton_points(factory: MessageFactory, kp3d: np.ndarray) -> list:
    kp3d = np.asarray(kp3d, dtype=np.float64).reshape(-1, 3)
    bones = np.array([ab for ab in COCO17_SKELETON if max(ab) < len(kp3d)], dtype=np.int64).reshape(-1, 2)
    ok = np.isfinite(kp3d).all(axis=1)
    bones = bones[ok[bones].all(axis=1)]
    return factory.points(kp3d[bones.reshape(-1)])


def _label_position(kp3d: np.ndarray, offset: Sequence[float]) -> np.ndarray | None:
    kp3d = np.asarray(kp3d, dtype=np.float64).reshape(-1, 3)
    nose = KP["nose"]
    if len(kp3d) > nose and np.isfinite(kp3d[nose]).all():
        anchor = kp3d[nose]
    else:
        finite = kp3d[np.isfinite(kp3d).all(axis=1)]
        if len(finite) == 0:
            return None
        anchor = finite.mean(axis=0)
    return anchor + np.asarray(offset, dtype=np.float64)


def fits_to_markers(
    fits: Sequence[BodyFit],
    faces: np.ndarray | None,
    stamp: Any,
    frame_id: str,
    previous_ids: Iterable[int] = (),
    factory: MessageFactory | None = None,
    *,
    max_triangles: int | None = None,
    alpha: float = 0.8,
    line_width: float = 0.02,
    text_height: float = 0.12,
    label_offset: Sequence[float] = (0.0, -0.3, 0.0),
    lifetime_s: float = 0.0,
    grid_m: float = 0.0,
) -> tuple[Any, set[int]]:
    """Fits -> (MarkerArray, ids drawn now). Pass the returned ids as `previous_ids` next frame.

    `faces` (F, 3) are the body model's triangles (None: no mesh markers). `label_offset` (m) moves the
    label from the nose; the default is "up" in the camera optical frame (-y). `lifetime_s` 0 keeps
    markers until deleted. `grid_m` > 0 rounds the mesh's coordinates to that grid (`snap`); the mesh
    marker's points are then relative to its pose (`mesh_origin`), as RViz draws them. Raises ValueError
    for malformed faces or two fits with the same person id.
    """
    factory = resolve_factory(factory)
    mk = _MarkerMaker(factory, stamp, frame_id, alpha, lifetime_s)
    faces_used = None
    if faces is not None:
        all_faces = _check_faces(faces)
        faces_used = compressible_order(decimate_faces(all_faces, max_triangles))
    markers = []
    current: set[int] = set()
    for fit in fits:
        pid = int(fit.person_id)
        if pid in current:
            raise ValueError(f"two fits carry person id {pid}")
        if not -(2**31) <= pid < 2**31:
            raise ValueError(f"person id {pid} does not fit a Marker id (int32)")
        current.add(pid)
        if faces_used is not None:
            verts = np.asarray(fit.vertices, dtype=np.float64).reshape(-1, 3)
            origin = mesh_origin(verts, grid_m)
            points = _mesh_points(factory, snap(verts - origin, grid_m), faces_used, len(faces_used) < len(all_faces))
            markers.append(mk.marker(MESH_NS, pid, TRIANGLE_LIST, points, position=tuple(origin.tolist())))
        markers.append(mk.marker(SKELETON_NS, pid, LINE_LIST, _skeleton_points(factory, fit.keypoints3d),
                                 scale=(line_width, 0.0, 0.0), alpha=1.0))
        position = _label_position(fit.keypoints3d, label_offset)
        if position is not None:
            markers.append(mk.marker(LABEL_NS, pid, TEXT_VIEW_FACING, scale=(0.0, 0.0, text_height),
                                     position=tuple(position.tolist()), text=f"id {pid}", alpha=1.0))
    for pid in sorted({int(i) for i in previous_ids} - current):
        markers.extend(mk.delete(ns, pid) for ns in MARKER_NAMESPACES)
    return factory.make("visualization_msgs/msg/MarkerArray", markers=markers), current
