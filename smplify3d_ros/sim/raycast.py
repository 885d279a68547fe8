"""First-hit ray casting against a labelled triangle soup (Embree through trimesh).

The simulated LiDAR and the simulated camera both look at the same `RayScene`: one mesh holding every
person and every static surface, each face labelled with what it belongs to (person id >= 0,
`LABEL_GROUND`, `LABEL_STATIC`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh
from trimesh.ray.ray_pyembree import RayMeshIntersector

LABEL_GROUND = -1
LABEL_STATIC = -2
LABEL_NONE = -3  # the ray hit nothing


@dataclass
class RayHits:
    """First hits of N rays; rays that hit nothing have distance inf, face -1, label LABEL_NONE."""

    distance: np.ndarray  # (N,) float64, m along the unit ray direction
    face: np.ndarray  # (N,) int64 face index in the scene, -1 for none
    label: np.ndarray  # (N,) int32 what was hit
    normal: np.ndarray  # (N, 3) float64 unit face normal (zero for none)

    @property
    def hit(self) -> np.ndarray:
        return self.face >= 0


class RayScene:
    """A labelled triangle mesh with an Embree BVH, in one frame (the simulator uses the camera frame)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, face_labels: np.ndarray):
        self.vertices = np.asarray(vertices, dtype=np.float64)
        self.faces = np.asarray(faces, dtype=np.int64)
        self.face_labels = np.asarray(face_labels, dtype=np.int32)
        if len(self.face_labels) != len(self.faces):
            raise ValueError(f"{len(self.face_labels)} face labels for {len(self.faces)} faces")
        mesh = trimesh.Trimesh(self.vertices, self.faces, process=False, validate=False)
        self._intersector = RayMeshIntersector(mesh)
        self._intersector._scene  # noqa: B018 - build the BVH now, not inside the first query
        tri = self.vertices[self.faces]
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(normals, axis=1, keepdims=True)
        self.face_normals = normals / np.where(norm > 0, norm, 1.0)
        self.face_origin = tri[:, 0]

    @classmethod
    def from_parts(cls, parts: list[tuple[np.ndarray, np.ndarray, int]]) -> RayScene:
        """Concatenate (vertices, faces, label) parts into one scene."""
        verts, faces, labels = [], [], []
        offset = 0
        for v, f, label in parts:
            verts.append(np.asarray(v, dtype=np.float64))
            faces.append(np.asarray(f, dtype=np.int64) + offset)
            labels.append(np.full(len(f), label, dtype=np.int32))
            offset += len(v)
        return cls(np.concatenate(verts), np.concatenate(faces), np.concatenate(labels))

    def cast(self, origins: np.ndarray, directions: np.ndarray) -> RayHits:
        """First hit along each ray; `directions` are normalized here. Distances are exact plane hits."""
        directions = np.asarray(directions, dtype=np.float64)
        directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        origins = np.broadcast_to(np.asarray(origins, dtype=np.float64), directions.shape)
        face = np.asarray(self._intersector.intersects_first(origins, directions), dtype=np.int64)
        hit = face >= 0
        distance = np.full(len(face), np.inf)
        normal = np.zeros((len(face), 3))
        label = np.full(len(face), LABEL_NONE, dtype=np.int32)
        if hit.any():
            f = face[hit]
            n = self.face_normals[f]
            d = directions[hit]
            # Embree works in float32; recompute the distance to the hit face's plane in float64.
            denom = np.einsum("ij,ij->i", n, d)
            t = np.einsum("ij,ij->i", n, self.face_origin[f] - origins[hit]) / np.where(
                denom != 0, denom, 1e-12
            )
            distance[hit] = t
            normal[hit] = n
            label[hit] = self.face_labels[f]
        return RayHits(distance, face, label, normal)
