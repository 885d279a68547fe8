"""Free space: a LiDAR return says that its beam crossed empty space on the way to it.

L_3D binds each point to the body's nearest visible vertex, but nothing in it keeps the body out of the
space the beams went through: a forearm the image sees end-on can be placed pointing at the sensor, in
front of the torso points the beams reached past it, at no cost (the vertex-to-point half, which would
object, is off for ring-scanning LiDARs: it pulls the body onto the rings). This term objects. As a
stage that moves the pose starts, each of a person's beams (sensor to point) is cast against their
current mesh; a beam that hits the body more than `free_space_margin_m` short of its point is blocked,
and the L_3D vertex nearest the hit stands for it during the stage (like ICP's correspondences), pushed
back along the beam until it is no longer short:

    L_free = (1/m) Σ_blocked min(0, u·(v − o) − limit)²

over the person's m points, with o the sensor, u the beam's direction, v the stand-in vertex and limit
the point's range less the margin, moved by the vertex's offset from the hit along the beam. The beams
are cast against the mesh's faces, not tested against its vertices: near silhouettes, folds and hands a
beam passes within millimetres of vertices it never hits. On the true bodies of simulated VLP-16 scenes
(tuning seeds 0-39, 2-8 m, 74 people), a vertex test (a vertex within 3 cm of a beam and 5 cm short of
its point) found 72 of the 74 bodies blocking their own beams, with 8,797 such vertices; the cast finds
75 blocked beams in all, half of them short by less than 5 mm (range noise).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

_CANDIDATE_VERTICES = 12  # vertices nearest a beam in direction whose faces are tested against it
_FACE_M = 0.03  # m, larger than a face of the body meshes: a face's corners lie within this of any point of it


@dataclass
class BlockedBeams:
    """The beams each person's body blocks short of their points, (B, k, ...) padded per person; each tied
    to the L_3D vertex nearest its hit, which stands for the hit until the beams are cast again."""

    rows: torch.Tensor  # (B, k) int64 that vertex, as a position in the problem's vertex rows
    direction: torch.Tensor  # (B, k, 3) the beam's unit direction
    limit: torch.Tensor  # (B, k) the range along the beam (m) the vertex must reach (see `blocked_beams`)
    mask: torch.Tensor  # (B, k) bool

    def __getitem__(self, rows: torch.Tensor) -> BlockedBeams:
        return BlockedBeams(self.rows[rows], self.direction[rows], self.limit[rows], self.mask[rows])


def vertex_faces(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """(V, D) int64 the faces around each vertex, padded with −1."""
    order = np.argsort(faces.ravel(), kind="stable")
    vertex = faces.ravel()[order]
    counts = np.bincount(vertex, minlength=n_vertices)
    out = np.full((n_vertices, max(int(counts.max()), 1)), -1, dtype=np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out[vertex, np.arange(len(vertex)) - starts[vertex]] = order // 3
    return out


def first_hits(vertices: np.ndarray, faces: np.ndarray, candidates: np.ndarray, origin: np.ndarray,
               directions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first of each beam's `candidates` (m, c) faces (−1: none) it crosses (Möller-Trumbore): face
    (m,) (−1: none), range (m,) (inf: none) and barycentric coordinates (m, 3) of the hit."""
    corner = vertices[faces[np.maximum(candidates, 0)]]  # (m, c, 3 corners, 3)
    v0 = corner[:, :, 0]
    e1, e2 = corner[:, :, 1] - v0, corner[:, :, 2] - v0
    d = np.broadcast_to(directions[:, None], e1.shape)
    p = np.cross(d, e2)
    det = (e1 * p).sum(-1)
    ok = (candidates >= 0) & (np.abs(det) > 1e-12)
    inv = 1.0 / np.where(ok, det, 1.0)
    s = origin - v0
    u = (s * p).sum(-1) * inv
    q = np.cross(s, e1)
    v = (d * q).sum(-1) * inv
    t = (e2 * q).sum(-1) * inv
    hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 0)
    t = np.where(hit, t, np.inf)
    best = np.argmin(t, axis=1)
    rows = np.arange(len(t))
    face = np.where(np.isfinite(t[rows, best]), candidates[rows, best], -1)
    ub, vb = u[rows, best], v[rows, best]
    return face, t[rows, best], np.stack([1.0 - ub - vb, ub, vb], axis=-1)


