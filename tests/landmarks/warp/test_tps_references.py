"""The TPS pieces the warp-guided references and the tps_mean3 baseline use (landmarks.warp.tps): the coarse-grid map,
the nearest-shot order, ``warp_references`` and its validity masks."""

from __future__ import annotations

import numpy as np
import pytest

from landmarks.shape import measures
from landmarks.warp import tps
from landmarks.motion.head_pose import project_canonical

SIZE = 128


def _face(yaw: float = 0.0, pitch: float = 0.0, shift: tuple[float, float] = (0.0, 0.0), size: int = SIZE) -> np.ndarray:
    """(68, 2) float64 landmarks of the canonical 3-D face (landmarks.motion.head_pose) projected into a size x size frame."""
    return project_canonical(yaw, pitch, 0.0, (size, size), translation=shift).astype(np.float64)


def _deformed(points: np.ndarray, rng: np.random.Generator, amplitude: float, size: int) -> np.ndarray:
    """A smooth random deformation: a small random similarity plus a low-frequency sine field (~amplitude px)."""
    angle, scale = rng.uniform(-0.08, 0.08), rng.uniform(0.95, 1.05)
    rotation = scale * np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    centre = points.mean(axis=0)
    moved = (points - centre) @ rotation.T + centre + rng.uniform(-3.0, 3.0, size=2)
    frequency, phase = rng.uniform(0.5, 1.5, size=(2, 2)), rng.uniform(0.0, 2 * np.pi, size=2)
    wave = np.sin(2 * np.pi * (points / size) @ frequency + phase)  # (68, 2), one smooth field per axis
    return moved + amplitude * wave


def _flat_shots(values: list[int], size: int = SIZE) -> np.ndarray:
    """(K, size, size, 3) uint8, one flat colour per shot: a warp keeps it, so a warped reference shows its shot."""
    return np.stack([np.full((size, size, 3), value, np.uint8) for value in values])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_coarse_grid_map_agrees_with_the_exact_map(seed):
    rng = np.random.default_rng(seed)
    size = 224  # the evaluation side
    template = _face(size=size)
    source = _deformed(template, rng, 3.0, size)
    target = _deformed(_face(rng.uniform(-15, 15), rng.uniform(-8, 8), size=size), rng, 3.0, size)
    exact = tps.tps_map(source, target, size, size, grid_step=1)
    coarse = tps.tps_map(source, target, size, size, grid_step=4)
    assert exact.method == coarse.method == "tps"
    assert coarse.map_x.shape == coarse.map_y.shape == (size, size) and coarse.map_x.dtype == np.float32
    error = np.hypot(coarse.map_x - exact.map_x, coarse.map_y - exact.map_y)  # (H, W) pixels
    assert error.mean() < 0.1 and error.max() < 1.0


def test_nearest_shots_order_ties_and_missing_faces():
    target = _face()
    offsets = [6.0, 1.0, np.nan, 3.0, 1.0, 0.5]  # shot 2 has no face; shots 1 and 4 tie
    shot_landmarks = np.stack([target + [offset, 0.0] for offset in offsets])
    np.testing.assert_array_equal(measures.nearest_shots(shot_landmarks, target, 6), [5, 1, 4, 3, 0, 2])
    np.testing.assert_array_equal(measures.nearest_shots(shot_landmarks, target, 2), [5, 1])
    assert len(measures.nearest_shots(shot_landmarks, target, 10)) == 6  # never more than K
    partly_missing = shot_landmarks.copy()
    partly_missing[5, 30] = np.nan  # one missing point disqualifies the shot too
    assert measures.nearest_shots(partly_missing, target, 6)[-2:].tolist() == [2, 5]


def test_warp_references_returns_the_nearest_shots_in_order():
    target = _face()
    offsets = [6.0, 1.0, 9.0, 3.0, 2.0]  # order by distance: 1, 4, 3, 0, 2
    shot_landmarks = np.stack([target + [offset, 0.0] for offset in offsets])
    values = [10, 20, 30, 40, 50]
    warped, masks, indices = tps.warp_references(_flat_shots(values), shot_landmarks, target, 3)
    np.testing.assert_array_equal(indices, [1, 4, 3])
    assert warped.shape == (3, SIZE, SIZE, 3) and warped.dtype == np.uint8
    assert masks.shape == (3, SIZE, SIZE) and masks.dtype == np.float32
    for slot, index in enumerate(indices):
        assert np.all(warped[slot] == values[index])


