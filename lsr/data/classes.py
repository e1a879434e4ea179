"""The 19 face-parsing classes, in the CelebAMask-HQ order used by the LSR release.

Index = class id stored in the uint8 segmentation maps.
"""

import numpy as np

SEG_CLASSES: tuple[str, ...] = (
    "background",  # 0
    "skin",  # 1
    "l_brow",  # 2
    "r_brow",  # 3
    "l_eye",  # 4
    "r_eye",  # 5
    "eyeglasses",  # 6
    "l_ear",  # 7
    "r_ear",  # 8
    "earring",  # 9
    "nose",  # 10
    "mouth",  # 11 (inner mouth)
    "u_lip",  # 12
    "l_lip",  # 13
    "neck",  # 14
    "necklace",  # 15
    "cloth",  # 16
    "hair",  # 17
    "hat",  # 18
)
NUM_SEG_CLASSES = len(SEG_CLASSES)
SEG_CLASS_ID: dict[str, int] = {name: i for i, name in enumerate(SEG_CLASSES)}

# A fixed palette for showing class maps (argmax colours in previews and logs).
SEG_PALETTE = np.array(
    [
        [0, 0, 0], [204, 153, 128], [102, 51, 0], [153, 76, 0], [0, 0, 255],
        [0, 128, 255], [255, 255, 0], [255, 0, 128], [255, 0, 200], [255, 255, 255],
        [255, 102, 0], [128, 0, 0], [255, 0, 0], [200, 0, 60], [153, 204, 0],
        [0, 255, 255], [0, 153, 76], [76, 0, 153], [255, 128, 255],
    ],
    dtype=np.uint8,
)  # (19, 3) RGB


def colorize_segmentation(segmentation: np.ndarray) -> np.ndarray:
    """Class map (H, W) uint8 in [0, 19) -> RGB image (H, W, 3) uint8."""
    if segmentation.ndim != 2:
        raise ValueError(f"segmentation must be (H, W), got shape {segmentation.shape}")
    return SEG_PALETTE[np.clip(segmentation, 0, NUM_SEG_CLASSES - 1)]
