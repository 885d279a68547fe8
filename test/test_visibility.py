"""Back-face culling (Eq. 1) and the keypoint-confidence rule."""

import numpy as np

from smplify3d_ros.fitting.visibility import front_facing, occluded_parts, visible_vertices
from smplify3d_ros.keypoints import KP, PART_INDEX, PART_NAMES


def _two_faces():
    # two triangles at z = 5: one facing the camera (normal -z), one facing away (normal +z)
    v = np.array([[0, 0, 5], [0, 1, 5], [1, 0, 5], [2, 0, 5], [3, 0, 5], [2, 1, 5]], dtype=float)
    f = np.array([[0, 1, 2], [3, 4, 5]])
    return v, f


def test_front_facing_threshold():
    v, f = _two_faces()
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert n[0, 2] < 0 < n[1, 2]
    vis = front_facing(v, f, np.zeros(3), 0.0)
    assert vis.tolist() == [True, False]
    assert front_facing(v, f, np.zeros(3), -1.0).tolist() == [True, True]  # -1 disables culling
    # a sensor behind the faces sees the other one
    assert front_facing(v, f, np.array([0, 0, 10.0]), 0.0).tolist() == [False, True]


def test_occluded_parts_rule():
    scores = np.ones(17)
    scores[KP["left_elbow"]] = 0.2
    occ = occluded_parts(scores, 0.6)
    expected = {"left_upper_arm", "left_lower_arm"}
    assert {PART_NAMES[i] for i in np.flatnonzero(occ)} == expected


def test_visible_vertices_drops_occluded_parts_and_internal_faces():
    v, f = _two_faces()
    parts = np.array([PART_INDEX["torso"], PART_INDEX["head"]])
    occ = np.zeros(len(PART_NAMES), dtype=bool)
    mask = visible_vertices(v, f, parts, np.zeros(3), -1.0, occ)
    assert mask.all()
    occ[PART_INDEX["torso"]] = True
    mask = visible_vertices(v, f, parts, np.zeros(3), -1.0, occ)
    assert mask.tolist() == [False, False, False, True, True, True]
    parts[1] = -1  # internal face
    assert not visible_vertices(v, f, parts, np.zeros(3), -1.0, occ).any()