def test_warp_references_repeats_the_nearest_when_k_is_small(rng):
    target = _face()
    shots = rng.integers(0, 256, size=(2, SIZE, SIZE, 3), dtype=np.uint8)
    shot_landmarks = np.stack([target + [4.0, 0.0], target + [1.0, 1.0]])
    warped, masks, indices = tps.warp_references(shots, shot_landmarks, target, 3)
    np.testing.assert_array_equal(indices, [1, 0, 1])  # the nearest first, then the next, then again the nearest
    np.testing.assert_array_equal(warped[2], warped[0])
    np.testing.assert_array_equal(masks[2], masks[0])
    single, _, single_indices = tps.warp_references(shots[:1], shot_landmarks[:1], target, 4)
    np.testing.assert_array_equal(single_indices, [0, 0, 0, 0])
    assert all(np.array_equal(image, single[0]) for image in single)


def test_masks_are_one_inside_and_zero_where_the_map_leaves_the_shot():
    target = _face(shift=(-24.0, 0.0))  # the face near the image's left ...
    source = target - [30.0, 0.0]  # ... and further left in the shot: its left jaw lies outside the shot
    shot_landmarks = np.stack([target, source])
    warped, masks, indices = tps.warp_references(_flat_shots([200, 100]), shot_landmarks, target, 2)
    np.testing.assert_array_equal(indices, [0, 1])
    assert set(np.unique(masks)) <= {0.0, 1.0}
    # the shot already in the target pose: the map is the identity, every pixel samples the shot
    # (the outermost pixel ring is left out: an identity map computed in floating point may land a hair outside it)
    assert np.all(masks[0][1:-1, 1:-1] == 1.0)
    # the shifted shot: the mask is the map's validity, 0 where the output would sample left of the shot (a spline
    # pinned at the frame border folds to follow a 30-px shift, so this map is the similarity fallback's)
    expected = tps.tps_map(source, target, SIZE, SIZE, grid_step=4).valid(SIZE, SIZE)
    np.testing.assert_array_equal(masks[1], expected.astype(np.float32))
    columns, rows = np.rint(target).astype(int).T
    outside = source[:, 0] < -2.0  # landmarks whose shot position is off the shot's left edge
    inside = (source[:, 0] > 2.0) & (source[:, 0] < SIZE - 3.0)
    assert outside.any() and inside.any()
    assert np.all(masks[1][rows[outside], columns[outside]] == 0.0)
    assert np.all(masks[1][rows[inside], columns[inside]] == 1.0)
    assert 0.0 < masks[1].mean() < 1.0


def test_bad_references_requests_raise():
    target = _face()
    with pytest.raises(ValueError):
        tps.warp_references(_flat_shots([10])[0], target[None], target, 1)  # (S, S, 3), not (K, S, S, 3)
    with pytest.raises(ValueError):
        tps.warp_references(_flat_shots([10]), target[None], target, 0)


@pytest.mark.parametrize("step", [1, 4])
def test_shared_maps_equal_one_map_per_set_including_the_fallbacks(step):
    """tps_maps (one system for every set warped onto the same target) gives tps_map's maps, methods, lambdas and
    reasons, also for a set with a missing point (through tps_map alone) and sets that fold (their stronger tries
    solved together, then the similarity)."""
    rng = np.random.default_rng(7)
    size = 96
    target = _face(8.0, -4.0, size=size)
    sets = [_deformed(_face(size=size), rng, 2.0, size) for _ in range(3)]
    missing = sets[0].copy()
    missing[40] = np.nan
    folded = target.copy()
    folded[[36, 45]] = folded[[45, 36]]  # the eye corners swapped: the map must fold
    crossed = target.copy()
    crossed[[42, 45]] = crossed[[45, 42]]  # one eye's corners swapped: a stronger lambda unfolds it
    sets += [missing, folded, crossed]
    shared = tps.tps_maps(sets, target, size, size, grid_step=step)
    for points, got in zip(sets, shared, strict=True):
        expected = tps.tps_map(points, target, size, size, grid_step=step)
        assert (got.method, got.regularization, got.reason) == (expected.method, expected.regularization,
                                                                expected.reason)
        np.testing.assert_allclose(got.map_x, expected.map_x, atol=2e-3)
        np.testing.assert_allclose(got.map_y, expected.map_y, atol=2e-3)
    assert [got.method for got in shared[-2:]] == ["similarity", "tps_stronger"]  # both fallbacks really taken


def test_dense_evaluation_agrees_with_float64_to_a_hundredth_of_a_pixel():
    rng = np.random.default_rng(3)
    size = 256
    for _ in range(5):
        target = _deformed(_face(rng.uniform(-20, 20), rng.uniform(-10, 10), size=size), rng, 3.0, size)
        source = _deformed(_face(size=size), rng, 3.0, size)
        control = np.concatenate([target, tps.border_points(size, size)])
        values = np.concatenate([source, tps.border_points(size, size)])
        spline = tps.fit_tps(control, values)
        points = tps._Grid(size, size, 4).points
        assert np.abs(spline.dense(points) - spline(points)).max() < 0.01
