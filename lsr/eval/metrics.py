"""Image and landmark metrics of the evaluation protocol (thesis §4.4 "Metrics").

Conventions (stated in every report):
  PSNR  on uint8 RGB with peak 255, over all pixels and channels. Identical images have
        MSE 0 and PSNR = +inf; ``summarise_psnr`` reports the mean over finite frames, the
        count of infinite ones, and the PSNR of the mean MSE (which stays finite unless every
        frame is identical).
  SSIM  ``kornia.metrics.ssim``: 11x11 Gaussian window, sigma 1.5, reflect padding ('same'),
        on RGB in [0, 1] (c1 = 0.01^2, c2 = 0.03^2), mean of the map over pixels and channels.
  NMKE  (Bi-layer / LPD, [113, 114]): mean Euclidean distance of the 68 landmarks detected on
        the output to those on the ground truth, divided by the distance between the ground
        truth's eye centres (means of points 36-41 and 42-47).
  sharpness  per frame, var(Laplacian(grey output)) / var(Laplacian(grey ground truth)):
        ``cv2.cvtColor`` RGB2GRAY (uint8), ``cv2.Laplacian`` in CV_64F with ksize 1 (the 4-neighbour
        kernel [[0, 1, 0], [1, -4, 1], [0, 1, 0]]), default reflect-101 border; variance over all pixels.
        1.0 = as much fine detail as the real frame, < 1 blurrier, > 1 sharper or noisier. NaN where the
        ground truth has zero Laplacian variance (a flat frame). Reported as the median over frames (NaN
        ignored): a few noisy outputs would dominate a mean of ratios.
  face region  (``face_mask``) the convex hull of the 68 ground-truth landmarks (jaw, brows, eyes, nose,
        mouth), dilated by ``FACE_DILATION`` = 0.1 of the inter-ocular distance (about the jaw line's own
        width at 224 px) so that the chin and cheek edges count as face. ``psnr_face`` = PSNR of the MSE over
        the masked pixels; ``ssim_face`` = mean of the same SSIM map (computed on the whole frame, so the
        window sees real context) over the masked pixels; ``sharpness_face`` = the sharpness ratio of the
        Laplacian's variances over the masked pixels (the Laplacian still taken on the whole frame).
ID-SIM lives in ``lsr.eval.idsim`` (dlib embeddings; needs the model file).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from landmarks.shape.ibug68 import NUM_LANDMARKS
from lsr.errors import ConfigError

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5  # kornia's fixed Gaussian sigma; only the window size is a parameter
PIXEL_PEAK = 255.0
LAPLACIAN_KSIZE = 1  # cv2.Laplacian's own default: the 4-neighbour kernel, the usual variance-of-Laplacian focus measure
FACE_DILATION = 0.1  # face_mask's dilation, a fraction of the inter-ocular distance
LEFT_EYE = slice(36, 42)  # iBUG-68 points 36-41 (subject's right eye, image left)
RIGHT_EYE = slice(42, 48)


def _check_image_pair(output: np.ndarray, target: np.ndarray) -> None:
    if output.shape != target.shape or output.ndim < 3 or output.shape[-1] != 3:
        raise ConfigError(f"images must have the same (..., H, W, 3) shape, got {output.shape} and {target.shape}")
    if output.dtype != np.uint8 or target.dtype != np.uint8:
        raise ConfigError(f"images must be uint8 RGB, got {output.dtype} and {target.dtype}")


def _check_mask(mask: np.ndarray, image_shape: tuple[int, ...]) -> np.ndarray:
    mask = np.asarray(mask)
    if mask.dtype != bool or mask.shape != image_shape[:-1]:
        raise ConfigError(f"mask must be bool of shape {image_shape[:-1]} (the images' (..., H, W)), got {mask.shape} {mask.dtype}")
    return mask


def _masked_mean(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Mean of values (..., H, W) over mask (..., H, W) bool -> (...); NaN where the mask is empty."""
    count = mask.sum(axis=(-2, -1))
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(count > 0, (values * mask).sum(axis=(-2, -1)) / np.maximum(count, 1), np.nan)


