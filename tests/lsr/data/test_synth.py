"""The procedural talking-head generator: determinism, exact ground truth, conventions, CLI."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from lsr.data.classes import NUM_SEG_CLASSES, SEG_CLASS_ID
from lsr.data.synth import PRESET_NAMES, generate_dataset, identity_seed_of, render_video

C = SEG_CLASS_ID
FACE_INTERIOR = {C[n] for n in ("skin", "nose", "l_eye", "r_eye", "l_brow", "r_brow", "u_lip", "l_lip", "mouth", "eyeglasses")}


def _neighbourhood(segmentation: np.ndarray, point: np.ndarray, radius: int) -> set[int]:
    x, y = int(round(float(point[0]))), int(round(float(point[1])))
    size = segmentation.shape[0]
    patch = segmentation[max(0, y - radius) : min(size, y + radius + 1), max(0, x - radius) : min(size, x + radius + 1)]
    return set(np.unique(patch).tolist())


def landmark_class_checks(clip, radius: int = 2) -> dict[str, list[bool]]:
    """Per part: does each visible landmark sit on the class it names (within ``radius`` px)?"""
    eyes, brows, lips = {C["l_eye"], C["r_eye"]}, {C["l_brow"], C["r_brow"]}, {C["u_lip"], C["l_lip"]}
    checks: dict[str, list[bool]] = {"eyes": [], "brows": [], "outer_lips": [], "inner_lips": [], "nose": [], "jaw": []}
    for index in range(len(clip.frames)):
        seg, points, visible = clip.segmentation[index], clip.landmarks[index], clip.visible[index]
        eyes_open = clip.motion.eye_open[index] > 0.5
        for k in range(68):
            if not visible[k]:
                continue
            around = _neighbourhood(seg, points[k], radius)
            if 36 <= k < 48 and eyes_open:  # on the eye / skin border
                checks["eyes"].append(bool(around & eyes) and bool(around & {C["skin"], C["eyeglasses"]}))
            elif 17 <= k < 27:
                checks["brows"].append(bool(around & brows))
            elif 48 <= k < 60:
                checks["outer_lips"].append(bool(around & lips))
            elif 60 <= k < 68:
                checks["inner_lips"].append(bool(around & (lips | {C["mouth"]})))
            elif 31 <= k < 36:
                checks["nose"].append(C["nose"] in around)
            elif 27 <= k < 31:
                checks["nose"].append(bool(around & {C["nose"], C["skin"]}))
            elif k < 17:  # the jaw follows the silhouette: face inside, something else outside
                checks["jaw"].append(bool(around & FACE_INTERIOR) and bool(around - FACE_INTERIOR))
    return checks


def test_same_seed_same_arrays_different_seed_differs() -> None:
    first, second = render_video(11, 4, 64), render_video(11, 4, 64)
    for name in ("frames", "landmarks", "segmentation", "pose"):
        np.testing.assert_array_equal(getattr(first, name), getattr(second, name))
    other = render_video(12, 4, 64)
    assert not np.array_equal(first.frames, other.frames)
    assert not np.allclose(first.landmarks, other.landmarks)
    assert first.params["identity"] != other.params["identity"]
    # Another video of the same person: same identity, new motion/scene.
    video = render_video(11, 4, 64, video_index=1)
    assert video.params["identity"] == first.params["identity"] and video.params["scene"] != first.params["scene"]
    # Identity i depends on (seed, i) only.
    assert identity_seed_of(0, 3) == identity_seed_of(0, 3) != identity_seed_of(1, 3)


def test_shapes_dtypes_and_ranges() -> None:
    clip = render_video(5, 3, 96)
    assert clip.frames.shape == (3, 96, 96, 3) and clip.frames.dtype == np.uint8
    assert clip.segmentation.shape == (3, 96, 96) and clip.segmentation.dtype == np.uint8
    assert clip.segmentation.max() < NUM_SEG_CLASSES
    assert clip.landmarks.shape == (3, 68, 2) and clip.landmarks.dtype == np.float32
    assert clip.pose.shape == (3, 3) and clip.pose.dtype == np.float32
    assert np.isfinite(clip.landmarks).all() and ((clip.landmarks > 0) & (clip.landmarks < 96)).all()
    # Framing like VoxCeleb2 crops: face (jaw width) ~45-55% of the width, centred.
    width = clip.landmarks[:, 16, 0] - clip.landmarks[:, 0, 0]
    assert 0.35 * 96 < np.median(width) < 0.65 * 96
    assert abs(np.median(clip.landmarks[:, 30, 0]) - 48) < 15


def test_landmarks_fall_in_their_own_classes() -> None:
    checks: dict[str, list[bool]] = {}
    for i in range(4):
        clip = render_video(identity_seed_of(0, i), 10, 128)
        for part, values in landmark_class_checks(clip).items():
            checks.setdefault(part, []).extend(values)
    rates = {part: float(np.mean(values)) for part, values in checks.items()}
    overall = float(np.mean([v for values in checks.values() for v in values]))
    assert overall >= 0.95, rates
    assert min(rates.values()) >= 0.85, rates


def test_aligned_framing_matches_the_inference_crop() -> None:
    from landmarks.align import crop_transform

    from lsr.data.synth import render_framed

    camera = render_framed(identity_seed_of(0, 1), 6, 128, framing="camera")
    aligned = render_framed(identity_seed_of(0, 1), 6, 128)  # the default
    assert aligned.frames.shape == camera.frames.shape and aligned.params["framing"] == "aligned"
    for points in aligned.landmarks:  # cropping an aligned frame again is (nearly) the identity
        matrix = crop_transform(points, 128)
        assert np.allclose(matrix[:, :2], np.eye(2), atol=1e-3) and np.allclose(matrix[:, 2], 0, atol=0.1)
    checks = landmark_class_checks(aligned)  # classes were warped with the same transform as the points
    assert float(np.mean([v for values in checks.values() for v in values])) >= 0.95
    assert not np.allclose(crop_transform(camera.landmarks[0], 128)[:, :2], np.eye(2), atol=0.05)


def test_jaw_follows_the_silhouette_at_large_yaw() -> None:
    """At |yaw| > 30 the far-side jaw points lie on the head/background (or neck) border, not inside the face."""
    on_border = []
    for seed in range(3):
        clip = render_video(identity_seed_of(7, seed), 30, 128, "extreme_pose")
        for index in np.flatnonzero(np.abs(clip.pose[:, 0]) > 30):
            far = range(10, 16) if clip.pose[index, 0] > 0 else range(1, 7)  # yaw > 0: the face turns right
            seg = clip.segmentation[index]
            for k in far:
                around = _neighbourhood(seg, clip.landmarks[index, k], 2)
                on_border.append(bool(around & FACE_INTERIOR) and bool(around - FACE_INTERIOR))
    assert len(on_border) > 20
    assert np.mean(on_border) >= 0.85


def test_pose_sign_conventions() -> None:
    """yaw > 0: nose tip right of the jaw midpoint; pitch > 0: nose tip up (towards the eyes); roll > 0:
    clockwise (image-right eye lower); and landmarks.motion.head_pose's PnP estimate follows the ground-truth yaw."""
    from landmarks.motion.head_pose import estimate_head_pose

    clips = [render_video(identity_seed_of(3, i), 10, 128, "extreme_pose") for i in range(6)]
    pose_truth = np.concatenate([clip.pose for clip in clips])
    yaw, pitch, roll = pose_truth.T
    points = np.concatenate([clip.landmarks for clip in clips])
    nose_offset = points[:, 30, 0] - 0.5 * (points[:, 0, 0] + points[:, 16, 0])
    turned = np.abs(yaw) > 8
    assert turned.sum() > 10 and (np.sign(nose_offset[turned]) == np.sign(yaw[turned])).all()
    eye_drop = points[:, 42:48, 1].mean(1) - points[:, 36:42, 1].mean(1)
    rolled = np.abs(roll) > 5
    assert (np.sign(eye_drop[rolled]) == np.sign(roll[rolled])).all()
    eyes, mouth = points[:, 36:48].mean(1), points[:, 48:60].mean(1)
    axis_dir = (mouth - eyes) / np.linalg.norm(mouth - eyes, axis=1, keepdims=True)
    nose_height = ((points[:, 30] - eyes) * axis_dir).sum(1) / np.linalg.norm(mouth - eyes, axis=1)
    assert np.corrcoef(nose_height, pitch)[0, 1] < -0.9  # the protruding tip rises when the face tilts up
    estimate = np.array([estimate_head_pose(p, (128, 128)) for p in points])
    # Yaw only: PnP roll/pitch of a different 3D face model mix with yaw at these angles (pitch is offset ~+13 deg).
    assert np.corrcoef(estimate[:, 0], yaw)[0, 1] > 0.8


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_every_preset_renders(preset: str) -> None:
    clip = render_video(21, 3, 64, preset)
    assert clip.frames.shape == (3, 64, 64, 3) and clip.segmentation.max() < NUM_SEG_CLASSES
    assert clip.params["preset"] == preset


