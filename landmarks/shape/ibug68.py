"""The iBUG-68 landmark scheme: index ranges of each face part.

Points are 0-based. "Left"/"right" follow iBUG: points 17-21 are the brow on the
image's left (the subject's right), 36-41 the eye on the image's left.
"""

from __future__ import annotations

NUM_LANDMARKS = 68

# part name -> (first index, one past last index, closed polyline?)
PARTS: dict[str, tuple[int, int, bool]] = {
    "jaw": (0, 17, False),
    "brow_left": (17, 22, False),
    "brow_right": (22, 27, False),
    "nose_bridge": (27, 31, False),
    "nose_base": (31, 36, False),
    "eye_left": (36, 42, True),
    "eye_right": (42, 48, True),
    "lips_outer": (48, 60, True),
    "lips_inner": (60, 68, True),
}
PART_NAMES: tuple[str, ...] = tuple(PARTS)

NOSE_TIP = 30
CHIN = 8
LEFT_EYE = slice(36, 42)  # image-left eye
RIGHT_EYE = slice(42, 48)  # image-right eye

# Index permutation that mirrors a 68-point set left<->right (for flip augmentation).
MIRROR_INDEX: tuple[int, ...] = (
    tuple(range(16, -1, -1))  # jaw
    + tuple(range(26, 21, -1)) + tuple(range(21, 16, -1))  # brows
    + (27, 28, 29, 30)  # nose bridge
    + (35, 34, 33, 32, 31)  # nose base
    + (45, 44, 43, 42, 47, 46)  # eye_left <- mirrored eye_right
    + (39, 38, 37, 36, 41, 40)  # eye_right <- mirrored eye_left
    + (54, 53, 52, 51, 50, 49, 48, 59, 58, 57, 56, 55)  # outer lips
    + (64, 63, 62, 61, 60, 67, 66, 65)  # inner lips
)
assert len(MIRROR_INDEX) == NUM_LANDMARKS and sorted(MIRROR_INDEX) == list(range(NUM_LANDMARKS))
