"""An oracle face parsing built from 68 landmarks and OpenCV only (no downloaded networks).

The thesis (§4.3.1) supervises the layout latent with a face-parsing "oracle" that is itself a
noisy network output. We have no parsing weights, so this module builds a plausible 19-class map:

* face parts are polygons from the landmarks: skin (jaw hull extended up to an estimated hairline,
  facial-thirds rule), brows (thick strokes), eyes, nose, upper / lower lip and inner mouth;
* the person / background split is GrabCut seeded from the landmarks (borders above the chin are
  background, the face and the bottom centre of the frame are foreground);
* inside the person: below the jaw, skin-coloured pixels connected to the chin are neck and the rest
  is cloth; above and beside the face it is hair; dark, non-skin pixels inside the forehead are hair.

Class ids follow ``lsr.data.classes.SEG_CLASSES``. Left / right follow CelebAMask-HQ: ``l_*`` is the
subject's left, i.e. the image's right, i.e. iBUG ``brow_right`` / ``eye_right`` (verified on the
official LSR maps, see ``OFFICIAL_TO_SEG_CLASS``).

The official LSR maps (``NNNNN_segmap_merged.png``) store raw ids in the *original CelebAMask-HQ
mask order* (1 skin, 2 nose, 3 eye_g, 4 l_eye, ...), not in ``SEG_CLASSES`` order;
``read_official_segmap`` remaps them. ``segmentation_iou`` / ``print_iou_table`` compare maps.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from lsr.data.classes import NUM_SEG_CLASSES, SEG_CLASS_ID, SEG_CLASSES
from lsr.errors import DatasetError

if TYPE_CHECKING:
    from lsr.config import BenchOracleSegConfig

# Official LSR/CelebAMask-HQ mask id -> SEG_CLASSES id. Deduced from the id00017 maps (class centroids
# and sizes: id 2 is the large central region = nose, 4/5 eyes at image right/left, 17 below the jaw =
# neck, 18 the bottom = cloth); it is the label list of CelebAMask-HQ's g_mask.py.
_OFFICIAL_ORDER = (
    "background", "skin", "nose", "eyeglasses", "l_eye", "r_eye", "l_brow", "r_brow", "l_ear",
    "r_ear", "mouth", "u_lip", "l_lip", "hair", "hat", "earring", "necklace", "neck", "cloth",
)
OFFICIAL_TO_SEG_CLASS = np.array([SEG_CLASS_ID[name] for name in _OFFICIAL_ORDER], dtype=np.uint8)

_JAW = slice(0, 17)
_GRABCUT_SIDE = 128
_BROW_IMAGE_LEFT, _BROW_IMAGE_RIGHT = slice(17, 22), slice(22, 27)
_EYE_IMAGE_LEFT, _EYE_IMAGE_RIGHT = slice(36, 42), slice(42, 48)


def read_official_segmap(path: str | Path) -> np.ndarray:
    """Read an official LSR ``*_segmap_merged.png`` (raw ids, CelebAMask-HQ mask order) -> (H, W) uint8
    class map in ``SEG_CLASSES`` order."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim != 2:
        raise DatasetError(f"{path}: not a single-channel segmentation PNG; check the file")
    if int(image.max()) >= NUM_SEG_CLASSES:
        raise DatasetError(f"{path}: class id {int(image.max())} >= {NUM_SEG_CLASSES}; not an LSR segmap")
    return OFFICIAL_TO_SEG_CLASS[image]


def _face_frame(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, float]:
    """Face-aligned axes: origin (nose bridge top), unit right, unit up, face height, face width."""
    brows = landmarks[17:27].mean(axis=0)
    chin = landmarks[8]
    up = brows - chin
    height = float(np.linalg.norm(up)) + 1e-6
    up = up / height
    right = np.array([-up[1], up[0]], dtype=np.float64)  # perpendicular; fix sign with the jaw
    if np.dot(landmarks[16] - landmarks[0], right) < 0:
        right = -right
    width = float(np.linalg.norm(landmarks[16] - landmarks[0])) + 1e-6
    return landmarks[27].astype(np.float64), right, up, height, width


def _forehead_points(landmarks: np.ndarray, up: np.ndarray, height: float) -> np.ndarray:
    """Estimated hairline: brows lifted by 0.35 of the brow-to-chin distance (facial thirds give 0.5 to
    the bare hairline; the official maps end lower, fringe included), less at the temples."""
    brows = np.concatenate([landmarks[_BROW_IMAGE_LEFT], landmarks[_BROW_IMAGE_RIGHT]]).astype(np.float64)
    centre = brows.mean(axis=0)
    spread = np.abs((brows - centre) @ np.array([up[1], -up[0]]))
    lateral = spread / (spread.max() + 1e-6)
    lift = 0.35 * height * (1.0 - 0.45 * lateral**2)
    return brows + lift[:, None] * up[None, :]