def test_occluders_cover_pixels_not_ground_truth() -> None:
    """Same seed with and without occluders: identical landmarks and class maps; only occluded frames differ."""
    clean, occluded = render_video(8, 40, 64, "default"), render_video(8, 40, 64, "heavy_occlusion")
    np.testing.assert_array_equal(clean.landmarks, occluded.landmarks)
    np.testing.assert_array_equal(clean.segmentation, occluded.segmentation)
    assert 0.4 <= occluded.occluded.mean() <= 0.8
    changed = (clean.frames != occluded.frames).any(axis=(1, 2, 3))
    assert (changed[~occluded.occluded & ~clean.occluded] == 0).all()
    assert changed[occluded.occluded & ~clean.occluded].all()


def test_generate_dataset_is_valid_and_deterministic(tmp_path: Path) -> None:
    from lsr.data.format import ClipReader, list_clips, read_manifest

    for name in ("a", "b"):
        generate_dataset(tmp_path / name, identities=3, videos_per_identity=2, frames=3, size=48, seed=4, test_fraction=0.34, progress=False)
    manifest = read_manifest(tmp_path / "a")
    assert manifest["counts"]["test"]["identities"] == 1 and manifest["counts"]["train"]["clips"] == 4
    clips_a, clips_b = list_clips(tmp_path / "a"), list_clips(tmp_path / "b")
    assert len(clips_a) == 6
    for path_a, path_b in zip(clips_a, clips_b):
        a, b = ClipReader(path_a), ClipReader(path_b)
        assert a.meta["origin"] == "synthetic" and a.has_segmentation and a.num_frames == 3
        np.testing.assert_array_equal(a.landmarks, b.landmarks)
        np.testing.assert_array_equal(a.frame(2), b.frame(2))
        np.testing.assert_array_equal(a.segmentation(1), b.segmentation(1))
    # Adding identities does not change existing ones.
    generate_dataset(tmp_path / "c", identities=4, videos_per_identity=2, frames=3, size=48, seed=4, progress=False)
    np.testing.assert_array_equal(ClipReader(tmp_path / "c" / "id00001" / "vid001").landmarks, ClipReader(tmp_path / "a" / "id00001" / "vid001").landmarks)


