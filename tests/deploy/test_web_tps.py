"""The web runtime's TPS reference warps (deploy/web/src/tps.ts, remap.ts) against landmarks.warp.tps and OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from landmarks.shape import measures
from landmarks.warp import tps
from landmarks.motion.head_pose import project_canonical

SIDE = 256  # the side of conftest.py's real_shots


def _psnr(first: np.ndarray, second: np.ndarray) -> float:
    error = np.mean((first.astype(np.float64) - second.astype(np.float64)) ** 2)
    return float("inf") if error == 0 else float(10 * np.log10(255**2 / error))


def _check_references(expected, got, count: int) -> list[float]:
    warped, masks, indices = expected
    assert got["indices"] == indices.tolist()
    assert got["warped"].shape == (count, SIDE, SIDE, 3) and got["warped"].dtype == np.uint8
    assert got["masks"].shape == (count, SIDE, SIDE) and got["masks"].dtype == np.float32
    values = [_psnr(a, b) for a, b in zip(warped, got["warped"])]
    assert min(values) >= 40, values
    assert np.mean(masks == got["masks"]) >= 0.99
    return values


def test_warp_references_of_real_shots_match_python(web, real_shots):
    crops, points = real_shots
    shots, shot_points = crops[:8], points[:8]
    targets = [points[8], points[9]]
    results = web.calls(*(("warpReferences", [shots, shot_points, target, 5]) for target in targets),
                        ("warpReferences", [shots[:3], shot_points[:3], targets[0], 5]))  # fewer shots: repeats
    for target, got in zip(targets, results[:2]):
        values = _check_references(tps.warp_references(shots, shot_points, target, 5), got, 5)
        print(f"real shots, PSNR against Python (dB): {np.round(values, 1).tolist()}")
    _check_references(tps.warp_references(shots[:3], shot_points[:3], targets[0], 5), results[2], 5)


def test_warp_references_of_synthetic_poses_match_python(web, rng):
    """Canonical faces at 8 poses over a textured image, the target at another pose."""
    noise = cv2.GaussianBlur(rng.random((SIDE, SIDE, 3)).astype(np.float32), (0, 0), 2)
    texture = np.clip((noise - noise.mean()) / noise.std() * 50 + 128, 0, 255).astype(np.uint8)
    poses = [(-30, 0, 0), (-15, 5, 3), (0, 0, 0), (10, -8, -4), (20, 10, 6), (30, -5, 0), (5, 15, -8), (-8, -12, 10)]
    shot_points = np.stack([project_canonical(*pose, (SIDE, SIDE), scale=0.45).astype(np.float64) for pose in poses])
    shots = np.stack([np.roll(texture, 11 * k, axis=1) for k in range(8)])
    target = project_canonical(12, 4, 2, (SIDE, SIDE), scale=0.45, translation=(4, -3)).astype(np.float64)
    got = web.call("warpReferences", shots, shot_points, target, 8)
    values = _check_references(tps.warp_references(shots, shot_points, target, 8), got, 8)
    print(f"synthetic poses, PSNR against Python (dB): {np.round(values, 1).tolist()}")


def test_degenerate_landmarks_fall_back_as_python(web, real_shots):
    """Folding (mirrored, moved off the frame), collapsed, missing (NaN) and collinear point sets: the same method
    (tps, tps_stronger, similarity, identity) and the same map as Python's."""
    target = real_shots[1][9]
    mirrored = target.copy()
    mirrored[:, 0] = SIDE - 1 - mirrored[:, 0]
    collapsed = np.tile(target.mean(0), (68, 1))
    missing = target.copy()
    missing[60:] = np.nan
    line = np.stack([np.linspace(50, 200, 68), np.linspace(60, 190, 68)], axis=1)
    synthetic = project_canonical(25, 10, 5, (SIDE, SIDE), scale=0.5).astype(np.float64)
    cases = [(mirrored, target, {}), (collapsed, target, {}), (target, collapsed, {}), (np.full((68, 2), np.nan), target, {}),
             (missing, target, {}), (line + 3, line, {"fix_border": False}), (mirrored, target, {"fix_border": False}),
             (target + 400, target, {}), (synthetic, target, {}), (target, target, {"regularization": 0.0})]
    settings = [{"gridStep": 4, **({"fixBorder": False} if "fix_border" in kw else {}),
                 **({"regularization": kw["regularization"]} if "regularization" in kw else {})} for _, _, kw in cases]
    results = web.calls(*(("tpsMap", [source, target_points, SIDE, SIDE, options])
                          for (source, target_points, _), options in zip(cases, settings)))
    methods = []
    for (source, target_points, kw), got in zip(cases, results):
        expected = tps.tps_map(source, target_points, SIDE, SIDE, grid_step=4, **kw)
        assert got["method"] == expected.method, (got["reason"], expected.reason)
        assert got["regularization"] == pytest.approx(expected.regularization)
        np.testing.assert_allclose(got["mapX"].reshape(SIDE, SIDE), expected.map_x, atol=2e-3)
        np.testing.assert_allclose(got["mapY"].reshape(SIDE, SIDE), expected.map_y, atol=2e-3)
        methods.append(expected.method)
    assert {"tps", "similarity", "identity"} <= set(methods)  # the cases reach every fallback

    # references from degenerate shots: a shot without a face is chosen last, a folding one falls back
    rng = np.random.default_rng(3)
    shots = rng.integers(0, 256, (4, 64, 64, 3)).astype(np.uint8)
    shot_points = np.stack([real_shots[1][0], np.full((68, 2), np.nan), mirrored, collapsed]) * 0.25
    expected = tps.warp_references(shots, shot_points, target * 0.25, 6)
    got = web.call("warpReferences", shots, shot_points, target * 0.25, 6)
    assert got["indices"] == expected[2].tolist() == [0, 3, 2, 1, 0, 3]
    assert got["methods"] == ["tps", "identity", "similarity", "tps", "tps", "identity"]
    assert np.mean(got["warped"] == expected[0]) > 0.999 and np.mean(got["masks"] == expected[1]) > 0.999