def _shrink(points: np.ndarray, factor: float) -> np.ndarray:
    centre = points.mean(axis=0)
    return centre + factor * (points - centre)


def _fill(mask_shape: tuple[int, int], polygon: np.ndarray, convex: bool = False) -> np.ndarray:
    mask = np.zeros(mask_shape, np.uint8)
    points = np.round(polygon).astype(np.int32)
    if convex:
        cv2.fillConvexPoly(mask, cv2.convexHull(points), 1)
    else:
        cv2.fillPoly(mask, [points], 1)
    return mask.astype(bool)


def face_part_masks(landmarks: np.ndarray, size: tuple[int, int]) -> dict[str, np.ndarray]:
    """Landmark polygons of the face parts.

    landmarks: (68, 2) float (x, y) pixels, no NaN; size: (H, W). Returns name -> (H, W) bool for
    "skin_hull", "forehead", the brows, eyes, "nose", "u_lip", "l_lip", "mouth" (SEG_CLASSES names).
    """
    landmarks = np.asarray(landmarks, dtype=np.float64)
    if landmarks.shape != (68, 2) or not np.isfinite(landmarks).all():
        raise ValueError(f"landmarks must be finite (68, 2), got shape {landmarks.shape}")
    _, right, up, face_height, face_width = _face_frame(landmarks)
    forehead = _forehead_points(landmarks, up, face_height)
    masks: dict[str, np.ndarray] = {}
    masks["skin_hull"] = _fill(size, np.concatenate([landmarks[_JAW], forehead]), convex=True)
    brow_line = np.concatenate([landmarks[_BROW_IMAGE_LEFT], landmarks[_BROW_IMAGE_RIGHT]]).mean(0)
    above_brows = np.concatenate([forehead, [brow_line + 2.0 * face_height * up]])
    masks["forehead"] = _fill(size, np.concatenate([landmarks[17:27], above_brows]), convex=True)
    # Brows: thick strokes, slightly lifted (the landmarks sit on the lower edge of the brow).
    thickness = max(2, int(round(0.035 * face_width)))
    for name, part in (("r_brow", _BROW_IMAGE_LEFT), ("l_brow", _BROW_IMAGE_RIGHT)):
        stroke = np.zeros(size, np.uint8)
        points = _shrink(landmarks[part], 0.85) + 0.5 * thickness * up
        cv2.polylines(stroke, [np.round(points).astype(np.int32)], False, 1, thickness)
        masks[name] = stroke.astype(bool)
    # Eyes and inner mouth shrunk: parsers label the visible eyeball / teeth, inside the lid contour.
    for name, part in (("r_eye", _EYE_IMAGE_LEFT), ("l_eye", _EYE_IMAGE_RIGHT)):
        masks[name] = _fill(size, _shrink(landmarks[part], 0.75))
    # Nose: bridge top widened to a narrow ridge, nostril wings pushed out a little.
    base = landmarks[31:36]
    base_width = float(np.linalg.norm(base[-1] - base[0])) + 1e-6
    base_centre = base.mean(axis=0)
    wings = base_centre + 1.2 * (base - base_centre)
    ridge = [landmarks[27] + s * 0.18 * base_width * right for s in (-1.0, 1.0)]
    masks["nose"] = _fill(size, np.concatenate([wings, ridge, landmarks[28:31]]), convex=True)
    outer, inner = landmarks[48:60], landmarks[60:68]
    masks["mouth"] = _fill(size, _shrink(inner, 0.85))
    # Upper lip: outer 48..54 back along inner 64..60; lower lip: outer 54..59,48 back along inner.
    masks["u_lip"] = _fill(size, np.concatenate([outer[0:7], inner[[4, 3, 2, 1, 0]]]))
    masks["l_lip"] = _fill(size, np.concatenate([outer[[6, 7, 8, 9, 10, 11, 0]], inner[[0, 7, 6, 5, 4]]]))
    return masks


def _skin_colour_distance(lab: np.ndarray, skin_mask: np.ndarray) -> np.ndarray:
    """Mahalanobis distance (H, W) of every pixel's chroma (a, b) plus damped lightness to the skin model."""
    samples = lab[skin_mask].astype(np.float64)
    if len(samples) < 20:
        return np.full(lab.shape[:2], np.inf)
    features = lab.reshape(-1, 3).astype(np.float64)
    mean = np.median(samples, axis=0)
    cov = np.cov(samples.T) + np.diag([40.0, 4.0, 4.0])  # floor: lighting varies, chroma less so
    cov[0, :] *= 2.0  # lightness matters less (shadows on the neck)
    cov[:, 0] *= 2.0
    inverse = np.linalg.inv(cov)
    centred = features - mean
    distance = np.sqrt(np.einsum("ni,ij,nj->n", centred, inverse, centred))
    return distance.reshape(lab.shape[:2])