def test_cli_writes_dataset_and_preview(tmp_path: Path) -> None:
    from lsr.cli import main
    from lsr.data.format import list_clips

    out = tmp_path / "ds"
    assert main(["synth", "--out", str(out), "--identities", "2", "--videos-per-identity", "1", "--frames", "2", "--resolution", "48"]) == 0
    assert len(list_clips(out)) == 2
    preview = tmp_path / "sheet.png"
    assert main(["synth", "--preview", str(preview), "--resolution", "48"]) == 0
    assert preview.is_file() and preview.stat().st_size > 1000
    assert main(["synth", "--out", str(out), "--frames", "0"]) == 2  # typed error -> exit 2


@pytest.mark.slow
def test_dlib_finds_near_frontal_faces() -> None:
    """dlib's HOG detector (default threshold 0, upsampled twice: 128 px -> 512 px pyramid) finds >= 90% of
    near-frontal synthetic faces, and its 68 points agree with the ground truth.

    Measured (20 identities x 6 frames at 128 px): hit rate 0.94, NMKE median 0.09, mean 0.10, p90 0.13 —
    a systematic domain gap (dlib's shape model vs our geometry, e.g. brows on their centre line), far from
    what a mirrored or re-ordered annotation gives (> 0.3, checked below). Gate: median NMKE < 0.15.
    """
    from landmarks.detect.face_detector import DlibDetector
    from landmarks.shape.ibug68 import MIRROR_INDEX

    detector = DlibDetector("hog", upsample=2, min_score=0.0)
    hits, errors, mirrored = [], [], []
    for i in range(12):
        clip = render_video(identity_seed_of(0, i), 21, 128)
        for k in (0, 10, 20):
            yaw, pitch, _ = clip.pose[k]
            if abs(yaw) >= 20 or abs(pitch) >= 15:
                continue
            faces = detector.detect(clip.frames[k])
            hits.append(bool(faces))
            if faces:
                truth = clip.landmarks[k]
                inter_ocular = np.linalg.norm(truth[36:42].mean(0) - truth[42:48].mean(0))
                errors.append(np.linalg.norm(faces[0].landmarks - truth, axis=1).mean() / inter_ocular)
                mirrored.append(np.linalg.norm(faces[0].landmarks[list(MIRROR_INDEX)] - truth, axis=1).mean() / inter_ocular)
    assert len(hits) >= 15
    assert np.mean(hits) >= 0.9, f"hit rate {np.mean(hits):.2f}"
    assert np.median(errors) < 0.15, f"NMKE median {np.median(errors):.3f}"
    assert np.median(mirrored) > 2 * np.median(errors)
