"""Regularised TPS warping (landmarks.warp.tps) and the TPS baseline's fallback counting."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.warp import tps
from lsr.eval.baselines import NearestShot, TpsWarp


def _points(rng: np.random.Generator, count: int = 30, size: int = 96) -> np.ndarray:
    return rng.uniform(0.25 * size, 0.75 * size, size=(count, 2))


def _image(rng: np.random.Generator, size: int = 96) -> np.ndarray:
    return rng.integers(0, 256, size=(size, size, 3), dtype=np.uint8)


def test_identity_when_source_equals_target(rng):
    image, points = _image(rng), _points(rng)
    result = tps.warp_tps(image, points, points)
    assert result.method == "tps"
    assert np.abs(result.image.astype(int) - image.astype(int)).max() <= 1


def test_exact_interpolation_without_regularisation(rng):
    control = _points(rng)
    values = control + rng.normal(0, 3, size=control.shape)
    spline = tps.fit_tps(control, values, regularization=0.0)
    np.testing.assert_allclose(spline(control), values, atol=1e-6)


def test_regularisation_smooths_instead_of_interpolating(rng):
    control = _points(rng)
    values = control + rng.normal(0, 3, size=control.shape)
    spline = tps.fit_tps(control, values, regularization=1.0)
    assert np.abs(spline(control) - values).max() > 1e-3


@pytest.mark.parametrize("merge_distance", [tps.DEFAULT_MERGE_DISTANCE, 0.0])
def test_near_coincident_points_give_finite_fold_free_output(rng, merge_distance):
    image = _image(rng)
    target = _points(rng)
    source = target + rng.normal(0, 2, size=target.shape)
    target = np.concatenate([target, target[:1] + 1e-6])  # a near-duplicate control point ...
    source = np.concatenate([source, source[:1] + [4.0, -4.0]])  # ... asking for a different value
    result = tps.warp_tps(image, source, target, merge_distance=merge_distance)
    assert result.image.dtype == np.uint8 and result.image.shape == image.shape
    assert result.folded_fraction == 0.0
    assert result.method in ("tps", "tps_stronger", "similarity")


def test_unregularised_near_duplicates_are_rejected():
    control = np.array([[0, 0], [10, 0], [0, 10], [10, 10], [5, 5], [5, 5 + 1e-9]], float)
    values = control.copy()
    values[-1] += 3.0
    with pytest.raises(tps.DegenerateTpsError):
        tps.fit_tps(control, values, regularization=0.0)


def test_collinear_points_fall_back_and_are_counted(rng):
    image = _image(rng)
    xs = np.linspace(20, 70, 12)
    target = np.stack([xs, 0.5 * xs + 10], axis=1)
    source = target + [3.0, 1.0]
    result = tps.warp_tps(image, source, target, fix_border=False)
    assert result.method == "similarity" and "ill-conditioned" in result.reason
    coincident = np.full((5, 2), 40.0)
    assert tps.warp_tps(image, coincident, coincident, fix_border=False).method == "identity"
    xs68 = np.linspace(20, 70, 68)
    line = np.stack([xs68, 0.5 * xs68 + 10], axis=1)[None]  # (1, 68, 2) collinear "landmarks"
    method = TpsWarp(fix_border=False)
    method.reenact([image], line + [3.0, 1.0], np.concatenate([line, line]))
    assert method.warp_counts["similarity"] == 2 and sum(method.warp_counts.values()) == 2


def test_folded_fraction_detects_a_mirrored_map():
    grid_y, grid_x = np.mgrid[0:16, 0:16].astype(float)
    assert tps.folded_fraction(grid_x, grid_y) == 0.0
    assert tps.folded_fraction(-grid_x, grid_y) == 1.0


def test_folded_fraction_reads_the_determinant_as_np_gradient_does(rng):
    """The fold check's own differences give np.gradient's numbers, so a map on the edge of folding is judged alike."""
    for shape in [(65, 65), (3, 40), (2, 9)]:
        map_x, map_y = (rng.normal(size=shape).astype(np.float32) for _ in range(2))
        determinant = (np.gradient(map_x, axis=1) * np.gradient(map_y, axis=0)
                       - np.gradient(map_x, axis=0) * np.gradient(map_y, axis=1))
        assert tps.folded_fraction(map_x, map_y) == float(np.mean(~(determinant > 0)))
        for axis in (0, 1):
            np.testing.assert_array_equal(tps._gradient(map_x, axis), np.gradient(map_x, axis=axis))


def test_fold_triggers_stronger_regularisation_or_fallback(rng):
    image = _image(rng)
    target = np.array([[30, 48], [66, 48], [48, 30], [48, 66]], float)
    source = target[[1, 0, 2, 3]]  # swap two points: the interpolating map must fold
    result = tps.warp_tps(image, source, target, regularization=0.0)
    assert result.method != "tps" and result.folded_fraction == 0.0


def test_nearest_shot_picks_the_closest_landmarks(rng):
    base = rng.uniform(40, 60, size=(68, 2))
    base[36:42] += [-15, 0]
    base[42:48] += [15, 0]
    shots = [np.full((8, 8, 3), value, np.uint8) for value in (10, 20, 30)]
    shot_landmarks = np.stack([base + 9.0, base + 0.5, base - 5.0])
    outputs = NearestShot().reenact(shots, shot_landmarks, np.stack([base, base - 4.0]))
    assert outputs[0, 0, 0, 0] == 20 and outputs[1, 0, 0, 0] == 30


def test_sub_pixel_warp_keeps_fine_detail(rng):
    """Bicubic sampling: half a pixel of shift keeps most of a band-limited texture's Laplacian energy (bilinear
    keeps under half of it, which blurred every warped reference)."""
    noise = cv2.GaussianBlur(rng.integers(0, 256, (128, 128, 3)).astype(np.float32), (0, 0), 1.0)
    image = np.clip((noise - noise.mean()) * 4 + 128, 0, 255).astype(np.uint8)
    points = rng.uniform(20, 108, (68, 2))
    result = tps.warp_tps(image, points, points + 0.5)
    assert result.method == "tps"

    def detail(x):
        return cv2.Laplacian(cv2.cvtColor(x, cv2.COLOR_RGB2GRAY).astype(np.float64), cv2.CV_64F)[8:-8, 8:-8].var()

    assert detail(result.image) / detail(image) > 0.8


@pytest.mark.parametrize("shift", [(3.0, 1.0), None])
def test_the_grid_map_is_the_dense_map_before_densifying(rng, shift):
    """``tps_grid_map`` keeps the map on its grid (ends included): densified it is ``tps_map``'s, and at the grid's
    rows and columns the dense map is the grid's values; a fallback (collinear points: a similarity) likewise."""
    target = _points(rng) if shift is not None else np.stack([np.linspace(20, 70, 12)] * 2, axis=1)
    source = target + (shift if shift is not None else [3.0, 1.0])
    grid = tps.tps_grid_map(source, target, 90, 70, grid_step=8, fix_border=shift is not None)
    assert grid.method == ("tps" if shift is not None else "similarity")
    assert grid.grid.ys[0] == 0 and grid.grid.ys[-1] == 89 and grid.grid.xs[-1] == 69
    dense = tps.tps_map(source, target, 90, 70, grid_step=8, fix_border=shift is not None)
    np.testing.assert_allclose(grid.dense().map_x, dense.map_x, atol=1e-4)
    rows, cols = grid.grid.ys.astype(int), grid.grid.xs.astype(int)
    np.testing.assert_allclose(dense.map_x[np.ix_(rows, cols)], grid.map_x, atol=1e-3)
    np.testing.assert_allclose(dense.map_y[np.ix_(rows, cols)], grid.map_y, atol=1e-3)
    if shift is None:  # affine: exact at every pixel
        ys, xs = np.mgrid[0:90, 0:70]
        np.testing.assert_allclose(dense.map_x, xs + 3.0, atol=1e-3)
