"""Piecewise-affine warp maps over a triangulated face mesh, batched in torch: the torch version of
``landmarks.warp.piecewise_affine.mesh_warp_map`` (same triangles, same inside test, same feathering; tested against it).

The triangles and the map outside the face (the 68-point TPS there) come in as tensors: this package imports
nothing else of ours. ``landmarks.warp.piecewise_affine.triangulation()`` is the triangle list the numpy map uses.

Shapes: meshes (B, V, 2) x, y pixels; triangles (T, 3) int64, positively oriented (x right, y down) on a frontal
face; maps (B, H, W, 2) source pixel coordinates x, y per output pixel (backward maps, like ``cv2.remap``'s).
Differentiable in the meshes and the fallback map (which triangle holds a pixel is not).
"""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F

from models_def.shapes import check_shape

MIN_AREA = 1e-3  # = landmarks.warp.piecewise_affine.MIN_AREA
FEATHER = 3.0  # = landmarks.warp.piecewise_affine.FEATHER
WEIGHT_SNAP = 1e-5  # = landmarks.warp.piecewise_affine.WEIGHT_SNAP


def signed_areas(vertices: torch.Tensor, triangles: torch.Tensor) -> torch.Tensor:
    """(B, V, 2), (T, 3) -> (B, T) signed areas, positive for the canonical orientation."""
    corners = vertices[:, triangles]  # (B, T, 3, 2)
    first, second = corners[:, :, 1] - corners[:, :, 0], corners[:, :, 2] - corners[:, :, 0]
    return 0.5 * (first[..., 0] * second[..., 1] - first[..., 1] * second[..., 0])


def triangle_affines(source: torch.Tensor, target: torch.Tensor, triangles: torch.Tensor,
                     min_area: float = MIN_AREA) -> tuple[torch.Tensor, torch.Tensor]:
    """Per triangle the affine map taking its target corners onto its source corners, in its first corner's frame:
    p -> source_0 + L (p - target_0) (no large translation to cancel: float32 keeps small triangles exact).

    source, target: (B, V, 2); triangles: (T, 3) -> (affines (B, T, 2, 4): columns L (2x2), target_0, source_0;
    usable (B, T) bool: area >= min_area in both meshes). Unusable triangles get the identity."""
    # float64 tests, whatever the meshes' dtype: the same triangles and pixels as the numpy version for the same points
    usable = ((signed_areas(target.detach().double(), triangles) >= min_area)
              & (signed_areas(source.detach().double(), triangles) >= min_area))
    target_corners, source_corners = target[:, triangles], source[:, triangles]  # (B, T, 3, 2)
    target_edges = (target_corners[:, :, 1:] - target_corners[:, :, :1]).transpose(-1, -2)  # (B, T, 2, 2) columns
    source_edges = (source_corners[:, :, 1:] - source_corners[:, :, :1]).transpose(-1, -2)
    eye = torch.eye(2, dtype=target.dtype, device=target.device)
    target_edges = torch.where(usable[..., None, None], target_edges, eye)
    source_edges = torch.where(usable[..., None, None], source_edges, eye)
    linear = torch.linalg.solve(target_edges, source_edges, left=False)  # L T = S
    return torch.cat([linear, target_corners[:, :, 0, :, None], source_corners[:, :, 0, :, None]], dim=-1), usable


def _edge_coefficients(corners: torch.Tensor) -> torch.Tensor:
    """(..., 3, 2) -> (..., 3, 3): rows (a, b, c) per edge u -> v, a x + b y + c = cross(v - u, p - u)."""
    start, end = corners, corners.roll(-1, dims=-2)
    a = -(end[..., 1] - start[..., 1])
    b = end[..., 0] - start[..., 0]
    c = -(a * start[..., 0] + b * start[..., 1])
    return torch.stack([a, b, c], dim=-1)


