"""The COCO-17 keypoint format and the body parts built on it.

COCO-17 is the canonical keypoint format inside the project: every detector format is mapped onto it by
`msg_adapters.keypoints` before fitting. Body parts (for the visibility filter and the occlusion prior)
are defined by the keypoints that bound them, as in the thesis (Sec. 3.2).
"""

from __future__ import annotations

import numpy as np

COCO17_NAMES: tuple[str, ...] = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)
NUM_KEYPOINTS = len(COCO17_NAMES)
KP = {name: i for i, name in enumerate(COCO17_NAMES)}

# Left/right pairs (index pairs), used for mirroring and for detector swap simulation.
COCO17_FLIP_PAIRS: tuple[tuple[int, int], ...] = tuple(
    (KP[n], KP[n.replace("left_", "right_")]) for n in COCO17_NAMES if n.startswith("left_")
)

# Left/right groups a detector confuses together (a whole forearm-and-elbow or shin-and-knee flips at
# once): the simulated detector's swaps and the fitter's swapped readings (`init.swap_hypotheses`).
SWAP_GROUPS: dict[str, tuple[tuple[int, int], ...]] = {
    "face": ((KP["left_eye"], KP["right_eye"]), (KP["left_ear"], KP["right_ear"])),
    "shoulders": ((KP["left_shoulder"], KP["right_shoulder"]),),
    "arms": ((KP["left_elbow"], KP["right_elbow"]), (KP["left_wrist"], KP["right_wrist"])),
    "hips": ((KP["left_hip"], KP["right_hip"]),),
    "legs": ((KP["left_knee"], KP["right_knee"]), (KP["left_ankle"], KP["right_ankle"])),
}


def swapped_order(groups) -> list[int]:
    """The keypoint order that reads the left/right pairs of `groups` (SWAP_GROUPS names) the other way
    round: `keypoints[order]` swaps them, every other keypoint stays."""
    order = list(range(NUM_KEYPOINTS))
    for name in groups:
        for a, b in SWAP_GROUPS[name]:
            order[a], order[b] = order[b], order[a]
    return order


# Skeleton edges for drawing (LINE_LIST markers, overlays).
COCO17_SKELETON: tuple[tuple[int, int], ...] = (
    (KP["left_ankle"], KP["left_knee"]),
    (KP["left_knee"], KP["left_hip"]),
    (KP["right_ankle"], KP["right_knee"]),
    (KP["right_knee"], KP["right_hip"]),
    (KP["left_hip"], KP["right_hip"]),
    (KP["left_shoulder"], KP["left_hip"]),
    (KP["right_shoulder"], KP["right_hip"]),
    (KP["left_shoulder"], KP["right_shoulder"]),
    (KP["left_shoulder"], KP["left_elbow"]),
    (KP["left_elbow"], KP["left_wrist"]),
    (KP["right_shoulder"], KP["right_elbow"]),
    (KP["right_elbow"], KP["right_wrist"]),
    (KP["nose"], KP["left_eye"]),
    (KP["nose"], KP["right_eye"]),
    (KP["left_eye"], KP["left_ear"]),
    (KP["right_eye"], KP["right_ear"]),
)

# Body parts and the keypoints that bound them. A part is occluded when its keypoints' confidences are
# below the threshold (thesis Sec. 3.2). Hands belong to the lower arm, feet to the lower leg.
BODY_PARTS: dict[str, tuple[int, ...]] = {
    "head": (KP["nose"], KP["left_eye"], KP["right_eye"], KP["left_ear"], KP["right_ear"]),
    "torso": (KP["left_shoulder"], KP["right_shoulder"], KP["left_hip"], KP["right_hip"]),
    "left_upper_arm": (KP["left_shoulder"], KP["left_elbow"]),
    "left_lower_arm": (KP["left_elbow"], KP["left_wrist"]),
    "right_upper_arm": (KP["right_shoulder"], KP["right_elbow"]),
    "right_lower_arm": (KP["right_elbow"], KP["right_wrist"]),
    "left_upper_leg": (KP["left_hip"], KP["left_knee"]),
    "left_lower_leg": (KP["left_knee"], KP["left_ankle"]),
    "right_upper_leg": (KP["right_hip"], KP["right_knee"]),
    "right_lower_leg": (KP["right_knee"], KP["right_ankle"]),
}
PART_NAMES: tuple[str, ...] = tuple(BODY_PARTS)
PART_INDEX = {name: i for i, name in enumerate(PART_NAMES)}

# The joints (named as in `smplify3d_ros.body.joints.BODY_JOINTS`) whose rotation moves each part: an
# occluded part keeps these near their initial rotation (L_θocc, Eq. 8).
PART_DRIVING_JOINTS: dict[str, tuple[str, ...]] = {
    "head": ("neck", "head"),
    "torso": (),
    "left_upper_arm": ("left_shoulder",),
    "left_lower_arm": ("left_elbow", "left_wrist"),
    "right_upper_arm": ("right_shoulder",),
    "right_lower_arm": ("right_elbow", "right_wrist"),
    "left_upper_leg": ("left_hip",),
    "left_lower_leg": ("left_knee", "left_ankle"),
    "right_upper_leg": ("right_hip",),
    "right_lower_leg": ("right_knee", "right_ankle"),
}

# Keypoints used by the reprojection term (reference: COCO joints 0 to 15; the ankles' index 16 is
# excluded there only by an off-by-one, we keep all 17) and the root used for 2D alignment (hip midpoint).
HIP_INDICES: tuple[int, int] = (KP["left_hip"], KP["right_hip"])


def hip_midpoint(keypoints3d: np.ndarray) -> np.ndarray:
    """(3,) float64 the midpoint of the hips of COCO-17 keypoints (17, 3): a body's root (a fit's, a
    simulated person's, the built-in starts' `transl`)."""
    return np.asarray(keypoints3d, np.float64)[list(HIP_INDICES)].mean(axis=0)