def blocked_beams(vertices: np.ndarray, faces: np.ndarray, around: np.ndarray, visible: np.ndarray,
                  points: np.ndarray, origin: np.ndarray, margin: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One person's blocked beams: where each first hits the body (k, 3), its direction (k, 3) and its
    limit (k,), the range the hit must reach (the point's less `margin`). vertices (V, 3) the whole mesh,
    `around` its `vertex_faces`, `visible` (V,) bool the vertices facing the sensor (a beam's first hit is
    on a face whose corners all face it), points (m, 3)."""
    empty = (np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
    ids = np.flatnonzero(visible)
    if len(points) == 0 or len(ids) < 3:
        return empty
    ray = points.astype(np.float64) - origin
    reach = np.linalg.norm(ray, axis=1)
    direction = ray / np.maximum(reach, 1e-9)[:, None]
    toward = vertices[ids] - origin
    distance = np.linalg.norm(toward, axis=1)
    toward /= np.maximum(distance, 1e-9)[:, None]
    k = min(_CANDIDATE_VERTICES, len(ids))
    _, near = cKDTree(toward).query(direction, k=k, workers=1)
    near = near.reshape(len(points), k)
    # a beam none of whose nearby vertices is short of its point by the margin (less a face's size) is
    # not blocked: only the others are cast
    maybe = np.flatnonzero((distance[near] < (reach - margin + _FACE_M)[:, None]).any(axis=1))
    if not len(maybe):
        return empty
    candidates = around[ids[near[maybe]]].reshape(len(maybe), -1)
    face, hit_range, _ = first_hits(vertices, faces, candidates, origin, direction[maybe])
    blocked = (face >= 0) & (hit_range < reach[maybe] - margin)
    rows = maybe[blocked]
    hits = origin + direction[rows] * hit_range[blocked][:, None]
    return hits, direction[rows], reach[rows] - margin


def tie_to_vertices(vertices: np.ndarray, hits: np.ndarray, direction: np.ndarray, limit: np.ndarray,
                    origin: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each blocked beam's stand-in among `vertices` (n, 3) (a person's L_3D vertices): the one nearest
    its hit (k,), and the limit moved by the vertex's offset along the beam from the hit (k,), so that
    the vertex is clear exactly when the hit would be."""
    if len(hits) == 0 or len(vertices) == 0:
        return np.zeros(0, np.int64), np.zeros(0)
    _, row = cKDTree(vertices).query(hits, workers=1)
    offset = ((vertices[row] - hits) * direction).sum(-1)
    return row.astype(np.int64), limit + offset


def shortfall(vertices: torch.Tensor, beams: BlockedBeams, origin: torch.Tensor) -> torch.Tensor:
    """(B, k) how far each blocked beam's vertex in `vertices` (B, n, 3) still lies short of its limit
    (m, negative; 0 once it is not, and for padding)."""
    v = torch.gather(vertices, 1, beams.rows[..., None].expand(-1, -1, 3))
    gap = ((v - origin) * beams.direction).sum(-1) - beams.limit
    return torch.where(beams.mask, gap.clamp(max=0.0), torch.zeros_like(gap))


def free_space_loss(vertices: torch.Tensor, beams: BlockedBeams, origin: torch.Tensor,
                    point_mask: torch.Tensor) -> torch.Tensor:
    """(B,) L_free, m² per point (see the module's docstring)."""
    m = point_mask.sum(-1).clamp(min=1)
    return (shortfall(vertices, beams, origin) ** 2).sum(-1) / m