@torch.no_grad()
def rasterise_triangles(vertices: torch.Tensor, triangles: torch.Tensor, usable: torch.Tensor, height: int, width: int,
                        priority: torch.Tensor | None = None, chunk: int = 32) -> torch.Tensor:
    """Which triangle holds each pixel centre: (B, V, 2), (T, 3), (B, T) bool -> (B, H, W) int64, -1 = none. A pixel
    under several triangles gets the one of highest priority ((B, T) float, ties by index; None = the index), as
    ``landmarks.warp.piecewise_affine.rasterise_triangles``. Every pixel is tested against ``chunk`` triangles at a time, in
    float64 whatever the vertices' dtype (a float32 test moves pixel centres near an edge across it)."""
    vertices = vertices.double()
    batch, count = vertices.shape[0], len(triangles)
    ys, xs = torch.meshgrid(torch.arange(height, dtype=vertices.dtype, device=vertices.device),
                            torch.arange(width, dtype=vertices.dtype, device=vertices.device), indexing="ij")
    xs, ys = xs.reshape(1, 1, -1), ys.reshape(1, 1, -1)  # (1, 1, H*W)
    if priority is None:
        ranks = torch.arange(count, device=vertices.device).expand(batch, count)
    else:
        order = torch.argsort(priority.double(), dim=1, stable=True)  # (B, T) rank -> triangle
        ranks = torch.empty_like(order).scatter_(1, order, torch.arange(count, device=vertices.device).expand(batch, count))
    winner = torch.full((batch, height * width), -1, dtype=torch.long, device=vertices.device)
    for start in range(0, count, chunk):
        edges = _edge_coefficients(vertices[:, triangles[start : start + chunk]])  # (B, c, 3, 3)
        inside = usable[:, start : start + chunk, None].clone()  # (B, c, 1)
        for edge in range(3):
            a, b, c = (edges[:, :, edge, k, None] for k in range(3))
            inside = inside & (a * xs + b * ys + c >= 0)  # (B, c, H*W)
        labels = torch.where(inside, ranks[:, start : start + chunk, None], -1)
        winner = torch.maximum(winner, labels.amax(dim=1))
    by_rank = torch.argsort(ranks, dim=1)  # (B, T) rank -> triangle
    index = torch.where(winner >= 0, torch.gather(by_rank, 1, winner.clamp(min=0)), -1)
    return index.view(batch, height, width)


def _blur(values: torch.Tensor, feather: float) -> torch.Tensor:
    """(B, C, H, W) -> the same, blurred by the Gaussian of sigma feather / 2 (radius ceil(3 sigma), reflect-101)."""
    sigma = feather / 2.0
    radius = max(1, math.ceil(3.0 * sigma))
    taps = torch.arange(-radius, radius + 1, dtype=torch.float64, device=values.device)
    kernel = torch.exp(-0.5 * (taps / sigma) ** 2)
    kernel = (kernel / kernel.sum()).to(values.dtype)
    channels = int(values.shape[1])
    padded = F.pad(values, (radius, radius, radius, radius), mode="reflect")
    rows = F.conv2d(padded, kernel.view(1, 1, 1, -1).repeat(channels, 1, 1, 1), groups=channels)
    return F.conv2d(rows, kernel.view(1, 1, -1, 1).repeat(channels, 1, 1, 1), groups=channels)


def feather_weights(inside: torch.Tensor, feather: float = FEATHER) -> torch.Tensor:
    """(B, H, W) {0, 1} -> (B, H, W): clip(2 * blur(inside) - 1, 0, 1), snapped to 1 within WEIGHT_SNAP (a
    dropped triangle's pixels keep their weight: ``mesh_warp_maps`` fills their correction)."""
    if feather <= 0:
        return inside
    weights = (2.0 * _blur(inside[:, None], feather)[:, 0] - 1.0).clamp(0.0, 1.0)
    return torch.where(weights > 1.0 - WEIGHT_SNAP, torch.ones_like(weights), weights)


