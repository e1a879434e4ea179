"""Crop a face to the training framing, and paste a synthesised crop back into its frame.

LSR is trained on VoxCeleb2 crops (thesis §4.4): head, hair and some shoulders, face centred.
``crop_transform`` reproduces that framing from any frame. Its constants were calibrated on
the 224x224 frames of ``fsth_eval_sample`` (5 ids, 154 frames, dlib HOG + 68-point landmarks):

* eye-centre to eye-centre distance = 0.2184 of the crop side (median; p10-p90 0.179-0.247),
* eye-midpoint to mouth-midpoint distance = 0.2645 of the side (p10-p90 0.240-0.291),
* the midpoint of those two (eyes and mouth) sits at (0.504, 0.393) of the side.

The crop side is ``max(iod / 0.2184, eye_mouth / 0.2645) / 1.031``: the larger of the two
estimates survives yaw (which shortens the inter-ocular distance) and pitch (which shortens the
eye-mouth distance); 1.031 makes the median over the calibration frames exactly 1.

Conventions: an affine ``M`` is (2, 3) float64 and maps FRAME pixel coordinates to CROP pixel
coordinates (``cv2.warpAffine(frame, M, ...)`` makes the crop). Coordinates are (x, y) with
integer values at pixel centres. ``crop_transform`` is a pure function of the landmarks, so
video callers can smooth the landmarks first or smooth the transforms (``smooth_transforms``).
"""

from __future__ import annotations

from typing import Literal

import cv2
import numpy as np

from landmarks.shape.ibug68 import LEFT_EYE, NUM_LANDMARKS, RIGHT_EYE

# Framing measured on the VoxCeleb2 (FSTH evaluation) frames; see the module docstring.
IOD_FRACTION = 0.2184
EYE_MOUTH_FRACTION = 0.2645
SIZE_NORMALISER = 1.031
ANCHOR_FRACTION = (0.504, 0.393)  # (x, y) of the eyes/mouth midpoint in the crop
MOUTH_CORNERS = (48, 54)

BorderMode = Literal["replicate", "constant"]
MaskShape = Literal["square", "ellipse"]
_BORDERS = {"replicate": cv2.BORDER_REPLICATE, "constant": cv2.BORDER_CONSTANT}


def _check_landmarks(landmarks: np.ndarray) -> np.ndarray:
    points = np.asarray(landmarks, dtype=np.float64)
    if points.shape != (NUM_LANDMARKS, 2):
        raise ValueError(f"landmarks must have shape ({NUM_LANDMARKS}, 2) (x, y), got {np.shape(landmarks)}")
    if not np.isfinite(points).all():
        raise ValueError(
            "landmarks contain NaN/inf (no face in this frame): fill or interpolate missing frames "
            "before cropping, or reuse the previous frame's transform"
        )
    return points


def _check_affine(matrix: np.ndarray) -> np.ndarray:
    matrix = np.asarray(matrix, dtype=np.float64)
    if matrix.shape != (2, 3):
        raise ValueError(f"affine transform must have shape (2, 3), got {matrix.shape}")
    return matrix


def _check_image(image: np.ndarray, what: str) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] not in (1, 3, 4)):
        raise ValueError(f"{what} must be (H, W) or (H, W, C) with C in 1, 3, 4; got shape {image.shape}")
    return image


def _check_out_size(out_size: int) -> int:
    if not isinstance(out_size, (int, np.integer)) or out_size < 1:
        raise ValueError(f"out_size must be a positive int (crop side in pixels), got {out_size!r}")
    return int(out_size)