def _person_mask(image: np.ndarray, face: np.ndarray, landmarks: np.ndarray, up: np.ndarray,
                 face_height: float, face_width: float, iterations: int) -> np.ndarray:
    """GrabCut person-vs-background mask (H, W) bool, seeded from the landmark geometry."""
    height_px, width_px = face.shape
    ys, xs = np.mgrid[0:height_px, 0:width_px]
    chin_y = float(landmarks[8, 1])
    gc = np.full((height_px, width_px), cv2.GC_PR_BGD, np.uint8)
    # Around the head (hair) and everything below the chin (neck, shoulders) probably belongs to the person.
    head_centre = landmarks[27] + 0.25 * face_height * up
    head = ((xs - head_centre[0]) / (0.95 * face_width)) ** 2 + ((ys - head_centre[1]) / (1.05 * face_height)) ** 2 < 1
    gc[head | (ys > chin_y)] = cv2.GC_PR_FGD
    border = max(2, int(0.03 * min(height_px, width_px)))
    frame_border = (ys < border) | (((xs < border) | (xs >= width_px - border)) & (ys < chin_y))
    gc[frame_border & ~head] = cv2.GC_BGD
    gc[cv2.erode(face.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)] = cv2.GC_FGD
    # Bottom centre of the frame below the chin: the subject's clothes.
    cloth_seed = (ys >= height_px - border) & (np.abs(xs - landmarks[8, 0]) < 0.5 * face_width) & (ys > chin_y)
    gc[cloth_seed] = cv2.GC_FGD
    if not (gc == cv2.GC_BGD).any() or not ((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)).any():
        return (gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)
    bgd_model, fgd_model = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    bgr = np.ascontiguousarray(image[:, :, ::-1])
    # GrabCut cost grows with pixels; the person outline needs no more than ~128 px (speed x4 at 256).
    scale = min(1.0, _GRABCUT_SIDE / max(height_px, width_px))
    if scale < 1.0:
        small = (max(1, round(width_px * scale)), max(1, round(height_px * scale)))
        bgr = cv2.resize(bgr, small, interpolation=cv2.INTER_AREA)
        gc = cv2.resize(gc, small, interpolation=cv2.INTER_NEAREST)
    cv2.grabCut(bgr, gc, None, bgd_model, fgd_model, iterations, cv2.GC_INIT_WITH_MASK)
    person = ((gc == cv2.GC_FGD) | (gc == cv2.GC_PR_FGD)).astype(np.uint8)
    if scale < 1.0:
        person = cv2.resize(person * 255, (width_px, height_px), interpolation=cv2.INTER_LINEAR) > 127
    return person.astype(bool)


def _largest_components_touching(mask: np.ndarray, seed: np.ndarray) -> np.ndarray:
    count, labels = cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)
    keep = np.unique(labels[seed & mask])
    keep = keep[keep > 0]
    return np.isin(labels, keep) if len(keep) else np.zeros_like(mask)


def _ear_masks(landmarks: np.ndarray, origin: np.ndarray, right: np.ndarray, up: np.ndarray,
               face_height: float, face_width: float, along_right: np.ndarray, along_up: np.ndarray) -> dict[str, np.ndarray]:
    """Ellipses just outside the jaw ends at eye-to-nose height (placement measured on the official
    maps: centre 0.05 face widths out, 0.2 face heights below the nose bridge). The ear on the side the
    head turns away from is hidden behind the cheek, so it is dropped when the nose tip is near that jaw end."""
    jaw_right = (landmarks[_JAW] - origin) @ right
    nose_right = float((landmarks[30] - origin) @ right)
    yaw_ratio = (nose_right - jaw_right[0]) / max(jaw_right[16] - jaw_right[0], 1e-6)  # 0.5 = frontal
    ears = {}
    for name, end, side, visible in (("r_ear", jaw_right[0], -1.0, yaw_ratio > 0.3), ("l_ear", jaw_right[16], 1.0, yaw_ratio < 0.7)):
        if not visible:
            continue
        centre_right, centre_up = end + side * 0.05 * face_width, -0.2 * face_height
        ears[name] = ((along_right - centre_right) / (0.1 * face_width)) ** 2 + ((along_up - centre_up) / (0.19 * face_height)) ** 2 < 1
    return ears