def mesh_warp_maps(source_meshes: torch.Tensor, target_meshes: torch.Tensor, triangles: torch.Tensor,
                   fallback_maps: torch.Tensor, feather: float = FEATHER, min_area: float = MIN_AREA,
                   target_depths: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Backward maps that move each source mesh onto its target mesh: piecewise affine inside the target face,
    ``fallback_maps`` outside, feathered over ``feather`` pixels inside the face outline.

    source_meshes, target_meshes: (B, V, 2) pixels; triangles: (T, 3) int64; fallback_maps: (B, H, W, 2); feather:
    pixels (the numpy map's default is relative to the face: pass its ``MeshWarpMap.feather``), under H and W / 3;
    target_depths: (B, V) the target meshes' z (smaller = nearer), which decides which of two overlapping triangles
    shows, or None (the larger index) -> (maps (B, H, W, 2), face weights (B, H, W) in [0, 1])."""
    bound = check_shape("source_meshes", source_meshes, ("B", "V", 2))
    check_shape("target_meshes", target_meshes, (bound["B"], bound["V"], 2))
    sizes = check_shape("fallback_maps", fallback_maps, (bound["B"], "H", "W", 2))
    if triangles.ndim != 2 or triangles.shape[1] != 3 or triangles.is_floating_point():
        raise ValueError(f"triangles must be (T, 3) integer, got {tuple(triangles.shape)} {triangles.dtype}")
    batch, height, width = bound["B"], sizes["H"], sizes["W"]
    triangles = triangles.long().to(source_meshes.device)
    affines, usable = triangle_affines(source_meshes, target_meshes, triangles, min_area)  # (B, T, 2, 4)
    priority = None if target_depths is None else -target_depths.detach()[:, triangles].mean(dim=-1)  # (B, T)
    index = rasterise_triangles(target_meshes.detach(), triangles, usable, height, width, priority)  # (B, H, W)
    inside = (index >= 0).to(fallback_maps.dtype)  # (B, H, W)
    weights = feather_weights(inside, feather)
    coefficients = affines.reshape(batch, -1, 8)  # (B, T, 8) rows of the 2x4 matrices
    gathered = torch.gather(coefficients, 1, index.clamp(min=0).view(batch, -1, 1).expand(-1, -1, 8))  # (B, H*W, 8)
    ys, xs = torch.meshgrid(torch.arange(height, dtype=affines.dtype, device=affines.device),
                            torch.arange(width, dtype=affines.dtype, device=affines.device), indexing="ij")
    dx, dy = xs.reshape(1, -1) - gathered[..., 2], ys.reshape(1, -1) - gathered[..., 6]  # p - target_0
    inside_x = gathered[..., 3] + gathered[..., 0] * dx + gathered[..., 1] * dy  # (B, H*W)
    inside_y = gathered[..., 7] + gathered[..., 4] * dx + gathered[..., 5] * dy
    affine = torch.stack([inside_x, inside_y], dim=-1).view(batch, height, width, 2)
    correction = (affine - fallback_maps) * inside[..., None]  # the piecewise-affine map minus the TPS, on triangles
    if feather > 0:  # a dropped triangle's pixels: its kept neighbours' correction, Gaussian-averaged
        averaged = _blur(correction.permute(0, 3, 1, 2), feather).permute(0, 2, 3, 1)
        averaged = averaged / _blur(inside[:, None], feather)[:, 0, ..., None].clamp(min=1e-6)
        holes = ((weights > 0) & (inside == 0))[..., None]
        correction = torch.where(holes, averaged, correction)
    return fallback_maps + weights[..., None] * correction, weights


def maps_to_grid(maps: torch.Tensor) -> torch.Tensor:
    """Pixel maps (B, H, W, 2) of a same-sized source -> ``F.grid_sample`` grids with ``align_corners=True``."""
    height, width = maps.shape[1:3]
    scale = torch.tensor([2.0 / max(width - 1, 1), 2.0 / max(height - 1, 1)], dtype=maps.dtype, device=maps.device)
    return maps * scale - 1.0