def test_shared_maps_take_each_fallback_as_python(web, real_shots):
    """tpsMaps (one solve per try for every set onto one target): the sets that fold go on to the stronger tries
    together, then the similarity; a set with a missing point alone. Each as Python's tps_maps: the same method,
    lambda, reason and map."""
    target = real_shots[1][9]
    sets = [real_shots[1][k] for k in range(3)]
    for first, second in ((37, 41), (36, 45), (30, 33)):  # an eye's lids, the eyes' outer corners, the nose: folds
        swapped = target.copy()
        swapped[[first, second]] = swapped[[second, first]]
        sets.append(swapped)
    missing = sets[0].copy()
    missing[40] = np.nan
    sets.append(missing)
    got = web.call("tpsMaps", sets, target, SIDE, SIDE, {"gridStep": 4})
    expected = tps.tps_maps(sets, target, SIDE, SIDE, grid_step=4)
    for mine, theirs in zip(got, expected, strict=True):
        assert (mine["method"], mine["reason"]) == (theirs.method, theirs.reason)
        assert mine["regularization"] == pytest.approx(theirs.regularization)
        np.testing.assert_allclose(mine["mapX"].reshape(SIDE, SIDE), theirs.map_x, atol=2e-3)
        np.testing.assert_allclose(mine["mapY"].reshape(SIDE, SIDE), theirs.map_y, atol=2e-3)
    assert [theirs.method for theirs in expected[3:6]] == ["tps_stronger", "similarity", "tps_stronger"]