def face_geometry(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(eye_centre_left, eye_centre_right, mouth_centre), each (2,) float64, of (68, 2) landmarks."""
    points = _check_landmarks(landmarks)
    return points[LEFT_EYE].mean(0), points[RIGHT_EYE].mean(0), points[list(MOUTH_CORNERS)].mean(0)


def crop_transform(
    landmarks: np.ndarray, out_size: int, *, scale: float = 1.0, rotate: bool = False
) -> np.ndarray:
    """The similarity transform that frames a face like the VoxCeleb2 training crops.

    landmarks: (68, 2) float (x, y) in the frame, all finite.
    out_size: crop side S in pixels.
    scale: crop side relative to the calibrated framing (> 1 zooms out, shows more around the head).
    rotate: False keeps the frame's vertical (as VoxCeleb2 crops do); True also levels the eyes.
    returns: (2, 3) float64 M mapping frame (x, y) to crop (x, y). Pure function of its inputs.
    """
    out_size = _check_out_size(out_size)
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be a positive number, got {scale!r}")
    eye_left, eye_right, mouth = face_geometry(landmarks)
    eye_centre = (eye_left + eye_right) / 2
    inter_ocular = np.linalg.norm(eye_right - eye_left)
    eye_mouth = np.linalg.norm(mouth - eye_centre)
    side_in_frame = max(inter_ocular / IOD_FRACTION, eye_mouth / EYE_MOUTH_FRACTION) / SIZE_NORMALISER * scale
    if side_in_frame <= 0:
        raise ValueError("degenerate landmarks: eyes and mouth coincide, cannot size the crop")
    zoom = out_size / side_in_frame
    angle = np.arctan2(*(eye_right - eye_left)[::-1]) if rotate else 0.0
    cos, sin = np.cos(angle) * zoom, np.sin(angle) * zoom
    linear = np.array([[cos, sin], [-sin, cos]])  # rotates by -angle: eye line becomes horizontal
    anchor_frame = (eye_centre + mouth) / 2
    # Fractions are of the crop's extent [-0.5, S - 0.5] in pixel-centre coordinates.
    anchor_crop = np.asarray(ANCHOR_FRACTION) * out_size - 0.5
    return np.concatenate([linear, (anchor_crop - linear @ anchor_frame)[:, None]], axis=1)


def transform_landmarks(landmarks: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply an affine M to points. landmarks: (..., 2); M: (2, 3). NaN points stay NaN."""
    points = np.asarray(landmarks, dtype=np.float64)
    if points.shape[-1] != 2:
        raise ValueError(f"points must have a last axis of 2 (x, y), got shape {points.shape}")
    matrix = _check_affine(matrix)
    return points @ matrix[:, :2].T + matrix[:, 2]


def transform_mesh(mesh: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Apply a similarity M ((2, 3): rotation and uniform scale, as a crop transform) to a (..., 468, 3) mesh: x, y
    as points, depth scaled by the same factor. NaN stays NaN."""
    mesh = np.asarray(mesh, dtype=np.float64)
    scale = float(np.sqrt(abs(np.linalg.det(_check_affine(matrix)[:, :2]))))
    return np.concatenate([transform_landmarks(mesh[..., :2], matrix), mesh[..., 2:3] * scale], axis=-1)


def invert_affine(matrix: np.ndarray) -> np.ndarray:
    """Inverse of a (2, 3) affine (crop -> frame for a crop transform). Raises on a singular one."""
    matrix = _check_affine(matrix)
    linear = matrix[:, :2]
    if abs(np.linalg.det(linear)) < 1e-12:
        raise ValueError("affine transform is singular (zero scale) and cannot be inverted")
    inverse = np.linalg.inv(linear)
    return np.concatenate([inverse, (-inverse @ matrix[:, 2])[:, None]], axis=1)


def _frame_roi(matrix: np.ndarray, crop_size: int, frame_hw: tuple[int, int], margin: int) -> tuple[int, int, int, int] | None:
    """Bounding box (x0, y0, x1, y1) in the frame of the crop's footprint, clipped; None if outside."""
    corners = np.array([[-0.5, -0.5], [crop_size - 0.5, -0.5], [-0.5, crop_size - 0.5], [crop_size - 0.5] * 2])
    footprint = transform_landmarks(corners, invert_affine(matrix))
    x0, y0 = np.floor(footprint.min(0)).astype(int) - margin
    x1, y1 = np.ceil(footprint.max(0)).astype(int) + margin + 1
    height, width = frame_hw
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, width), min(y1, height)
    return None if x0 >= x1 or y0 >= y1 else (x0, y0, x1, y1)


def crop(
    frame: np.ndarray,
    landmarks: np.ndarray,
    out_size: int,
    *,
    scale: float = 1.0,
    rotate: bool = False,
    border: BorderMode = "replicate",
    interpolation: int = cv2.INTER_CUBIC,
) -> tuple[np.ndarray, np.ndarray]:
    """Cut the training-framed face crop out of a frame.

    frame: (H, W, C) or (H, W) uint8; landmarks: (68, 2) in the frame; out_size: crop side S.
    border: how the crop is filled where it leaves the frame ("replicate" edge pixels or
        "constant" black). Downscaling by more than 2x is pre-filtered (INTER_AREA) against aliasing.
    returns: (crop (S, S[, C]) same dtype as frame, M (2, 3) float64 frame -> crop).
    """
    frame = _check_image(frame, "frame")
    if border not in _BORDERS:
        raise ValueError(f"border must be one of {sorted(_BORDERS)}, got {border!r}")
    matrix = crop_transform(landmarks, out_size, scale=scale, rotate=rotate)
    return warp_to_crop(frame, matrix, out_size, border=border, interpolation=interpolation), matrix


def warp_to_crop(
    frame: np.ndarray, matrix: np.ndarray, out_size: int, *, border: BorderMode = "replicate",
    interpolation: int = cv2.INTER_CUBIC,
) -> np.ndarray:
    """Warp a frame with a given crop transform (e.g. a smoothed one). Shapes as in ``crop``."""
    frame = _check_image(frame, "frame")
    matrix = _check_affine(matrix)
    out_size = _check_out_size(out_size)
    zoom = np.sqrt(abs(np.linalg.det(matrix[:, :2])))
    if zoom < 0.5:
        # Warping samples points; shrinking by > 2x would alias. Area-average the region first.
        roi = _frame_roi(matrix, out_size, frame.shape[:2], margin=4)
        if roi is not None:
            x0, y0, x1, y1 = roi
            factor = min(1.0, 2 * zoom)  # leave at most 2x for the warp to do
            region = frame[y0:y1, x0:x1]
            new_w, new_h = max(1, round((x1 - x0) * factor)), max(1, round((y1 - y0) * factor))
            small = cv2.resize(region, (new_w, new_h), interpolation=cv2.INTER_AREA)
            fx, fy = (x1 - x0) / new_w, (y1 - y0) / new_h
            # small pixel (u, v) centre <- frame ((u + 0.5) * fx - 0.5 + x0, (v + 0.5) * fy - 0.5 + y0)
            to_frame = np.array([[fx, 0, 0.5 * fx - 0.5 + x0], [0, fy, 0.5 * fy - 0.5 + y0]])
            frame = small
            matrix = matrix @ np.vstack([to_frame, [0, 0, 1]])
            # Edges of the region are only frame edges where the ROI was clipped; else the margin covers it.
    return cv2.warpAffine(
        frame, matrix, (out_size, out_size), flags=interpolation, borderMode=_BORDERS[border], borderValue=0
    )


def crop_mask(out_size: int, *, feather: float, shape: MaskShape = "square") -> np.ndarray:
    """Blend weights in crop space: (S, S) float32 in [0, 1], 1 inside, ramping to 0 at the edge.

    feather: width of the linear ramp in crop pixels (0 = hard edge).
    shape: "square" (the whole crop) or "ellipse" (inscribed ellipse: face and hair, no corners).
    """
    out_size = _check_out_size(out_size)
    if not (np.isfinite(feather) and feather >= 0):
        raise ValueError(f"feather must be >= 0 crop pixels, got {feather!r}")
    centres = np.arange(out_size, dtype=np.float32) + 0.5  # pixel centres, crop spans [0, S]
    if shape == "square":
        to_edge = np.minimum(centres, out_size - centres)  # distance to the nearest edge
        distance = np.minimum(to_edge[:, None], to_edge[None, :])
    elif shape == "ellipse":
        radius = out_size / 2
        offset = (centres - radius) / radius
        # Approximate distance inside the inscribed circle, in pixels.
        distance = (1 - np.sqrt(offset[:, None] ** 2 + offset[None, :] ** 2)) * radius
    else:
        raise ValueError(f"mask shape must be 'square' or 'ellipse', got {shape!r}")
    if feather == 0:
        return (distance > 0).astype(np.float32)
    return np.clip(distance / feather, 0, 1).astype(np.float32)


def paste_back(
    frame: np.ndarray,
    crop_image: np.ndarray,
    matrix: np.ndarray,
    *,
    feather: float | None = None,
    mask: np.ndarray | MaskShape = "square",
    interpolation: int = cv2.INTER_CUBIC,
) -> np.ndarray:
    """Put a (synthesised) crop back into its frame with the exact inverse of the crop warp.

    frame: (H, W, C) uint8; crop_image: (S, S, C) uint8 (same C); matrix: the (2, 3) frame -> crop
        transform the crop was made with.
    feather: blend ramp width in crop pixels; default S / 16.
    mask: "square" / "ellipse" (see ``crop_mask``), or an (S, S) float array in [0, 1] in crop
        space (e.g. a head mask), multiplied by the feathered square so crop edges never show.
    returns: a new (H, W, C) uint8 frame; only pixels inside the frame under the mask change.
    """
    frame = _check_image(frame, "frame")
    crop_image = _check_image(crop_image, "crop_image")
    matrix = _check_affine(matrix)
    size = crop_image.shape[0]
    if crop_image.shape[1] != size:
        raise ValueError(f"crop_image must be square (S, S, C), got shape {crop_image.shape}")
    if crop_image.shape[2:] != frame.shape[2:]:
        raise ValueError(f"crop_image channels {crop_image.shape[2:]} differ from frame channels {frame.shape[2:]}")
    feather = size / 16 if feather is None else feather
    if isinstance(mask, str):
        weights = crop_mask(size, feather=feather, shape=mask)
    else:
        user_mask = np.asarray(mask, dtype=np.float32)
        if user_mask.shape != (size, size):
            raise ValueError(f"mask must have the crop's shape ({size}, {size}), got {user_mask.shape}")
        weights = np.clip(user_mask, 0, 1) * crop_mask(size, feather=feather, shape="square")

    result = frame.copy()
    roi = _frame_roi(matrix, size, frame.shape[:2], margin=2)
    if roi is None:
        return result  # the crop lies entirely outside the frame
    x0, y0, x1, y1 = roi
    # Frame pixel (x, y) of the ROI samples the crop at M @ (x + x0, y + y0): the exact inverse warp.
    roi_matrix = matrix.copy()
    roi_matrix[:, 2] += matrix[:, :2] @ np.array([x0, y0], dtype=np.float64)
    flags = interpolation | cv2.WARP_INVERSE_MAP
    roi_size = (x1 - x0, y1 - y0)
    pasted = cv2.warpAffine(crop_image, roi_matrix, roi_size, flags=flags, borderMode=cv2.BORDER_REPLICATE)
    alpha = cv2.warpAffine(weights, roi_matrix, roi_size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    if frame.ndim == 3:
        alpha = alpha[..., None]
    region = result[y0:y1, x0:x1].astype(np.float32)
    blended = region + (pasted.astype(np.float32) - region) * alpha
    if np.issubdtype(frame.dtype, np.integer):
        info = np.iinfo(frame.dtype)
        blended = np.clip(np.rint(blended), info.min, info.max)
    result[y0:y1, x0:x1] = blended.astype(frame.dtype)
    return result


def smooth_transforms(matrices: np.ndarray, alpha: float) -> np.ndarray:
    """Exponential smoothing of a video's crop transforms, against jitter of the framing.

    matrices: (T, 2, 3) float; frames with NaN (no face) hold the last smoothed transform
        (leading NaN frames take the first valid one). All-NaN input is returned unchanged.
    alpha: weight of the new frame in (0, 1]; 1 = no smoothing, smaller = steadier but laggier.
    returns: (T, 2, 3) float64. Averaging similarity matrices keeps them similarities.
    """
    matrices = np.asarray(matrices, dtype=np.float64)
    if matrices.ndim != 3 or matrices.shape[1:] != (2, 3):
        raise ValueError(f"matrices must have shape (T, 2, 3), got {matrices.shape}")
    if not (0 < alpha <= 1):
        raise ValueError(f"alpha must be in (0, 1], got {alpha!r}")
    valid = np.isfinite(matrices).all(axis=(1, 2))
    smoothed = matrices.copy()
    if not valid.any():
        return smoothed
    state = matrices[np.argmax(valid)]
    for index in range(len(matrices)):
        if valid[index]:
            state = alpha * matrices[index] + (1 - alpha) * state
        smoothed[index] = state
    return smoothed