def oracle_segmentation(image: np.ndarray, landmarks: np.ndarray, grabcut_iterations: int = 3) -> np.ndarray:
    """Landmark-seeded face parsing of one frame.

    image: (H, W, 3) uint8 RGB; landmarks: (68, 2) float (x, y) pixels of the same frame, or all-NaN
    (no face: the whole map is background). Returns (H, W) uint8 class ids in ``SEG_CLASSES`` order.
    Plausible, not exact: compare with ``segmentation_iou`` (per-class IoU vs the official maps is
    printed by ``lsr bench oracle-seg``).
    """
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}")
    landmarks = np.asarray(landmarks, dtype=np.float64)
    if landmarks.shape != (68, 2):
        raise ValueError(f"landmarks must be (68, 2), got {landmarks.shape}")
    size = image.shape[:2]
    segmentation = np.zeros(size, np.uint8)
    if not np.isfinite(landmarks).all():
        return segmentation
    height_px, width_px = size
    parts = face_part_masks(landmarks, size)
    origin, right, up, face_height, face_width = _face_frame(landmarks)
    face = parts["skin_hull"]
    person = _person_mask(image, face, landmarks, up, face_height, face_width, grabcut_iterations) | face

    lab = cv2.cvtColor(image, cv2.COLOR_RGB2LAB)
    inner_parts = np.zeros(size, bool)
    for name in ("l_brow", "r_brow", "l_eye", "r_eye", "nose", "u_lip", "l_lip", "mouth"):
        inner_parts |= parts[name]
    cheeks = face & ~parts["forehead"] & ~cv2.dilate(inner_parts.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    skin_distance = _skin_colour_distance(lab, cheeks)
    skin_like = skin_distance < 3.0

    # Face-aligned coordinates: "below the jaw" survives head tilt.
    ys, xs = np.mgrid[0:height_px, 0:width_px]
    offset = np.stack([xs - origin[0], ys - origin[1]], axis=-1)
    along_right = offset @ right
    along_up = offset @ up
    jaw = landmarks[_JAW]
    jaw_right = (jaw - origin) @ right
    jaw_up = (jaw - origin) @ up
    order = np.argsort(jaw_right)
    jaw_level = np.interp(along_right, jaw_right[order], jaw_up[order])
    inside_jaw_span = (along_right > jaw_right.min()) & (along_right < jaw_right.max())
    below_jaw = (along_up < jaw_level) & inside_jaw_span | (along_up < jaw_up.min())

    body = person & ~face & below_jaw
    neck_zone = body & (np.abs(along_right - jaw_right[8]) < 0.42 * face_width) & (along_up > jaw_up[8] - 0.7 * face_height)
    chin_seed = np.zeros(size, np.uint8)
    cv2.polylines(chin_seed, [np.round(jaw[3:14]).astype(np.int32)], False, 1, max(3, int(0.06 * face_width)))
    neck = _largest_components_touching(neck_zone & skin_like, chin_seed.astype(bool))
    neck = cv2.morphologyEx(neck.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)).astype(bool) & body
    cloth = body & ~neck
    ears = _ear_masks(landmarks, origin, right, up, face_height, face_width, along_right, along_up)
    ears = {name: mask & person & ~face & (skin_distance < 4.0) for name, mask in ears.items()}
    hair = person & ~face & ~below_jaw
    # Hair over the forehead: dark, non-skin pixels in the estimated forehead band above the brows.
    brow_band = cv2.dilate((parts["l_brow"] | parts["r_brow"]).astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    fringe = face & parts["forehead"] & ~brow_band & (skin_distance > 4.0)
    if cheeks.any():
        fringe &= lab[..., 0] < np.median(lab[cheeks][:, 0])  # hair is darker than the cheeks
    fringe = _largest_components_touching(fringe, ~face | ~parts["forehead"] & face & ~cheeks) if fringe.any() else fringe

    segmentation[cloth] = SEG_CLASS_ID["cloth"]
    segmentation[neck] = SEG_CLASS_ID["neck"]
    segmentation[hair] = SEG_CLASS_ID["hair"]
    segmentation[face] = SEG_CLASS_ID["skin"]
    segmentation[fringe] = SEG_CLASS_ID["hair"]
    for name, mask in ears.items():
        segmentation[mask] = SEG_CLASS_ID[name]
    for name in ("nose", "l_brow", "r_brow", "l_eye", "r_eye", "u_lip", "l_lip", "mouth"):
        segmentation[parts[name]] = SEG_CLASS_ID[name]
    # Median filter removes GrabCut speckle without moving the landmark-drawn parts much.
    cleaned = cv2.medianBlur(segmentation, 5)
    cleaned[inner_parts] = segmentation[inner_parts]
    return cleaned


def segmentation_confusion(predicted: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(19, 19) int64 confusion counts, rows = reference class, columns = predicted class.

    predicted, reference: (..., H, W) integer class maps of the same shape (ids >= 19 are ignored)."""
    if predicted.shape != reference.shape:
        raise ValueError(f"shape mismatch: predicted {predicted.shape} vs reference {reference.shape}")
    predicted = predicted.astype(np.int64).ravel()
    reference = reference.astype(np.int64).ravel()
    valid = (predicted < NUM_SEG_CLASSES) & (reference < NUM_SEG_CLASSES) & (predicted >= 0) & (reference >= 0)
    index = reference[valid] * NUM_SEG_CLASSES + predicted[valid]
    return np.bincount(index, minlength=NUM_SEG_CLASSES**2).reshape(NUM_SEG_CLASSES, NUM_SEG_CLASSES)


def segmentation_iou(predicted: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Per-class IoU (19,) float64 pooled over all pixels; NaN where the class is absent from both."""
    confusion = segmentation_confusion(predicted, reference)
    intersection = np.diag(confusion).astype(np.float64)
    union = confusion.sum(0) + confusion.sum(1) - intersection
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(union > 0, intersection / np.maximum(union, 1), np.nan)


def format_iou_table(iou: np.ndarray, reference_share: np.ndarray | None = None) -> str:
    """A text table of per-class IoU (and the class's share of reference pixels, if given)."""
    lines = [f"{'id':>2}  {'class':<11} {'IoU':>6}" + ("  ref-share" if reference_share is not None else "")]
    for class_id, name in enumerate(SEG_CLASSES):
        value = "   n/a" if np.isnan(iou[class_id]) else f"{iou[class_id]:6.3f}"
        share = f"  {100 * reference_share[class_id]:8.2f}%" if reference_share is not None else ""
        lines.append(f"{class_id:>2}  {name:<11} {value}{share}")
    lines.append(f"    {'mean (present)':<11} {np.nanmean(iou):6.3f}")
    return "\n".join(lines)


def compare_with_official(frames_dirs: Sequence[Path], detector: str = "hog") -> tuple[np.ndarray, np.ndarray, int]:
    """Run the oracle on every ``NNNNN_rgb.png`` that has an official ``NNNNN_segmap_merged.png`` beside it.

    Landmarks come from ``landmarks.detect.face_detector``. Returns (iou (19,), reference pixel share (19,), frames used).
    """
    from landmarks.detect.registry import make_detector
    from landmarks.exceptions import NoFaceError
    from landmarks.io.image_files import read_image

    face_detector = make_detector(detector)
    predicted_maps, reference_maps = [], []
    for folder in frames_dirs:
        for rgb_path in sorted(Path(folder).glob("*_rgb.png")):
            seg_path = rgb_path.with_name(rgb_path.name.replace("_rgb.png", "_segmap_merged.png"))
            if not seg_path.is_file():
                continue
            image = read_image(rgb_path)
            try:
                landmarks = face_detector.detect_one(image).landmarks
            except NoFaceError:
                continue
            predicted_maps.append(oracle_segmentation(image, landmarks))
            reference_maps.append(read_official_segmap(seg_path))
    if not predicted_maps:
        raise DatasetError(f"no *_rgb.png with *_segmap_merged.png and a detectable face under {list(frames_dirs)}")
    predicted, reference = np.stack(predicted_maps), np.stack(reference_maps)
    share = np.bincount(reference.ravel(), minlength=NUM_SEG_CLASSES) / reference.size
    return segmentation_iou(predicted, reference), share, len(predicted_maps)


def run_bench_oracle_seg(cfg: BenchOracleSegConfig) -> int:
    """Entry point of ``lsr bench oracle-seg [ROOT]``: the per-class IoU of the oracle vs the official LSR maps
    (default root: the shared id00017 sample)."""
    from lsr.errors import DatasetError

    default = Path(__file__).resolve().parents[3] / "shared" / "data" / "fsth_eval_sample_processed"
    root = Path(cfg.root) if cfg.root is not None else default
    folders = sorted({p.parent for p in root.rglob("*_segmap_merged.png")})
    if not folders:
        raise DatasetError(f"no *_segmap_merged.png under {root}: give a folder of the LSR release's processed frames")
    iou, share, count = compare_with_official(folders)
    print(f"oracle vs official LSR segmaps: {count} frames from {len(folders)} folder(s) under {root}")
    print(format_iou_table(iou, share))
    return count