def test_nearest_shots_and_landmark_distance_match_python(web, real_shots):
    points = real_shots[1].copy()
    points[2] = np.nan  # a shot without a face comes last
    target = points[9]
    got = web.calls(("nearestShots", [points[:8], target, 8]), ("nearestShots", [points[:8], target, 3]),
                    ("landmarkDistance", [points[0], target]))
    assert got[0] == measures.nearest_shots(points[:8], target, 8).tolist() and got[0][-1] == 2
    assert got[1] == measures.nearest_shots(points[:8], target, 3).tolist()
    assert got[2] == pytest.approx(float(measures.landmark_distance(points[0], target)), rel=1e-12)


def test_the_spline_and_the_grid_map_match_python(web, real_shots):
    points = real_shots[1]
    fixed = tps.border_points(SIDE, SIDE)
    control, values = tps.merge_close_points(np.concatenate([points[9], fixed]), np.concatenate([points[0], fixed]), 1.0)
    expected = tps.fit_tps(control, values)
    # a head-like region: not square, another grid step (landmarks.scene.compositing's use of tps_grid_map)
    source, target = points[0][:40] * 0.8 + [5, 9], points[3][:40] * 0.8 + [2, 7]
    grid = tps.tps_grid_map(source, target, 190, 170, grid_step=5)
    got, got_grid = web.calls(("fitTps", [control, values]), ("tpsGridMap", [source, target, 190, 170, {"gridStep": 5}]))
    assert got["condition"] == pytest.approx(expected.condition, rel=1e-6)
    np.testing.assert_allclose(got["weights"], expected.weights, rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(got["affine"], expected.affine, rtol=1e-6, atol=1e-6)
    assert got_grid["method"] == grid.method
    np.testing.assert_array_equal(got_grid["grid"]["xs"], grid.grid.xs)
    np.testing.assert_array_equal(got_grid["grid"]["ys"], grid.grid.ys)
    np.testing.assert_allclose(got_grid["mapX"].reshape(grid.map_x.shape), grid.map_x, atol=2e-3)
    np.testing.assert_allclose(got_grid["mapY"].reshape(grid.map_y.shape), grid.map_y, atol=2e-3)


def test_samplers_match_opencv(web, real_shots, rng):
    image = real_shots[0][0][40:200, 60:220].copy()
    height, width = image.shape[:2]
    map_x = rng.uniform(-8, width + 8, (70, 90)).astype(np.float32)
    map_y = rng.uniform(-8, height + 8, (70, 90)).astype(np.float32)
    matrix = np.array([[0.9, 0.1, 12.3], [-0.08, 1.1, -5.7]])
    values = rng.random((61, 47, 3)).astype(np.float32)
    replicate, reflect, affine, area, linear = web.calls(
        ("remapImage", [image, map_x, map_y, "replicate"]), ("remapImage", [image, map_x, map_y, "reflect"]),
        ("warpAffineImage", [image, list(matrix.ravel()), 150, 130, "replicate"]),
        ("resizeImage", [values, 13, 9, "area"]), ("resizeImage", [values[:9, :13].copy(), 47, 61, "linear"]))
    expected = [cv2.remap(image, map_x, map_y, cv2.INTER_CUBIC, borderMode=border)
                for border in (cv2.BORDER_REPLICATE, cv2.BORDER_REFLECT)]
    expected.append(cv2.warpAffine(image, matrix, (150, 130), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                                   borderMode=cv2.BORDER_REPLICATE))
    for got, reference in zip((replicate, reflect, affine), expected):
        difference = np.abs(got.astype(int) - reference.astype(int))
        if int(cv2.__version__.split(".")[0]) >= 5:  # OpenCV 5 samples at the float position, as remap.ts does
            assert difference.max() <= 1 and np.mean(difference > 0) < 0.002  # float rounding at .5 only
        else:  # OpenCV 4 rounds the position to 1/32 pixel first
            assert _psnr(got, reference) > 40
    np.testing.assert_allclose(area, cv2.resize(values, (13, 9), interpolation=cv2.INTER_AREA), atol=1e-5)
    np.testing.assert_allclose(linear, cv2.resize(values[:9, :13], (47, 61), interpolation=cv2.INTER_LINEAR), atol=1e-5)