def mse(output: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Mean squared error in grey levels^2. output, target: (..., H, W, 3) uint8 -> (...) float64.

    mask: (..., H, W) bool: the mean over its pixels (and the channels) only; NaN where it is empty."""
    _check_image_pair(output, target)
    difference = output.astype(np.float64) - target.astype(np.float64)
    if mask is None:
        return np.mean(difference**2, axis=(-3, -2, -1))
    return _masked_mean(np.mean(difference**2, axis=-1), _check_mask(mask, output.shape))


def psnr_from_mse(mean_squared_error: np.ndarray | float) -> np.ndarray:
    """PSNR in dB for peak 255; MSE 0 gives +inf (identical images), never a division warning."""
    value = np.asarray(mean_squared_error, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return np.where(value > 0, 10.0 * np.log10(PIXEL_PEAK**2 / np.maximum(value, 1e-300)), np.inf)


def psnr(output: np.ndarray, target: np.ndarray) -> np.ndarray:
    """PSNR in dB. output, target: (..., H, W, 3) uint8 -> (...) float64; +inf where identical."""
    return psnr_from_mse(mse(output, target))


def summarise_psnr(values: np.ndarray, mses: np.ndarray) -> dict[str, float | int]:
    """Means of per-frame PSNR with infinities handled explicitly.

    Returns {"mean_finite": mean over finite frames (nan if none), "infinite": count of identical
    frames (excluded from mean_finite), "of_mean_mse": PSNR of the mean MSE over all frames}.
    """
    values = np.asarray(values, dtype=np.float64)
    finite = values[np.isfinite(values)]
    return {
        "mean_finite": float(finite.mean()) if finite.size else math.nan,
        "infinite": int(np.sum(np.isinf(values))),
        "of_mean_mse": float(psnr_from_mse(float(np.mean(mses)))) if len(mses) else math.nan,
    }


def ssim(output: np.ndarray, target: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """Mean SSIM (11x11 Gaussian window, sigma 1.5). output, target: (N, H, W, 3) or (H, W, 3) uint8
    -> (N,) or () float64. Computed in fp32 (fp64 is 5x slower on CPU; identical images give 1 to ~1e-7).

    mask: (N, H, W) or (H, W) bool: the mean of the (whole-frame) SSIM map over its pixels and the channels
    instead of over all pixels; NaN where it is empty. Without a mask the result is unchanged."""
    import kornia
    import torch

    _check_image_pair(output, target)
    if mask is not None:
        mask = _check_mask(mask, output.shape)
    single = output.ndim == 3
    if single:
        output, target = output[None], target[None]
        mask = None if mask is None else mask[None]
    if min(output.shape[1:3]) <= SSIM_WINDOW // 2:
        raise ConfigError(f"SSIM needs images larger than {SSIM_WINDOW // 2} pixels, got {output.shape[1:3]}")
    # (N, H, W, 3) uint8 -> (N, 3, H, W) float32 in [0, 1]
    first = torch.from_numpy(output).permute(0, 3, 1, 2).to(torch.float32) / PIXEL_PEAK
    second = torch.from_numpy(target).permute(0, 3, 1, 2).to(torch.float32) / PIXEL_PEAK
    with torch.no_grad():
        ssim_map = kornia.metrics.ssim(first, second, window_size=SSIM_WINDOW, max_val=1.0, eps=0.0)
    if mask is None:
        values = ssim_map.mean(dim=(1, 2, 3)).double().numpy()
    else:
        values = _masked_mean(ssim_map.mean(dim=1).double().numpy(), mask)  # (N, H, W) channel mean, then masked
    return values[0] if single else values


def laplacian_variance(images: np.ndarray) -> np.ndarray:
    """Variance of the Laplacian of the grey image (see the module docstring).

    images: (..., H, W, 3) uint8 RGB -> (...) float64.
    """
    images = np.asarray(images)
    if images.ndim < 3 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise ConfigError(f"images must be (..., H, W, 3) uint8 RGB, got {images.shape} {images.dtype}")
    flat = images.reshape(-1, *images.shape[-3:])  # (N, H, W, 3)
    values = np.empty(len(flat))
    for index, image in enumerate(flat):
        grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
        values[index] = cv2.Laplacian(grey, cv2.CV_64F, ksize=LAPLACIAN_KSIZE).var()
    return values.reshape(images.shape[:-3])


def masked_laplacian_variance(image: np.ndarray, mask: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image over the pixels of ``mask`` (the Laplacian is taken on the
    whole image, so the mask's edge is no edge). image: (H, W, 3) uint8 RGB; mask: (H, W) bool -> float
    (NaN when the mask is empty)."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[-1] != 3 or image.dtype != np.uint8:
        raise ConfigError(f"image must be (H, W, 3) uint8 RGB, got {image.shape} {image.dtype}")
    mask = _check_mask(mask, image.shape)
    if not mask.any():
        return math.nan
    grey = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY)
    return float(cv2.Laplacian(grey, cv2.CV_64F, ksize=LAPLACIAN_KSIZE)[mask].var())


def sharpness(output: np.ndarray, target: np.ndarray, masks: np.ndarray | None = None) -> np.ndarray:
    """Laplacian-variance ratio output / ground truth (1 = as sharp as the real frame; module docstring).

    output, target: (..., H, W, 3) uint8; masks: None (the whole frame) or (..., H, W) bool, each frame's variances
    over its mask (``masked_laplacian_variance``, e.g. the face region) -> (...) float64; NaN where the target's
    variance is 0 or its mask empty.
    """
    _check_image_pair(output, target)
    if masks is None:
        reference, value = laplacian_variance(target), laplacian_variance(output)
    else:
        masks = np.asarray(masks)
        if masks.shape != output.shape[:-1]:
            raise ConfigError(f"masks must be {output.shape[:-1]} (one per frame), got {masks.shape}")
        pairs = np.array([(masked_laplacian_variance(t, m), masked_laplacian_variance(o, m)) for o, t, m in zip(
            output.reshape(-1, *output.shape[-3:]), target.reshape(-1, *target.shape[-3:]),
            masks.reshape(-1, *masks.shape[-2:]))], np.float64).reshape(*output.shape[:-3], 2)
        reference, value = pairs[..., 0], pairs[..., 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(reference > 0, value / np.where(reference > 0, reference, 1.0), np.nan)


def median_sharpness(values: np.ndarray) -> float:
    """Median of per-frame sharpness ratios, NaN frames ignored (NaN when none is finite)."""
    values = np.asarray(values, np.float64)
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if finite.size else math.nan


def face_mask(landmarks: np.ndarray, shape: tuple[int, int], dilate: float = FACE_DILATION) -> np.ndarray:
    """The face region of one face (module docstring): the convex hull of its 68 landmarks dilated by
    ``dilate`` x its inter-ocular distance. landmarks: (68, 2) x, y pixels; shape: (H, W) -> (H, W) bool
    (all False when the landmarks are not finite)."""
    points = check_landmarks(landmarks)
    if points.shape != (NUM_LANDMARKS, 2):
        raise ConfigError(f"face_mask needs one face's ({NUM_LANDMARKS}, 2) landmarks, got {points.shape}")
    if dilate < 0:
        raise ConfigError(f"face_mask's dilation must be >= 0, got {dilate}")
    mask = np.zeros(shape, np.uint8)
    if not np.isfinite(points).all():
        return mask.astype(bool)
    hull = cv2.convexHull(np.round(points).astype(np.int32))
    cv2.fillConvexPoly(mask, hull, 1)
    radius = dilate * float(eye_distance(points))
    if radius > 0:
        outside = cv2.distanceTransform(1 - mask, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)  # pixels to the hull, 0 inside
        return outside <= radius
    return mask.astype(bool)


def check_landmarks(landmarks: np.ndarray, name: str = "landmarks") -> np.ndarray:
    """(..., 68, 2) float array or ConfigError."""
    landmarks = np.asarray(landmarks)
    if landmarks.ndim < 2 or landmarks.shape[-2:] != (NUM_LANDMARKS, 2):
        raise ConfigError(f"{name} must have shape (..., {NUM_LANDMARKS}, 2), got {landmarks.shape}")
    return landmarks.astype(np.float64)


def eye_distance(landmarks: np.ndarray) -> np.ndarray:
    """Distance between the eye centres (means of points 36-41 and 42-47). (..., 68, 2) -> (...)."""
    landmarks = check_landmarks(landmarks)
    left = landmarks[..., LEFT_EYE, :].mean(axis=-2)
    right = landmarks[..., RIGHT_EYE, :].mean(axis=-2)
    return np.linalg.norm(right - left, axis=-1)


def nmke(predicted: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Normalised mean keypoint error [113, 114]: mean point distance / eye distance of ``reference``.

    predicted, reference: (..., 68, 2) x, y pixels (broadcastable) -> (...) float64. NaN where
    either set has NaN rows (no face) or the reference eye distance is 0.
    """
    predicted = check_landmarks(predicted, "predicted")
    reference = check_landmarks(reference, "reference")
    mean_distance = np.linalg.norm(predicted - reference, axis=-1).mean(axis=-1)
    normaliser = eye_distance(reference)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(normaliser > 0, mean_distance / np.where(normaliser > 0, normaliser, 1.0), np.nan)
