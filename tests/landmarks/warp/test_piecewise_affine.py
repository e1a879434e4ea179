"""Piecewise-affine warping over the face mesh (landmarks.warp.piecewise_affine): triangulation, rasteriser, map."""

from __future__ import annotations

import json

import numpy as np
import pytest

from landmarks.warp import piecewise_affine as mesh_warp
from landmarks.warp import tps
from landmarks.shape.mesh68 import mesh_to_68

SIZE = 96


def _face(scale: float = 26.0, centre: tuple[float, float] = (48.0, 44.0)) -> np.ndarray:
    """(468, 2) float64: the canonical mesh placed in a SIZE x SIZE frame."""
    return mesh_warp.frontal_canonical() * scale + np.asarray(centre)


def _grid(height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    grid_y, grid_x = np.mgrid[0:height, 0:width].astype(np.float64)
    return grid_x, grid_y


class TestTriangulation:
    def test_stored_triangles_are_what_the_builder_gives_from_the_canonical_mesh(self):
        record = json.loads(mesh_warp.TRIANGLES_FILE.read_text())
        rebuilt = mesh_warp.build_triangles(mesh_warp.frontal_canonical(), record["min_angle_degrees"])
        np.testing.assert_array_equal(rebuilt, np.asarray(record["triangles"]))  # else: write_triangulation()

    def test_no_flipped_or_sliver_triangle_on_the_canonical_mesh(self):
        canonical, triangles = mesh_warp.frontal_canonical(), mesh_warp.triangulation()
        assert canonical.shape == (468, 2) and triangles.shape[1] == 3 and triangles.dtype == np.int32
        assert np.all(mesh_warp.signed_areas(canonical, triangles) > 0)
        assert np.all(mesh_warp.smallest_angles(canonical, triangles) >= mesh_warp.MIN_ANGLE_DEGREES)
        assert len({tuple(sorted(t)) for t in triangles.tolist()}) == len(triangles)  # no duplicates

    def test_covers_the_face_hull_without_overlaps(self):
        import cv2

        canonical, triangles = mesh_warp.frontal_canonical(), mesh_warp.triangulation()
        hull_area = cv2.contourArea(cv2.convexHull(canonical.astype(np.float32)))
        total = mesh_warp.signed_areas(canonical, triangles).sum()
        assert 0.97 * hull_area <= total <= hull_area * (1 + 1e-6)  # only hull slivers are left out
        # at pixel scale: each pixel centre of the hull in exactly one triangle except on shared edges
        face = _face(60.0, (128.0, 128.0))
        index = mesh_warp.rasterise_triangles(face, triangles, np.ones(len(triangles), bool), 256, 256)
        hull = np.zeros((256, 256), np.uint8)
        cv2.fillConvexPoly(hull, np.round(cv2.convexHull(face.astype(np.float32))).astype(np.int32)[:, 0], 1)
        assert np.mean(index[hull > 0] >= 0) > 0.97
        assert len(np.unique(triangles)) >= 466  # (nearly) every vertex is used

    def test_canonical_is_eye_normalised_with_an_open_mouth(self):
        from landmarks.shape.expression import mouth_opening

        points = mesh_to_68(mesh_warp.frontal_canonical()).astype(np.float64)
        left, right = points[36:42].mean(0), points[42:48].mean(0)
        np.testing.assert_allclose((left + right) / 2, 0.0, atol=1e-5)
        np.testing.assert_allclose(right - left, [1.0, 0.0], atol=1e-5)
        assert mouth_opening(points) > 0.05  # the lips do not touch: no triangle joins them by accident


class TestRasterise:
    @pytest.mark.parametrize("with_priority", [False, True])
    def test_fast_equals_reference(self, rng, with_priority):
        triangles = mesh_warp.triangulation()
        face = _face() + rng.normal(0, 0.7, (468, 2))  # noise: triangles overlap, so the ranks matter
        usable = rng.random(len(triangles)) > 0.1
        priority = rng.normal(size=len(triangles)) if with_priority else None
        fast = mesh_warp.rasterise_triangles(face, triangles, usable, SIZE, SIZE + 7, priority)
        reference = mesh_warp.rasterise_triangles_reference(face, triangles, usable, SIZE, SIZE + 7, priority)
        np.testing.assert_array_equal(fast, reference)
        assert fast.dtype == np.int32 and not np.isin(np.flatnonzero(~usable), fast).any()

    def test_the_nearest_of_overlapping_triangles_shows(self):
        triangles = np.array([[0, 1, 2], [3, 4, 5]])
        vertices = np.array([[2.0, 2.0], [12.0, 2.0], [2.0, 12.0], [4.0, 4.0], [14.0, 4.0], [4.0, 14.0]])
        usable = np.ones(2, bool)
        assert mesh_warp.rasterise_triangles(vertices, triangles, usable, 16, 16)[5, 5] == 1  # default: larger index
        index = mesh_warp.rasterise_triangles(vertices, triangles, usable, 16, 16, priority=np.array([1.0, 0.0]))
        assert index[5, 5] == 0 and index[3, 3] == 0 and index[12, 5] == 1

    def test_clipped_at_the_frame_and_empty_when_nothing_is_usable(self):
        triangles = mesh_warp.triangulation()
        face = _face(40.0, (10.0, 90.0))  # mostly outside the frame
        fast = mesh_warp.rasterise_triangles(face, triangles, np.ones(len(triangles), bool), SIZE, SIZE)
        reference = mesh_warp.rasterise_triangles_reference(face, triangles, np.ones(len(triangles), bool), SIZE, SIZE)
        np.testing.assert_array_equal(fast, reference)
        none = mesh_warp.rasterise_triangles(face, triangles, np.zeros(len(triangles), bool), SIZE, SIZE)
        assert np.all(none == -1)


class TestMeshWarpMap:
    def test_same_meshes_give_the_identity(self):
        face = _face()
        warp = mesh_warp.mesh_warp_map(face, face, SIZE, SIZE)
        grid_x, grid_y = _grid(SIZE, SIZE)
        assert np.abs(warp.map_x - grid_x).max() < 1e-3 and np.abs(warp.map_y - grid_y).max() < 1e-3
        assert warp.usable_triangles > 0.9 * warp.triangles and warp.map_x.dtype == np.float32

    def test_an_affine_motion_is_reproduced_exactly_inside_the_face(self):
        source = _face()
        matrix, shift = np.array([[1.06, 0.12], [-0.09, 0.95]]), np.array([2.5, -3.0])
        target = source @ matrix.T + shift
        warp = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
        grid_x, grid_y = _grid(SIZE, SIZE)
        expected = (np.stack([grid_x, grid_y], -1) - shift) @ np.linalg.inv(matrix).T  # the source of each pixel
        inside = warp.face_weight == 1.0
        assert inside.sum() > 500  # the face's interior (the feather's width inside the outline aside), not a few pixels
        np.testing.assert_allclose(warp.map_x[inside], expected[..., 0][inside], atol=1e-3)
        np.testing.assert_allclose(warp.map_y[inside], expected[..., 1][inside], atol=1e-3)
        outside = warp.face_weight == 0.0
        np.testing.assert_array_equal(warp.map_x[outside], warp.fallback.map_x[outside])  # the TPS out there

    def test_inside_the_face_the_map_is_the_barycentric_reference(self, rng):
        source = _face() + rng.normal(0, 0.4, (468, 2))
        target = _face(28.0, (47.0, 46.0)) + rng.normal(0, 0.4, (468, 2))
        warp = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE, feather=0.0)  # weight 1 on every triangle's pixel
        triangles = mesh_warp.triangulation()
        _, usable = mesh_warp.triangle_affines(source, target, triangles)
        rows, cols = np.nonzero(warp.face_weight == 1.0)
        assert len(rows) > 2000
        for pick in rng.choice(len(rows), size=40, replace=False):
            expected = mesh_warp.piecewise_affine_reference(source, target, triangles, usable, (cols[pick], rows[pick]))
            assert expected is not None
            np.testing.assert_allclose([warp.map_x[rows[pick], cols[pick]], warp.map_y[rows[pick], cols[pick]]],
                                       expected, atol=1e-4)  # float32 maps

    def test_feathering_leaves_no_seam(self, rng):
        source = _face(22.0)  # inside the frame
        target = source + rng.normal(0, 1.0, source.shape)  # per-vertex noise: TPS and triangles disagree
        feathered = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
        hard = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE, feather=0.0, fallback=feathered.fallback)

        def largest_step(warp: mesh_warp.MeshWarpMap) -> float:
            return float(max(np.abs(np.diff(warp.map_x, axis=1)).max(), np.abs(np.diff(warp.map_y, axis=0)).max()))

        assert largest_step(feathered) < largest_step(hard)
        assert np.all((feathered.face_weight >= 0) & (feathered.face_weight <= 1))
        import cv2

        hull = np.zeros((SIZE, SIZE), np.uint8)
        cv2.fillConvexPoly(hull, np.round(cv2.convexHull(target.astype(np.float32))).astype(np.int32)[:, 0], 1)
        hull = cv2.dilate(hull, np.ones((3, 3), np.uint8))  # the drawn hull's rounding
        assert np.all(feathered.face_weight[hull == 0] == 0)  # never outside the face

    def test_dropped_triangles_leave_no_speck(self):
        source = _face()
        triangles = mesh_warp.triangulation()
        for seed in range(3):  # per-vertex noise: the triangles and the TPS disagree, and small triangles fold
            target = source * 1.04 + [0.5, 1.0] + np.random.default_rng(seed).normal(0, 0.8, source.shape)
            warp = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
            _, usable = mesh_warp.triangle_affines(source, target, triangles)
            holes = (warp.face_weight > 0) & (mesh_warp.rasterise_triangles(target, triangles, usable, SIZE, SIZE) < 0)
            assert holes.any()
            # next to a hole the map steps about a pixel per pixel, as a near-identity map does (a hole left to the
            # TPS alone stepped up to 2.6 px here)
            for values in (warp.map_x, warp.map_y):
                for axis in (0, 1):
                    near = (holes[1:] | holes[:-1]) if axis == 0 else (holes[:, 1:] | holes[:, :-1])
                    assert np.abs(np.diff(values, axis=axis))[near].max() < 1.6

    def test_folded_and_degenerate_triangles_fall_back(self):
        source = _face()
        target = source.copy()
        target[1] = target[1] + [0.0, 12.0]  # drag a vertex across its neighbours: its triangles fold
        target[2] = target[3]  # two vertices on top of each other: degenerate triangles
        triangles = mesh_warp.triangulation()
        _, before = mesh_warp.triangle_affines(source, source, triangles)  # the face's own sub-pixel triangles
        _, usable = mesh_warp.triangle_affines(source, target, triangles)
        touched = np.isin(triangles, [1, 2]).any(axis=1)
        assert not usable[mesh_warp.signed_areas(target, triangles) <= 0].any()
        assert (~usable & before & touched).sum() >= 2 and np.array_equal(usable[~touched], before[~touched])
        warp = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
        assert warp.usable_triangles == usable.sum() and np.isfinite(warp.map_x).all() and np.isfinite(warp.map_y).all()

    def test_default_fallback_is_the_tps_of_the_mesh_points(self):
        source = _face()
        target = source * 1.03 + [1.0, 0.5]
        warp = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
        expected = tps.tps_map(mesh_to_68(source), mesh_to_68(target), SIZE, SIZE)
        np.testing.assert_array_equal(warp.fallback.map_x, expected.map_x)

    def test_warp_mesh_moves_the_image(self, rng):
        image = rng.integers(0, 256, (SIZE, SIZE, 3), dtype=np.uint8)
        face = _face()
        moved, warp = mesh_warp.warp_mesh(image, face, face)
        assert moved.shape == image.shape and moved.dtype == np.uint8
        assert np.abs(moved.astype(int) - image).max() <= 1  # identity map, bicubic rounding
        assert warp.valid(SIZE, SIZE).all()

    def test_bad_inputs_raise(self):
        face = _face()
        with pytest.raises(ValueError, match="468"):
            mesh_warp.mesh_warp_map(face[:68], face[:68], SIZE, SIZE)
        wrong = tps.tps_map(mesh_to_68(face), mesh_to_68(face), SIZE // 2, SIZE)
        with pytest.raises(ValueError, match="fallback"):
            mesh_warp.mesh_warp_map(face, face, SIZE, SIZE, fallback=wrong)
        with pytest.raises(ValueError, match="uint8"):
            mesh_warp.warp_mesh(np.zeros((SIZE, SIZE, 3), np.float32), face, face)


def test_a_shared_target_layout_gives_the_per_source_map_when_nothing_folds():
    """warp_references_mesh rasterises the target once for all its shots: with no folded source triangle that is
    the map mesh_warp_map makes alone."""
    source, target = _face(), _face(scale=27.0, centre=(49.0, 45.0))
    alone = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
    shared = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE, layout=mesh_warp.target_layout(target, SIZE, SIZE))
    np.testing.assert_allclose(shared.map_x, alone.map_x, atol=1e-4)
    np.testing.assert_allclose(shared.map_y, alone.map_y, atol=1e-4)


