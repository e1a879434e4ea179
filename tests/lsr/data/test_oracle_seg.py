"""Oracle face parsing from landmarks: geometry on synthetic heads, IoU helpers, and the per-class
IoU against the official LSR maps of id00017 (shared data)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from lsr.data.classes import NUM_SEG_CLASSES, SEG_CLASS_ID
from lsr.data.oracle_seg import (
    OFFICIAL_TO_SEG_CLASS,
    compare_with_official,
    face_part_masks,
    format_iou_table,
    oracle_segmentation,
    read_official_segmap,
    segmentation_iou,
)
from lsr.errors import DatasetError


@pytest.fixture(scope="module")
def synthetic_head(tmp_path_factory) -> tuple[np.ndarray, np.ndarray]:
    from lsr.data.format import read_clip
    from lsr.data.synth import generate_dataset

    root = tmp_path_factory.mktemp("synth")
    generate_dataset(root, identities=1, videos_per_identity=1, frames=2, size=128, seed=3, test_fraction=0.0, progress=False)
    clip = read_clip(next(root.glob("*/*")))
    return clip["frames"][0], clip["landmarks"][0]


def _centre(points: np.ndarray) -> tuple[int, int]:
    x, y = np.round(points.mean(axis=0)).astype(int)
    return int(y), int(x)


class TestOracleSegmentation:
    def test_shape_dtype_and_parts_on_the_landmarks(self, synthetic_head):
        image, landmarks = synthetic_head
        seg = oracle_segmentation(image, landmarks)
        assert seg.shape == image.shape[:2] and seg.dtype == np.uint8
        assert seg.max() < NUM_SEG_CLASSES
        # Parts sit where the landmarks say; CelebAMask-HQ l_* = subject's left = image right (iBUG 42-47).
        assert seg[_centre(landmarks[42:48])] == SEG_CLASS_ID["l_eye"]
        assert seg[_centre(landmarks[36:42])] == SEG_CLASS_ID["r_eye"]
        assert seg[_centre(landmarks[31:36])] == SEG_CLASS_ID["nose"]
        assert seg[_centre(landmarks[[3, 4, 5]])] == SEG_CLASS_ID["skin"]
        assert seg[0, 0] == SEG_CLASS_ID["background"]

    def test_missing_face_is_all_background(self, synthetic_head):
        image, _ = synthetic_head
        seg = oracle_segmentation(image, np.full((68, 2), np.nan, np.float32))
        assert not seg.any()

    def test_bad_inputs_raise(self, synthetic_head):
        image, landmarks = synthetic_head
        with pytest.raises(ValueError, match="uint8"):
            oracle_segmentation(image.astype(np.float32), landmarks)
        with pytest.raises(ValueError, match="68, 2"):
            oracle_segmentation(image, landmarks[:10])
        with pytest.raises(ValueError):
            face_part_masks(np.full((68, 2), np.nan), (64, 64))

    def test_lips_split_upper_and_lower(self, synthetic_head):
        image, landmarks = synthetic_head
        parts = face_part_masks(landmarks, image.shape[:2])
        upper_y = np.nonzero(parts["u_lip"])[0].mean()
        lower_y = np.nonzero(parts["l_lip"])[0].mean()
        assert upper_y < lower_y
        assert not (parts["u_lip"] & parts["l_lip"]).sum() > 0.2 * parts["u_lip"].sum()


class TestIoU:
    def test_known_values(self):
        reference = np.zeros((4, 4), np.uint8)
        reference[:, :2] = 1
        predicted = np.zeros((4, 4), np.uint8)
        predicted[:, :1] = 1
        iou = segmentation_iou(predicted, reference)
        assert iou[1] == pytest.approx(0.5)  # 4 / 8
        assert iou[0] == pytest.approx(8 / 12)
        assert np.isnan(iou[5])
        assert "background" in format_iou_table(iou)

    def test_shape_mismatch_raises(self):
        with pytest.raises(ValueError, match="shape"):
            segmentation_iou(np.zeros((2, 2)), np.zeros((3, 3)))

    def test_official_ids_are_remapped(self, tmp_path: Path):
        raw = np.arange(19, dtype=np.uint8).reshape(1, 19).repeat(2, axis=0)
        cv2.imwrite(str(tmp_path / "00000_segmap_merged.png"), raw)
        remapped = read_official_segmap(tmp_path / "00000_segmap_merged.png")
        assert remapped[0, 2] == SEG_CLASS_ID["nose"] and remapped[0, 18] == SEG_CLASS_ID["cloth"]
        assert sorted(OFFICIAL_TO_SEG_CLASS.tolist()) == list(range(19))
        cv2.imwrite(str(tmp_path / "bad.png"), np.full((2, 2), 40, np.uint8))
        with pytest.raises(DatasetError, match="class id"):
            read_official_segmap(tmp_path / "bad.png")


# Measured on the 32 train frames of id00017 (HOG landmarks): background 0.81, skin 0.76, nose 0.75,
# cloth 0.85, l_ear 0.68, r_ear 0.54, u_lip 0.60, neck 0.48, l_lip 0.43, eyes 0.33, brows 0.23-0.29,
# hair 0.02. Thresholds leave ~0.1 of margin for detector/OpenCV version drift. Hair is not checked:
# the official oracle labels this subject's dark hair mostly as background (hair is 1.6 % of its
# pixels), so IoU there measures the official map's misses, not ours.
IOU_THRESHOLDS = {
    "background": 0.70, "skin": 0.65, "nose": 0.62, "cloth": 0.72, "l_ear": 0.50, "r_ear": 0.40,
    "u_lip": 0.45, "l_lip": 0.30, "neck": 0.35, "l_eye": 0.2, "r_eye": 0.2, "l_brow": 0.15, "r_brow": 0.12,
}


@pytest.mark.slow
def test_iou_against_official_maps(shared_data: Path):
    folder = shared_data / "fsth_eval_sample_processed" / "train" / "id00017"
    folders = sorted({p.parent for p in folder.rglob("*_segmap_merged.png")})
    if not folders:
        pytest.skip(f"no official segmaps under {folder}")
    iou, share, count = compare_with_official(folders)
    print(f"\n{count} frames\n" + format_iou_table(iou, share))
    assert count >= 30
    failed = {name: round(float(iou[SEG_CLASS_ID[name]]), 3) for name, low in IOU_THRESHOLDS.items() if not iou[SEG_CLASS_ID[name]] >= low}
    assert not failed, f"IoU below threshold: {failed}"
