"""Metric identities and known values (lsr.eval.metrics)."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from lsr.errors import ConfigError
from lsr.eval import metrics


def _face_landmarks(rng: np.random.Generator) -> np.ndarray:
    points = rng.uniform(40, 180, size=(68, 2))
    points[36:42] = [60, 90] + rng.normal(0, 2, size=(6, 2))  # one eye around x = 60
    points[42:48] = [140, 90] + rng.normal(0, 2, size=(6, 2))  # the other around x = 140
    return points


class TestPsnr:
    def test_identical_images_are_infinite(self, rng):
        image = rng.integers(0, 256, size=(32, 32, 3), dtype=np.uint8)
        assert metrics.psnr(image, image) == math.inf
        summary = metrics.summarise_psnr(np.array([math.inf, 20.0]), np.array([0.0, 650.25]))
        assert summary["infinite"] == 1
        assert summary["mean_finite"] == pytest.approx(20.0)
        assert summary["of_mean_mse"] == pytest.approx(10 * math.log10(255**2 / (650.25 / 2)))

    def test_known_noise_matches_formula(self):
        target = np.full((16, 16, 3), 128, np.uint8)
        output = target.copy()
        output[::2] += 10  # half the pixels +10, half -10: MSE = 100 exactly
        output[1::2] -= 10
        assert metrics.mse(output, target) == pytest.approx(100.0)
        assert metrics.psnr(output, target) == pytest.approx(10 * math.log10(255**2 / 100.0))

    def test_random_noise_matches_formula(self, rng):
        target = rng.integers(20, 236, size=(2, 24, 24, 3)).astype(np.uint8)
        noise = rng.integers(-15, 16, size=target.shape)
        output = (target.astype(int) + noise).astype(np.uint8)
        expected = 10 * np.log10(255**2 / np.mean(noise.astype(float) ** 2, axis=(1, 2, 3)))
        np.testing.assert_allclose(metrics.psnr(output, target), expected, rtol=1e-12)

    def test_bad_inputs_raise(self):
        with pytest.raises(ConfigError):
            metrics.psnr(np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8))
        with pytest.raises(ConfigError):
            metrics.psnr(np.zeros((8, 8, 3), np.float32), np.zeros((8, 8, 3), np.float32))


class TestSsim:
    def test_identical_is_one(self, rng):
        images = rng.integers(0, 256, size=(3, 32, 32, 3), dtype=np.uint8)
        np.testing.assert_allclose(metrics.ssim(images, images), 1.0, atol=1e-6)

    def test_noise_lowers_ssim_and_is_symmetric(self, rng):
        image = rng.integers(0, 256, size=(32, 32, 3), dtype=np.uint8)
        noisy = np.clip(image.astype(int) + rng.integers(-40, 41, size=image.shape), 0, 255).astype(np.uint8)
        value = metrics.ssim(noisy, image)
        assert 0.0 < value < 0.99
        assert metrics.ssim(image, noisy) == pytest.approx(value, abs=1e-6)


def _smooth_image(rng: np.random.Generator, size: int = 64) -> np.ndarray:
    """Blurred noise stretched to 10..245: natural-image-like detail, room for added noise without clipping."""
    noise = rng.normal(0.0, 1.0, size=(size, size, 3))
    smooth = cv2.GaussianBlur(noise, (0, 0), 1.5)
    smooth = (smooth - smooth.min()) / (smooth.max() - smooth.min())
    return np.rint(10 + 235 * smooth).astype(np.uint8)


class TestSharpness:
    def test_image_against_itself_is_one(self, rng):
        images = np.stack([_smooth_image(rng), _smooth_image(rng)])
        np.testing.assert_array_equal(metrics.sharpness(images, images), [1.0, 1.0])

    def test_blur_lowers_and_noise_raises_it(self, rng):
        image = _smooth_image(rng)
        blurred = cv2.GaussianBlur(image, (0, 0), 1.5)
        noisy = np.clip(image + rng.normal(0.0, 8.0, size=image.shape), 0, 255).round().astype(np.uint8)
        assert metrics.sharpness(blurred, image) < 0.5
        assert metrics.sharpness(noisy, image) > 1.0
        assert metrics.sharpness(image, blurred) > 2.0  # the ratio is output over ground truth

    def test_flat_ground_truth_is_nan_and_ignored_by_the_median(self, rng):
        image = _smooth_image(rng)
        flat = np.full_like(image, 128)
        assert np.isnan(metrics.sharpness(image, flat))
        values = metrics.sharpness(np.stack([image, image, image]), np.stack([image, flat, cv2.GaussianBlur(image, (0, 0), 1.5)]))
        assert np.isnan(values[1]) and values[2] > 1.0
        assert metrics.median_sharpness(values) == pytest.approx((1.0 + values[2]) / 2)
        assert np.isnan(metrics.median_sharpness(np.array([np.nan])))

    def test_matches_opencv_definition(self, rng):
        output, target = _smooth_image(rng), _smooth_image(rng)

        def laplacian_variance(image):
            return cv2.Laplacian(cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), cv2.CV_64F, ksize=metrics.LAPLACIAN_KSIZE).var()

        expected = laplacian_variance(output) / laplacian_variance(target)
        assert metrics.sharpness(output, target) == pytest.approx(expected, rel=1e-12)

    def test_over_a_mask_counts_only_its_pixels(self, rng):
        target = _smooth_image(rng)
        output = target.copy()
        output[:, : target.shape[1] // 2] = cv2.GaussianBlur(target, (0, 0), 2.0)[:, : target.shape[1] // 2]
        right = np.zeros(target.shape[:2], bool)
        right[:, target.shape[1] // 2 + 2 :] = True  # clear of the blurred half's edge
        assert metrics.sharpness(output, target) < 0.9  # the blurred half counts over the whole frame ...
        assert metrics.sharpness(output, target, masks=right) == 1.0  # ... not over the sharp half
        pair = metrics.sharpness(np.stack([output, output]), np.stack([target, target]), masks=np.stack([right, ~right]))
        assert pair[0] == 1.0 and pair[1] < 0.5
        assert np.isnan(metrics.sharpness(output, target, masks=np.zeros_like(right)))  # an empty mask

    def test_bad_inputs_raise(self):
        with pytest.raises(ConfigError):
            metrics.sharpness(np.zeros((8, 8, 3), np.uint8), np.zeros((8, 9, 3), np.uint8))
        with pytest.raises(ConfigError):
            metrics.sharpness(np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8, 3), np.uint8), masks=np.ones((8, 9), bool))
        with pytest.raises(ConfigError):
            metrics.laplacian_variance(np.zeros((8, 8), np.uint8))


class TestNmke:
    def test_identical_is_zero(self, rng):
        landmarks = _face_landmarks(rng)
        assert metrics.nmke(landmarks, landmarks) == 0.0

    def test_translation_is_distance_over_eye_distance(self, rng):
        landmarks = _face_landmarks(rng)
        eyes = np.linalg.norm(landmarks[42:48].mean(0) - landmarks[36:42].mean(0))
        assert metrics.nmke(landmarks + [3.0, 4.0], landmarks) == pytest.approx(5.0 / eyes)

    def test_missing_landmarks_give_nan_and_bad_shapes_raise(self, rng):
        assert np.isnan(metrics.nmke(np.full((68, 2), np.nan), _face_landmarks(rng)))
        with pytest.raises(ConfigError):
            metrics.nmke(np.zeros((5, 2)), np.zeros((5, 2)))


class TestFaceRegion:
    def test_mask_is_the_dilated_hull(self, rng):
        landmarks = _face_landmarks(rng)
        tight = metrics.face_mask(landmarks, (224, 224), dilate=0.0)
        wide = metrics.face_mask(landmarks, (224, 224))
        hull = cv2.convexHull(np.round(landmarks).astype(np.int32))
        assert tight.sum() == pytest.approx(cv2.contourArea(hull), rel=0.05)
        assert np.all(wide[tight]) and wide.sum() > tight.sum()
        eyes = metrics.eye_distance(landmarks)
        perimeter = cv2.arcLength(hull, True)  # a dilation by r adds about perimeter * r + pi r^2
        radius = metrics.FACE_DILATION * eyes
        assert wide.sum() - tight.sum() == pytest.approx(perimeter * radius + math.pi * radius**2, rel=0.15)
        assert not metrics.face_mask(np.full((68, 2), np.nan), (32, 32)).any()
        with pytest.raises(ConfigError):
            metrics.face_mask(np.zeros((5, 2)), (32, 32))

    def test_masked_mse_and_psnr(self):
        target = np.full((2, 16, 16, 3), 100, np.uint8)
        output = target.copy()
        output[:, :8] += 10  # top half off by 10
        top = np.zeros((2, 16, 16), bool)
        top[:, :8] = True
        assert metrics.mse(output, target, mask=top) == pytest.approx([100.0, 100.0])
        assert metrics.mse(output, target, mask=~top) == pytest.approx([0.0, 0.0])
        assert metrics.mse(output, target, mask=np.ones_like(top)) == pytest.approx(metrics.mse(output, target))
        assert np.isnan(metrics.mse(output, target, mask=np.zeros_like(top))).all()
        with pytest.raises(ConfigError):
            metrics.mse(output, target, mask=top[:, :, :8])

    def test_masked_ssim_is_the_mean_of_the_map_inside(self, rng):
        target = rng.integers(0, 256, size=(2, 32, 32, 3), dtype=np.uint8)
        output = target.copy()
        output[:, :, 20:] = rng.integers(0, 256, size=(2, 32, 12, 3), dtype=np.uint8)  # right part replaced
        left = np.zeros((2, 32, 32), bool)
        left[:, :, :8] = True  # far from the change: the window never sees it
        assert metrics.ssim(output, target, mask=left) == pytest.approx([1.0, 1.0], abs=1e-5)
        assert np.all(metrics.ssim(output, target, mask=~left) < metrics.ssim(output, target))
        everywhere = metrics.ssim(output, target, mask=np.ones_like(left))
        assert everywhere == pytest.approx(metrics.ssim(output, target), abs=1e-6)
        assert metrics.ssim(output[0], target[0], mask=left[0]) == pytest.approx(1.0, abs=1e-5)

    def test_masked_laplacian_variance(self, rng):
        image = rng.integers(0, 256, size=(32, 32, 3), dtype=np.uint8)
        image[:, 16:] = 128  # flat right half
        right = np.zeros((32, 32), bool)
        right[2:-2, 20:-2] = True
        assert metrics.masked_laplacian_variance(image, right) == 0.0
        assert metrics.masked_laplacian_variance(image, ~right) > 0.0
        assert math.isnan(metrics.masked_laplacian_variance(image, np.zeros((32, 32), bool)))
