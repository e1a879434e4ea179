"""The torch mesh warp (models_def.mesh_warp) against the numpy one (landmarks.warp.piecewise_affine)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from landmarks.warp import piecewise_affine as numpy_warp
from models_def import mesh_warp

HEIGHT, WIDTH = 72, 64


def _meshes(seed: int, count: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """(count, 468, 2) source and target meshes: the canonical face, moved and jittered per vertex."""
    rng = np.random.default_rng(seed)
    base = numpy_warp.frontal_canonical() * 18.0 + [32.0, 33.0]
    sources = np.stack([base + rng.normal(0, 0.5, base.shape) for _ in range(count)])
    matrix = np.array([[1.03, 0.06], [-0.05, 0.97]])
    targets = np.stack([base @ matrix.T + [1.5, -2.0] + rng.normal(0, 0.5, base.shape) for _ in range(count)])
    return sources, targets


def _numpy_maps(sources: np.ndarray, targets: np.ndarray) -> list[numpy_warp.MeshWarpMap]:
    return [numpy_warp.mesh_warp_map(s, t, HEIGHT, WIDTH) for s, t in zip(sources, targets)]


def _stack(maps: list[numpy_warp.MeshWarpMap], fallback: bool = False) -> np.ndarray:
    chosen = [m.fallback if fallback else m for m in maps]
    return np.stack([np.stack([m.map_x, m.map_y], axis=-1) for m in chosen]).astype(np.float64)  # (B, H, W, 2)


def _triangles() -> torch.Tensor:
    return torch.from_numpy(np.asarray(numpy_warp.triangulation(), np.int64))


def test_constants_are_the_numpy_ones():
    assert (mesh_warp.MIN_AREA, mesh_warp.FEATHER, mesh_warp.WEIGHT_SNAP) == (
        numpy_warp.MIN_AREA, numpy_warp.FEATHER, numpy_warp.WEIGHT_SNAP)


class TestMeshWarpMaps:
    @pytest.mark.parametrize(("dtype", "tolerance"), [(torch.float64, 1e-4), (torch.float32, 1e-3)])
    def test_matches_numpy(self, dtype, tolerance):
        sources, targets = (points.astype(np.float32).astype(np.float64) for points in _meshes(0))  # one set of points
        depths = np.random.default_rng(5).normal(0.0, 3.0, targets.shape[:2])  # overlapping triangles: the nearer shows
        maps = _numpy_maps(sources, targets)
        feather = maps[0].feather
        maps = [numpy_warp.mesh_warp_map(s, np.concatenate([t, z[:, None]], axis=1), HEIGHT, WIDTH, feather=feather)
                for s, t, z in zip(sources, targets, depths)]
        out, weights = mesh_warp.mesh_warp_maps(torch.from_numpy(sources).to(dtype), torch.from_numpy(targets).to(dtype),
                                                _triangles(), torch.from_numpy(_stack(maps, fallback=True)).to(dtype),
                                                feather=feather, target_depths=torch.from_numpy(depths).to(dtype))
        assert out.shape == (2, HEIGHT, WIDTH, 2) and out.dtype == dtype and weights.shape == (2, HEIGHT, WIDTH)
        assert np.abs(out.double().numpy() - _stack(maps)).max() < tolerance
        np.testing.assert_allclose(weights.double().numpy(), np.stack([m.face_weight for m in maps]), atol=10 * tolerance)

    def test_rasteriser_matches_numpy(self):
        sources, targets = _meshes(1, count=1)
        triangles = numpy_warp.triangulation()
        _, usable = numpy_warp.triangle_affines(sources[0], targets[0], triangles)
        expected = numpy_warp.rasterise_triangles(targets[0], triangles, usable, HEIGHT, WIDTH)
        found = mesh_warp.rasterise_triangles(torch.from_numpy(targets), _triangles(), torch.from_numpy(usable)[None],
                                              HEIGHT, WIDTH)
        np.testing.assert_array_equal(found[0].numpy(), expected)
        priority = np.random.default_rng(6).normal(size=len(triangles))
        expected = numpy_warp.rasterise_triangles(targets[0], triangles, usable, HEIGHT, WIDTH, priority)
        found = mesh_warp.rasterise_triangles(torch.from_numpy(targets), _triangles(), torch.from_numpy(usable)[None],
                                              HEIGHT, WIDTH, torch.from_numpy(priority)[None])
        np.testing.assert_array_equal(found[0].numpy(), expected)

    def test_identity_and_grid(self):
        sources, _ = _meshes(2, count=1)
        grid_y, grid_x = torch.meshgrid(torch.arange(HEIGHT, dtype=torch.float64),
                                        torch.arange(WIDTH, dtype=torch.float64), indexing="ij")
        identity = torch.stack([grid_x, grid_y], dim=-1)[None]
        mesh = torch.from_numpy(sources)
        out, _ = mesh_warp.mesh_warp_maps(mesh, mesh, _triangles(), identity)
        torch.testing.assert_close(out, identity, atol=1e-9, rtol=0)
        grid = mesh_warp.maps_to_grid(out)
        assert grid.min() == -1.0 and grid.max() == 1.0

    def test_gradients_in_float64(self):
        # a small frame (the canonical face at 1/4 scale) and few parameters keep the numerical Jacobian cheap
        sources, targets = _meshes(3, count=1)
        source, target = torch.from_numpy(sources / 4.0), torch.from_numpy(targets / 4.0)
        fallback = torch.from_numpy(_stack(_numpy_maps(sources, targets), fallback=True))[:, ::4, ::4] / 4.0

        def warp(motion: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
            moved = source @ (torch.eye(2, dtype=torch.float64) + motion[:, :2]).T + motion[:, 2]
            return mesh_warp.mesh_warp_maps(moved, target, _triangles(), fallback * gain, min_area=0.01)[0]

        motion = torch.zeros(2, 3, dtype=torch.float64, requires_grad=True)
        gain = torch.ones(1, dtype=torch.float64, requires_grad=True)
        assert torch.autograd.gradcheck(warp, (motion, gain), eps=1e-6, atol=1e-5)

    def test_bad_inputs_raise(self):
        sources, targets = _meshes(4, count=1)
        mesh = torch.from_numpy(sources)
        fallback = torch.zeros(1, HEIGHT, WIDTH, 2, dtype=torch.float64)
        with pytest.raises(ValueError, match="target_meshes"):
            mesh_warp.mesh_warp_maps(mesh, mesh[:, :68], _triangles(), fallback)
        with pytest.raises(ValueError, match="fallback_maps"):
            mesh_warp.mesh_warp_maps(mesh, mesh, _triangles(), fallback[..., :1])
        with pytest.raises(ValueError, match="triangles"):
            mesh_warp.mesh_warp_maps(mesh, mesh, _triangles().double(), fallback)