class TestCoarseGrid:
    """grid_step > 1: the piecewise-affine correction made at block centres and upsampled (the references' speed)."""

    def test_upsampling_interpolates_between_the_block_centres(self):
        for step in (1, 2, 4):
            rows, cols = mesh_warp.grid_shape(SIZE, SIZE, step)
            grid_x = mesh_warp.grid_points(cols, step)
            grid_y = mesh_warp.grid_points(rows, step)
            values = (0.5 * grid_x[None, :] - 0.25 * grid_y[:, None] + 3.0).astype(np.float32)  # linear in x, y
            dense = mesh_warp.upsample(values, step, SIZE, SIZE)
            grid_x_dense, grid_y_dense = _grid(SIZE, SIZE)
            expected = 0.5 * grid_x_dense - 0.25 * grid_y_dense + 3.0
            within = (grid_x_dense >= grid_x[0]) & (grid_x_dense <= grid_x[-1]) & (grid_y_dense >= grid_y[0]) & (
                grid_y_dense <= grid_y[-1])
            assert dense.shape == (SIZE, SIZE)
            np.testing.assert_allclose(dense[within], expected[within], atol=1e-4)
        assert mesh_warp.grid_shape(97, 96, 4) == (25, 24)
        with pytest.raises(ValueError):
            mesh_warp.grid_shape(SIZE, SIZE, 0)

    def test_an_affine_motion_stays_exact_inside_the_face(self):
        source = _face()
        matrix, shift = np.array([[1.06, 0.12], [-0.09, 0.95]]), np.array([2.5, -3.0])
        target = source @ matrix.T + shift
        exact = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
        for step in (2, 4):
            fallback = tps.tps_map(mesh_to_68(source), mesh_to_68(target), SIZE, SIZE, grid_step=step)
            coarse = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE, fallback=fallback,
                                             layout=mesh_warp.target_layout(target, SIZE, SIZE, grid_step=step))
            inside = (exact.face_weight == 1.0) & (coarse.face_weight == 1.0)
            assert inside.sum() > 400
            # one affine everywhere inside: the only error is the TPS's curvature between grid points
            assert np.abs(coarse.map_x - exact.map_x)[inside].max() < 0.05
            assert np.abs(coarse.map_y - exact.map_y)[inside].max() < 0.05

    def test_an_expressive_warp_is_within_a_fraction_of_a_pixel(self, rng):
        source = _face(40.0, (48.0, 48.0)) + rng.normal(0, 0.3, (468, 2))
        target = _face(42.0, (47.0, 49.0)) + rng.normal(0, 0.3, (468, 2))
        exact = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE)
        for step, limit in ((2, 0.5), (4, 1.0)):  # a 96-px face with 0.3 px of noise per vertex: tiny triangles
            coarse = mesh_warp.mesh_warp_map(source, target, SIZE, SIZE, grid_step=step)
            error = np.hypot(coarse.map_x - exact.map_x, coarse.map_y - exact.map_y)
            assert np.percentile(error, 99) < limit and np.median(error) < 0.1 * limit
            assert coarse.map_x.shape == (SIZE, SIZE) and coarse.map_x.dtype == np.float32

    def test_references_use_the_grid_of_the_tps_references(self, rng):
        import inspect

        image = rng.integers(0, 256, (SIZE // 4, SIZE // 4, 3), dtype=np.uint8).repeat(4, 0).repeat(4, 1)
        shots = np.stack([image, image[:, ::-1].copy()])
        meshes = np.stack([_face(), _face(27.0, (49.0, 45.0))])
        meshes = np.concatenate([meshes, np.zeros((2, 468, 1))], axis=2)
        landmarks = mesh_to_68(meshes).astype(np.float64)
        target = np.concatenate([_face(26.5, (48.5, 44.5)), np.zeros((468, 1))], axis=1)
        step = inspect.signature(mesh_warp.warp_references_mesh).parameters["grid_step"].default
        assert step == inspect.signature(tps.warp_references).parameters["grid_step"].default
        coarse, masks, _ = mesh_warp.warp_references_mesh(shots, meshes, landmarks, target, mesh_to_68(target), 2)
        exact, _, _ = mesh_warp.warp_references_mesh(shots, meshes, landmarks, target, mesh_to_68(target), 2,
                                                     grid_step=1)
        assert masks.shape == (2, SIZE, SIZE)
        assert np.abs(coarse.astype(float) - exact).mean() < 2.0  # the same images, up to sub-pixel resampling
